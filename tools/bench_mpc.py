"""Benchmark: MPC control-step time with learned models vs with the plant as model (same run).

Every controller tracks the same held-out tracked plans in closed loop with the UR-10 plant (1 ms
step, 10 ms control period, horizon 20, controllers/mpc.yaml). Models: the discrete plant itself
(its simulator, 10 contact-aware substeps per step), the fair compute baseline `RungeKuttaPlantModel`
(the description's continuous dynamics, one RK4 step), the paper's black boxes DD and PE, and the
default physics-structured D (next velocity from the nominal acceleration). Goal: <= 10 ms per
control step with a learned model (100 Hz closed loop) on 2 cores, with tracking error within 1.2x
of the plant-model MPC.

Usage: python tools/bench_mpc.py [--dataset D.h5 --checkpoint C.pt ...] [--plans 3] [--write]
Without --dataset/--checkpoint it collects the identification dataset (100 tracked plans, dithered
PID, ideal sensor: controllers/pid_dither.yaml, controllers/sensor_ideal.yaml) and trains a DD and
a PE model (the paper's structure) and a default-structure D on 20 plans per initial pose (seed 0)
in a temporary folder first, with the true,
held-torque derivative targets (--action-rate zero_order_hold) as `reproduce` trains its control
models: the dither changes the torque every sample, so forward-difference torque rates teach DD a
wrong torque response and its MPC diverges.
"""
import argparse
import os
import pathlib
import sys
import tempfile

os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")

import torch  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from benchmark_report import machine_description, write_benchmark_section  # noqa: E402

from stdm_drake.cli import main as cli  # noqa: E402
from stdm_drake.data.dataset import load_dataset  # noqa: E402
from stdm_drake.learning.learned_model import LearnedModel  # noqa: E402
from stdm_drake.learning.physics import PlantModel, RungeKuttaPlantModel  # noqa: E402
from stdm_drake.closed_loop.comparison import (compare_controllers, held_out_references, summarize,  # noqa: E402
                                               summary_table)
from stdm_drake.closed_loop.mpc import load_mpc_config  # noqa: E402
from stdm_drake.experiments.jobs import IDENTIFICATION_SETTINGS  # noqa: E402
from stdm_drake.robots.robot import UR10_CONFIG, load_robot  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=pathlib.Path)
    parser.add_argument("--checkpoint", type=pathlib.Path, action="append", default=[])
    parser.add_argument("--plans", type=int, default=3)
    parser.add_argument("--write", action="store_true", help="update BENCHMARKS.md")
    args = parser.parse_args()
    torch.set_num_threads(1)
    folder = pathlib.Path(tempfile.mkdtemp(prefix="bench_mpc_"))
    dataset_path = args.dataset or folder / "identification.h5"
    if args.dataset is None:
        assert cli(["collect", "--protocol", "tracking", "--controller", str(IDENTIFICATION_SETTINGS["controller"]),
                    "--sensor", str(IDENTIFICATION_SETTINGS["sensor"]), "--quiet",
                    "-o", str(dataset_path)]) == 0
    checkpoints = list(args.checkpoint)
    if not checkpoints:
        for name, kind, structure in (("DD", "DD", ["--predicts", "state", "--inputs", "raw"]),
                                      ("PE", "PE", ["--predicts", "state", "--inputs", "raw"]),
                                      ("D-default", "D", [])):
            derivative = (["--derivative-source", "true", "--action-rate", "zero_order_hold", "--alpha", "1e-3"]
                          if kind == "DD" else [])   # (the alpha of BENCHMARKS.md's runs, before train's default chose it)
            assert cli(["train", str(dataset_path), "--model", kind, *derivative, "--train", "20", *structure,
                        "--val", "3", "--test", "2", "--seeds", "0", "--quiet", "-o", str(folder / name)]) == 0
            checkpoints.append(folder / name / "seed0" / "checkpoint.pt")
    dataset = load_dataset(dataset_path)
    ur10 = load_robot(UR10_CONFIG)
    learned = [LearnedModel(path, robot=ur10) for path in checkpoints]
    for model in learned:
        default = model.structure.uses_nominal_model
        model.name = f"learned ({model.checkpoint.metadata.model_type or model.name}{', default' if default else ''})"
    references = held_out_references(dataset, [model.checkpoint for model in learned], args.plans)
    config = load_mpc_config()
    plants = [PlantModel(dataset.sample_period, robot=ur10), RungeKuttaPlantModel(dataset.sample_period, robot=ur10)]
    results = compare_controllers([*plants, *learned], references, config, progress=False, robot=ur10)
    rows = summarize(results, dataset.sample_period)
    plant_row, rk4_row = rows[0], rows[1]
    lines = [f"{len(references)} held-out plans of {dataset_path.name} (1 s each), horizon {config.horizon}, "
             f"{config.max_iterations} iLQR iteration(s) per step, disturbance gain {config.disturbance_gain}, "
             "torch threads 1.", "", summary_table(rows), ""]
    for row in rows[1:]:
        speed = row["solve_ms_mean"] / plant_row["solve_ms_mean"]
        fair = row["solve_ms_mean"] / rk4_row["solve_ms_mean"]
        lines.append(f"{row['model']}: {row['solve_ms_mean']:.2f} ms mean, {row['solve_ms_p95']:.2f} ms p95 "
                     f"per control step (goal <= 10 ms), {speed:.3f}x the plant-model step time, {fair:.3f}x the "
                     f"RK4 plant model's; tracking q MSE {row['q_mse_vs_plant']:.3g}x the plant-model MPC's (goal <= 1.2x).")
    given = "" if args.dataset is None and not args.checkpoint else (
        " (data and checkpoints from an earlier default run, passed in to time the closed loop alone)")
    command = " ".join(["python tools/bench_mpc.py", *sys.argv[1:]])
    report = "\n".join(lines + ["", f"Machine: {machine_description(threads=1)}.", f"Command: `{command}`{given}."])
    print(report)
    if args.write:
        write_benchmark_section("Deployment", "MPC control step (tools/bench_mpc.py)", report)


if __name__ == "__main__":
    main()
