"""Benchmark: MPC control-step time with a learned model vs with the plant as model (same run).

Both controllers track the same held-out tracked plans in closed loop with the UR-10 plant (1 ms
step, 10 ms control period, horizon 20, controllers/mpc.yaml). Goal: <= 10 ms per control step with
the learned model (100 Hz closed loop) on 2 cores, with tracking error within 1.2x of the plant-model
MPC.

Usage: python tools/bench_mpc.py [--dataset D.h5 --checkpoint C.pt] [--plans 3] [--write]
Without --dataset/--checkpoint it collects the default tracking dataset and trains a DD model
(default settings, seed 0) in a temporary folder first.
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
from stdm_drake.dataset import load_dataset  # noqa: E402
from stdm_drake.learned_system import LearnedModel  # noqa: E402
from stdm_drake.mpc import (PlantModel, compare_controllers, held_out_references, load_mpc_config,  # noqa: E402
                            markdown_table, summarize)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=pathlib.Path)
    parser.add_argument("--checkpoint", type=pathlib.Path)
    parser.add_argument("--plans", type=int, default=3)
    parser.add_argument("--write", action="store_true", help="update BENCHMARKS.md")
    args = parser.parse_args()
    torch.set_num_threads(1)
    folder = pathlib.Path(tempfile.mkdtemp(prefix="bench_mpc_"))
    dataset_path = args.dataset or folder / "tracking.h5"
    if args.dataset is None:
        assert cli(["collect", "--protocol", "tracking", "--quiet", "-o", str(dataset_path)]) == 0
    checkpoint = args.checkpoint
    if checkpoint is None:
        assert cli(["train", str(dataset_path), "--model", "DD", "--seeds", "0", "--quiet", "-o",
                    str(folder / "dd")]) == 0
        checkpoint = folder / "dd" / "seed0" / "checkpoint.pt"
    dataset = load_dataset(dataset_path)
    learned = LearnedModel(checkpoint)
    learned.name = f"learned ({learned.checkpoint.metadata.get('model_type', 'model')})"
    references = held_out_references(dataset, [learned.checkpoint], args.plans)
    config = load_mpc_config()
    results = compare_controllers([PlantModel(dataset.sample_period), learned], references, config, progress=False)
    rows = summarize(results, dataset.sample_period)
    plant_row, learned_row = rows
    ratio_time = learned_row["solve_ms_mean"] / plant_row["solve_ms_mean"]
    ratio_error = learned_row["q_mse_rad2"] / max(plant_row["q_mse_rad2"], 1e-300)
    report = "\n".join([
        f"{len(references)} held-out default tracking plans (1 s each), horizon {config.horizon}, "
        f"{config.max_iterations} iLQR iterations per step, torch threads 1.", "",
        markdown_table(rows), "",
        f"Learned-model step time: {learned_row['solve_ms_mean']:.2f} ms mean, {learned_row['solve_ms_p95']:.2f} ms "
        f"p95 (goal <= 10 ms); {ratio_time:.3f}x the plant-model step time. Tracking q MSE: "
        f"{ratio_error:.3g}x the plant-model MPC's (goal <= 1.2x).", "",
        f"Machine: {machine_description(threads=1)}.",
        "Command: `python tools/bench_mpc.py --write`."])
    print(report)
    if args.write:
        write_benchmark_section("Deployment", "MPC control step (tools/bench_mpc.py)", report)


if __name__ == "__main__":
    main()
