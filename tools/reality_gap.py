"""The reality-gap experiment: learned models against the nominal model on an affected UR-10 plant
(design, endpoints and success criteria in docs/reality_gap.md, fixed before the run).

Usage: python tools/reality_gap.py [--quick] [--workers 2] [-o docs/results/reality_gap]
       [--data out/reality_gap_data]

Part 1 (closed loop): D and DD models (`train`'s defaults, 5 seeds) on dithered-PID tracking data of the
plant with models/ur10_effects.yaml; MPC with the nominal plant, the true plant and each learned model
on the test plans, observer on and off; the torque Jacobian of each model against the true plant's.
Part 2 (open loop per effect): the same per plant with friction only, rotor inertia only, payload only
and all effects: one-step and 20/100-step errors of the nominal model, the learned models and the
physics-free baselines. Datasets and checkpoints are kept in --data and reused by a rerun.
"""
import argparse
import json
import os
import pathlib
import sys
import time


os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from stdm_drake.experiments.reality_gap import (EFFECTS_PRESET, FULL, QUICK, TYPES, closed_loop_group,  # noqa: E402
                                                closed_loop_summary, dataset, effect_plants, open_loop_rows,
                                                torque_jacobian_errors, train)
from stdm_drake.files import json_default, rows_csv, write_text_atomic  # noqa: E402

def table(rows: list) -> str:
    """CSV of rows with different keys: every key a column, empty where a row lacks it."""
    columns = list(dict.fromkeys(key for row in rows for key in row))
    return rows_csv([{column: row.get(column, "") for column in columns} for row in rows], columns)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=pathlib.Path, default=ROOT / "docs" / "results" / "reality_gap")
    parser.add_argument("--data", type=pathlib.Path, default=ROOT / "out" / "reality_gap_data")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--quick", action="store_true", help="tiny sizes: a pipeline check (about 2 min)")
    args = parser.parse_args(argv)
    from stdm_drake.cluster import RunnerConfig, job_pool
    from stdm_drake.robots.effects import load_plant_effects
    from stdm_drake.robots.robot import UR10_CONFIG, load_robot
    design = QUICK if args.quick else FULL
    started = time.perf_counter()
    args.data.mkdir(parents=True, exist_ok=True)
    preset = load_plant_effects(EFFECTS_PRESET)
    plans, train_count, val_count, test_count, seeds, epochs = design["closed"]
    closed = dataset(args.data, "closed_loop", preset, plans, 0)
    o_plans, o_train, o_val, o_test, o_seeds, o_epochs = design["open"]
    plants = {name: dataset(args.data, f"open_loop_{name}", effects, o_plans, 1)
              for name, effects in effect_plants(preset, load_robot(UR10_CONFIG)).items()}
    print(f"datasets in {time.perf_counter() - started:.0f} s", flush=True)
    trainings = [(str(closed.path), model_type, (train_count, val_count, test_count), seeds, epochs,
                  str(args.data / "runs" / f"closed_loop_{model_type}")) for model_type in TYPES]
    trainings += [(str(data.path), model_type, (o_train, o_val, o_test), o_seeds, o_epochs,
                   str(args.data / "runs" / f"open_loop_{name.replace(' ', '_')}_{model_type}"))
                  for name, data in plants.items() for model_type in TYPES]
    with job_pool(RunnerConfig(workers=args.workers)) as pool:
        folders = [future.result() for future in [pool.submit(train, *call) for call in trainings]]
    print(f"models trained in {time.perf_counter() - started:.0f} s", flush=True)
    closed_folders = dict(zip(TYPES, folders[:len(TYPES)]))
    checkpoints = [str(pathlib.Path(folder) / f"seed{seed}" / "checkpoint.pt")
                   for folder in closed_folders.values() for seed in range(seeds)]
    test_plans = 4 * test_count
    learned_specs = [(f"{t} seed {s}", str(pathlib.Path(closed_folders[t]) / f"seed{s}" / "checkpoint.pt"))
                     for t in TYPES for s in range(seeds)]
    by_type = [[spec for spec in learned_specs if spec[0].startswith(f"{t} ")] for t in TYPES]
    groups = [([("plant", None)], True), ([("true-plant", "true")], True), *[(specs, True) for specs in by_type],
              ([("plant", None)], False), *[(specs, False) for specs in by_type]]
    with job_pool(RunnerConfig(workers=args.workers)) as pool:
        futures = [pool.submit(closed_loop_group, specs, str(closed.path), checkpoints, test_plans,
                               design["mpc_steps"], observer) for specs, observer in groups]
        runs = [run for future in futures for run in future.result()]
    print(f"closed loops in {time.perf_counter() - started:.0f} s", flush=True)
    summary = closed_loop_summary(runs, seeds)
    jacobians = torque_jacobian_errors(str(closed.path), closed_folders, seeds)
    open_loop = [row for index, (name, data) in enumerate(plants.items())
                 for row in open_loop_rows(name, str(data.path), dict(zip(TYPES, folders[len(TYPES) * (index + 1):
                                                                                       len(TYPES) * (index + 2)])),
                                           o_seeds)]
    args.output.mkdir(parents=True, exist_ok=True)
    flat = [dict({k: v for k, v in row.items() if k != "nominal_over_model"},
                 **{f"nominal_over_model_{k}": v for k, v in row["nominal_over_model"].items()}) for row in summary]
    write_text_atomic(args.output / "closed_loop.csv", table(flat))
    open_flat = [dict({k: v for k, v in row.items() if k not in ("learned", "beats_nominal_every_seed")},
                      **{f"beats_nominal_{k}": v for k, v in row.get("beats_nominal_every_seed", {}).items()})
                 for row in open_loop]
    write_text_atomic(args.output / "open_loop.csv", table(open_flat))
    write_text_atomic(args.output / "results.json", json.dumps(dict(
        written_by="tools/reality_gap.py", quick=args.quick, design=design, effects=preset.record(),
        seconds=round(time.perf_counter() - started, 1), closed_loop=summary, torque_jacobian=jacobians,
        open_loop=open_loop, runs=[{k: v for k, v in run.items() if k != "q_error"} for run in runs]),
        indent=1, default=json_default) + "\n")
    for row in summary:
        ratio = row["nominal_over_model"]
        interval = f" [{ratio['low']:.3g}, {ratio['high']:.3g}]" if "low" in ratio else ""
        print(f"observer {'on ' if row['observer'] else 'off'} {row['model']:>10}: q MSE {row['q_mse']:.3g} rad², "
              f"nominal / model {ratio['ratio']:.3g}x{interval}, violations {row['limit_violations']}, "
              f"solve {row['solve_ms_mean']:.1f} ms")
    for row in jacobians:
        print(f"torque Jacobian B, {row['model']}: median relative error {row['relative_error']:.3g}")
    for row in open_loop:
        print(f"{row['plant']:>14} {row['model']:>38}: one-step q {row['one_step_q']:.3g}, q@20 "
              f"{row['open_loop_q_20']:.3g}, q@end {row['open_loop_q_end']:.3g}")
    print(f"-> {args.output} in {time.perf_counter() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
