"""The import round trip: a model trained on an imported log against one trained on its original data.

The import-versus-original experiment (docs/real_logs.md, designed before it ran): is a model trained on a log
imported by `stdm-drake import` as accurate as one trained on the data the log was written from?

40 tracked plans of the UR-10 at 500 Hz (paper's sensor) are collected, written as an RTDE recording (timing
jitter, 1 % dropped rows) and imported at 0.002 s; D models (`--model D`, 5 seeds, 100 epochs, derivative
source planned) are trained on each with the same split (24 / 8 / 8 plans, not per pose: the import keeps the
plans' order); both are evaluated on the original's 8 test plans (one-step and 20-step q MSE) beside the physics
baselines; the ratio import / original paired by seed with a 95 % interval. Success: the one-step ratio's
interval inside [0.8, 1.25].

    python tools/study.py import-round-trip [--quick] [--data /tmp/import_round_trip] [-o docs/results/real_logs]
"""
from __future__ import annotations

import argparse
import json
import pathlib
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
FULL = dict(plans=40, split=(24, 8, 8), seeds=5, epochs=100)
QUICK = dict(plans=8, split=(4, 2, 2), seeds=2, epochs=3)
ROLLOUT_STEPS = 20
SUCCESS = (0.8, 1.25)


def prepare(folder: pathlib.Path, design: dict, sensor: str | None = None) -> tuple[pathlib.Path, pathlib.Path]:
    """(the simulated dataset, its import), made once per folder; sensor: the sensor model's YAML (None: collect's
    default, the paper's)."""
    from stdm_drake.collection.collect_job import CollectJob, collect_job
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.data.logs import simulated
    from stdm_drake.data.logs.import_job import ImportJob, import_job
    from stdm_drake.paths import TRAJECTORIES_DIR
    folder.mkdir(parents=True, exist_ok=True)
    original, log, imported = folder / "original.h5", folder / "record.csv", folder / "imported.h5"
    if not original.exists():
        spec = folder / "tracking_500hz.yaml"
        spec.write_text((TRAJECTORIES_DIR / "tracking.yaml").read_text().replace("num_steps: 100", "num_steps: 500"))
        collect_job(CollectJob(output=original, protocol="tracking", config=spec, count=design["plans"], seed=3,
                               sample_period=0.002, sensor=None if sensor is None else pathlib.Path(sensor),
                               progress=False))
    if not imported.exists():
        simulated.write_rtde_csv(load_dataset(original), log)
        import_job(ImportJob(log=log, output=imported, progress=False))
    return original, imported


def train(dataset: pathlib.Path, folder: pathlib.Path, design: dict) -> pathlib.Path:
    """`train DATASET --model D` (the library's job) at the design's split, epochs and seeds, into `folder`
    (kept when its summary exists)."""
    from stdm_drake.learning.settings import TrainSettings
    from stdm_drake.learning.train_job import TrainJob, train_job
    if (folder / "summary.json").exists():
        return folder
    train_count, val, test = design["split"]
    given = dict(model="D", train=train_count, val=val, test=test, per_group="off", epochs=design["epochs"],
                 seeds=list(range(design["seeds"])))
    train_job(TrainJob(dataset=dataset, output=folder, settings=TrainSettings(**given), force=True, progress=False,
                       given=frozenset(given)))
    return folder


def evaluate(original_path, folders: dict, seeds: int) -> dict:
    """Per model (every seed of each folder) and baseline: one-step and 20-step q MSE on the original's test plans."""
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.dynamics.model_files import load_model
    from stdm_drake.learning.evaluate import compare_with_baselines, physics_baselines, trajectory_rollout_data
    from stdm_drake.robots.robot import UR10_CONFIG, load_robot
    robot = load_robot(UR10_CONFIG)
    data = load_dataset(original_path)
    models = {name: [load_model(pathlib.Path(folder) / f"seed{seed}" / "checkpoint.pt", robot,
                                name=f"{name} seed {seed}") for seed in range(seeds)] for name, folder in folders.items()}
    test = models["original"][0].checkpoint.split_indices(data, "test")
    imported_test = models["import"][0].checkpoint.metadata.split["test"]
    assert list(test) == list(imported_test), (test, imported_test)   # the same plans held out
    baselines = physics_baselines(data.sample_period, robot.state_dim, robot.action_dim, robot=robot,
                                  plant_config=data.metadata.plant_config(effects=False))
    every = baselines + [model for group in models.values() for model in group]
    rows = compare_with_baselines(every, data.transitions(list(test)), trajectory_rollout_data(data, test, ROLLOUT_STEPS))
    return {row.name: dict(one_step_q=row.one_step.angle_mse, one_step_v=row.one_step.velocity_mse,
                           q_at_20=float(row.multi_step.angle_mse[ROLLOUT_STEPS - 1]), verdict=row.verdict)
            for row in rows} | {"test_plans": [int(i) for i in test]}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="8 plans, 2 seeds, 3 epochs (a check that it runs)")
    parser.add_argument("--data", type=pathlib.Path, default=pathlib.Path("/tmp/import_round_trip"))
    parser.add_argument("-o", "--output", type=pathlib.Path, default=ROOT / "docs" / "results" / "real_logs")
    parser.add_argument("--sensor", type=pathlib.Path,
                        help="the sensor model the data are collected with (default: collect's, the paper's; run 2: "
                             "controllers/sensor_ideal.yaml)")


def run(args: argparse.Namespace) -> int:
    design = QUICK if args.quick else FULL
    started = time.perf_counter()
    original, imported = prepare(args.data, design, args.sensor)
    folders = {"original": train(original, args.data / "runs_original", design),
               "import": train(imported, args.data / "runs_import", design)}
    errors = evaluate(original, folders, design["seeds"])
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.stats import paired_ratio
    ratios = {}
    for key in ("one_step_q", "q_at_20"):
        ratios[key] = paired_ratio([errors[f"import seed {s}"][key] for s in range(design["seeds"])],
                                   [errors[f"original seed {s}"][key] for s in range(design["seeds"])]).as_dict()
    one_step = ratios["one_step_q"]
    learned = all(errors[f"{name} seed {s}"]["verdict"].startswith("learned")
                  for name in ("original", "import") for s in range(design["seeds"]))
    met = learned and one_step["low"] >= SUCCESS[0] and one_step["high"] <= SUCCESS[1]
    record = load_dataset(imported).metadata.record["import"]
    result = dict(written_by="tools/study.py import-round-trip", provenance=args.provenance, quick=args.quick, design=design,
                  sensor=str(args.sensor) if args.sensor else "collect's default (the paper's)",
                  success_interval=list(SUCCESS), every_model_learned=learned, met=met, import_over_original=ratios, errors=errors,
                  resampling=record["resampling"], trajectories=record["trajectories"],
                  seconds=round(time.perf_counter() - started, 1))
    args.output.mkdir(parents=True, exist_ok=True)
    from stdm_drake.files import json_default, write_text_atomic
    write_text_atomic(args.output / "round_trip.json", json.dumps(result, indent=1, default=json_default) + "\n")
    lines = ["| model | one-step q MSE (rad²) | q MSE at step 20 | verdict |", "|---|---|---|---|"]
    for name in ("Euler step", "stays put", "plant", "original", "import"):
        found = [value for key, value in errors.items() if key == name or key.startswith(f"{name} seed ")]
        one = np.exp(np.mean(np.log([row["one_step_q"] for row in found])))
        twenty = np.exp(np.mean(np.log([row["q_at_20"] for row in found])))
        verdicts = ", ".join(sorted({row["verdict"] for row in found if row["verdict"]})) or "-"
        lines.append(f"| {name}{' (D, ' + str(len(found)) + ' seeds)' if len(found) > 1 else ''} | {one:.3g} | "
                     f"{twenty:.3g} | {verdicts} |")
    text = "\n".join(lines + ["", f"import / original, one step: {one_step['ratio']:.3g}x [{one_step['low']:.3g}, "
                                  f"{one_step['high']:.3g}]; at step 20: {ratios['q_at_20']['ratio']:.3g}x "
                                  f"[{ratios['q_at_20']['low']:.3g}, {ratios['q_at_20']['high']:.3g}]; success "
                                  f"(one-step interval inside {SUCCESS}, every model learned): "
                                  f"{'met' if met else 'not met' if learned else 'uninformative (not every model learned)'}",
                                  ""])
    write_text_atomic(args.output / "round_trip.md", text)
    print(text)
    return 0

