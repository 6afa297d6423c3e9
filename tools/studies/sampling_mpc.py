"""Sampling MPC (iCEM, MPPI, CEM) against the iLQR on learned models of the affected UR-10 (docs/sampling_mpc.md, Part A).

    python tools/study.py sampling-mpc [--quick] [--workers 2] [-o docs/results/sampling_mpc] [--data out/sampling_mpc_data]

The reality gap's closed-loop data (run 2's protocol and split); the paper's black boxes D, DD, PE, PED (5
seeds); each sampling optimizer's noise (and MPPI's temperature) chosen on the validation plans with seed 0
of D and of PE; then every model under the iLQR and under each sampling optimizer on the test plans, the
nominal and the true plant as reference rows, PE under iCEM with the variance penalty. Per model type and
optimizer: the seed-level paired ratio iLQR q MSE / optimizer q MSE with its 95 % interval and the design's
verdict, limit violations and time per control step. Datasets, checkpoints and every finished closed-loop
group are kept in --data, so a stopped run resumes.
"""
import argparse
import dataclasses
import hashlib
import json
import math
import pathlib
import time

import numpy as np

TYPES = ("D", "DD", "PE", "PED")
SETTING = (1e-4, 1.0)                # (effort-weight scale, observer gain): run 2's choice for every learned model
# (plans per start pose: train / val / test, seeds, max epochs, test and validation plans used per pose, steps)
FULL = dict(split=(18, 2, 5), seeds=5, epochs=300, per_pose=2, steps=None)
QUICK = dict(split=(1, 1, 1), seeds=2, epochs=3, per_pose=1, steps=6)
# the optimizers' budgets (docs/sampling_mpc.md) and, for the sampling ones, the grid chosen from on validation
BUDGETS = {"iLQR": ("Ilqr", dict(max_iterations=1)),
           "iCEM": ("Icem", dict(samples=100, iterations=3, elites=10)),
           "MPPI": ("Mppi", dict(samples=100, iterations=1)),
           "CEM": ("Cem", dict(samples=400, iterations=5, elites=40))}
GRIDS = {"iCEM": [dict(noise_std=s) for s in (0.3, 1.0, 3.0)],
         "MPPI": [dict(noise_std=s, temperature=t) for s in (0.3, 1.0, 3.0) for t in (0.03, 0.3)],
         "CEM": [dict(noise_std=s) for s in (0.3, 1.0, 3.0)]}
# run 2 (docs/sampling_mpc.md, "Part A, run 2"): run 1's grids extended past every choice that fell at an edge
# (MPPI's temperature at the top, PE's MPPI noise at the bottom, CEM's noise at the top), iCEM's unchanged
GRIDS_BY_RUN = {1: GRIDS,
                2: {"iCEM": GRIDS["iCEM"],
                    "MPPI": [dict(noise_std=s, temperature=t) for s in (0.1, 0.3, 1.0, 3.0) for t in (0.03, 0.3, 3.0, 30.0)],
                    "CEM": [dict(noise_std=s) for s in (0.3, 1.0, 3.0, 10.0)]}}
PARTICLES = dict(propagation="tsinf", particles=5)     # PE and PED: one particle per member


def family(model_type: str) -> str:
    """The model whose seed 0 chooses a type's sampling settings: D (D, DD) or PE (PE, PED)."""
    return "PE" if model_type.startswith("P") else "D"


def optimizer_settings(name: str, model_type: str | None, extra: dict):
    """The OptimizerSettings of optimizer `name` for a model of `model_type` (None: a plant), with `extra`."""
    from stdm_drake.closed_loop.mpc import OptimizerConfig
    import typing
    kinds = {cls.__name__: cls for cls in typing.get_args(OptimizerConfig)}
    tag, budget = BUDGETS[name]
    fields = dict(budget, **(PARTICLES if name != "iLQR" and model_type in ("PE", "PED") else {}), **extra)
    return kinds[tag](**fields)


def chosen_references(data, checkpoint_path: str, split: str, per_pose: int, steps) -> list:
    """The first `per_pose` plans of each start pose in the checkpoint's `split`, as (index, Reference)."""
    from studies.reality_gap import plan_references
    seen, chosen = {}, []
    for index, reference in plan_references(data, checkpoint_path, split, steps):
        group = int(data.groups[index])
        if seen.get(group, 0) < per_pose:
            seen[group] = seen.get(group, 0) + 1
            chosen.append((index, reference))
    return chosen


def closed_loop_group(job: dict, cache: str) -> list:
    """The closed loops of one model under one optimizer on one split's chosen plans (ClosedLoopResult dicts with
    the job's labels), cached in `cache` (a rerun reads them)."""
    key = hashlib.sha256(json.dumps(job, sort_keys=True).encode()).hexdigest()[:20]
    path = pathlib.Path(cache) / f"{key}.json"
    if path.exists():
        return json.loads(path.read_text())
    import torch
    torch.set_num_threads(1)
    from stdm_drake.closed_loop.comparison import compare_controllers, spec_models
    from stdm_drake.closed_loop.mpc import mpc_config_for
    from stdm_drake.closed_loop.tuning import with_setting
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.robots.plant import PlantConfig
    from stdm_drake.robots.robot import load_robot
    robot = load_robot(job["robot"])
    data = load_dataset(job["dataset"])
    plant = PlantConfig.discrete(data.metadata.plant_time_step, effects=data.metadata.plant_effects)
    references = chosen_references(data, job["split_checkpoint"], job["split"], job["per_pose"], job["steps"])
    config = with_setting(mpc_config_for(robot), SETTING)
    optimizer = optimizer_settings(job["optimizer"], job["type"], job["extra"])
    models = spec_models([(job["model"], job["checkpoint"])], data.sample_period, plant, robot=robot)
    results = compare_controllers(models, references, config, plant, progress=False, robot=robot, optimizer=optimizer)
    rows = [dict({k: v for k, v in dataclasses.asdict(result).items() if k != "q_error"}, split=job["split"],
                 optimizer=job["optimizer"], type=job["type"], seed=job["seed"], variant=job["variant"],
                 extra=job["extra"]) for result in results]
    from stdm_drake.files import write_text_atomic
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(rows))
    return rows


def one_step_gate(dataset_path: str, checkpoint: str, robot_path: str) -> dict:
    """A model's one-step test MSE (q rad², v (rad/s)²) against the physics-free baselines and its verdict."""
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.dynamics.physics import ConstantVelocity
    from stdm_drake.dynamics.verdict import learning_verdict
    from stdm_drake.learning.learned_model import LearnedModel
    from stdm_drake.robots.robot import load_robot
    data = load_dataset(dataset_path)
    model = LearnedModel(checkpoint, robot=load_robot(robot_path))
    pairs = data.transitions(model.checkpoint.split_indices(data, "test"))
    n = model.num_joints
    errors = {}
    for name, predictor in (("model", model), ("euler", ConstantVelocity(2 * n, n, data.sample_period))):
        residual = predictor.step(pairs.state, pairs.action) - pairs.next_state
        errors[name] = (float(np.mean(residual[:, :n] ** 2)), float(np.mean(residual[:, n:] ** 2)))
    ratio_q, ratio_v = errors["euler"][0] / errors["model"][0], errors["euler"][1] / errors["model"][1]
    return dict(q_mse=errors["model"][0], v_mse=errors["model"][1], euler_over_model_q=ratio_q,
                v_unchanged_over_model_v=ratio_v, verdict=learning_verdict(ratio_q, ratio_v))


def cell_verdict(interval: dict, reference: str = "iLQR") -> str:
    """The design's verdict on a ratio reference MSE / optimizer MSE with its interval."""
    if interval.get("low") is None:
        return "one seed: no interval"
    if interval["low"] > 1:
        return f"better than {reference}"
    if interval["low"] >= 1 / 1.5:
        return f"within 1.5x of {reference}"
    if interval["high"] < 1 / 1.5:
        return f"worse than 1.5x {reference}"
    return "inconclusive"


def summary(runs: list, seeds: int, gates: dict) -> list:
    """Per model type and optimizer (variant): q MSE, the paired seed-level ratio to the same seeds under the iLQR
    (or, for the variance penalty, under iCEM without it) with its interval and verdict, violations, times."""
    from studies.reality_gap import seed_interval
    from stdm_drake.closed_loop.tuning import finite_mse
    test = [run for run in runs if run["split"] == "test"]
    rows = []
    for model_type in TYPES:
        for variant in dict.fromkeys(run["variant"] for run in test if run["type"] == model_type):
            mine = [run for run in test if run["type"] == model_type and run["variant"] == variant]
            reference_variant = "iCEM" if variant == "iCEM, variance weight 1" else "iLQR"
            logs = []
            for seed in range(seeds):
                base = {run["trajectory"]: run["q_mse_rad2"] for run in test if run["type"] == model_type
                        and run["variant"] == reference_variant and run["seed"] == seed}
                own = [run for run in mine if run["seed"] == seed]
                if own and base:
                    logs.append(float(np.mean([math.log(finite_mse(base[run["trajectory"]]) / finite_mse(run["q_mse_rad2"]))
                                               for run in own])))
            interval = seed_interval(logs) if variant != "iLQR" and logs else None
            rows.append(dict(model=model_type, optimizer=variant, models=len({run["seed"] for run in mine}),
                             runs=len(mine), q_mse=float(np.exp(np.mean([math.log(finite_mse(r["q_mse_rad2"])) for r in mine]))),
                             against=None if interval is None else reference_variant, ratio=interval,
                             verdict=None if interval is None else cell_verdict(interval, reference_variant),
                             limit_violations=int(sum(r["limit_violations"] for r in mine)),
                             runs_leaving_limits=int(sum(r["limit_violations"] > 0 for r in mine)),
                             fallbacks=int(sum(r["fallbacks"] for r in mine)),
                             solve_ms_mean=float(np.mean([r["solve_ms_mean"] for r in mine])),
                             solve_ms_p95_max=float(np.max([r["solve_ms_p95"] for r in mine])),
                             learned=[gates[f"{model_type} seed {s}"]["verdict"] for s in range(seeds)]))
    for name in ("plant", "true-plant"):
        for variant in ("iLQR", "iCEM"):
            mine = [run for run in test if run["type"] == name and run["variant"] == variant]
            if mine:
                rows.append(dict(model=name, optimizer=variant, models=1, runs=len(mine),
                                 q_mse=float(np.exp(np.mean([math.log(finite_mse(r["q_mse_rad2"])) for r in mine]))),
                                 against=None, ratio=None, verdict=None,
                                 limit_violations=int(sum(r["limit_violations"] for r in mine)),
                                 runs_leaving_limits=int(sum(r["limit_violations"] > 0 for r in mine)),
                                 fallbacks=int(sum(r["fallbacks"] for r in mine)),
                                 solve_ms_mean=float(np.mean([r["solve_ms_mean"] for r in mine])),
                                 solve_ms_p95_max=float(np.max([r["solve_ms_p95"] for r in mine])), learned=None))
    return rows


def goal(rows: list) -> dict:
    """The issue's goal: PE within 1.5x of the iLQR (or better) under at least one sampling optimizer, no limit left."""
    cells = [row for row in rows if row["model"] == "PE" and row["against"] == "iLQR"]
    met = [row["optimizer"] for row in cells if row["verdict"] in ("within 1.5x of iLQR", "better than iLQR")
           and row["limit_violations"] == 0]
    text = ("met by " + ", ".join(met)) if met else "not met: " + "; ".join(
        f"{row['optimizer']}: iLQR's q MSE / its {row['ratio']['ratio']:.3g}x [{row['ratio']['low']:.3g}, "
        f"{row['ratio']['high']:.3g}], {row['limit_violations']} steps outside the limits" for row in cells if row["ratio"]
        and row["ratio"].get("low") is not None)
    return dict(met=bool(met), text=f"PE within 1.5x of iLQR with no limit left: {text}")


def run_experiment(design: dict, data_folder: pathlib.Path, robot, effects, workers: int = 2, say=print,
                   grids: dict = GRIDS) -> dict:
    from stdm_drake.cluster import RunnerConfig, job_pool
    from stdm_drake.closed_loop.tuning import best_setting
    from studies.reality_gap import dataset, start_poses, train
    started = time.perf_counter()
    data_folder = pathlib.Path(data_folder)
    data_folder.mkdir(parents=True, exist_ok=True)
    poses = start_poses(robot)
    train_count, val_count, test_count = design["split"]
    seeds, epochs = design["seeds"], design["epochs"]
    closed = dataset(data_folder, "closed_loop", effects, poses * (train_count + val_count + test_count), 0, robot,
                     workers)
    config = str(robot.config_path)
    with job_pool(RunnerConfig(workers=workers)) as pool:
        futures = [pool.submit(train, str(closed.path), model_type, design["split"], seeds, epochs,
                               str(data_folder / "runs" / f"paper_{model_type}"), config, None, "state", "raw")
                   for model_type in TYPES]
        folders = dict(zip(TYPES, [future.result() for future in futures]))
    say(f"sampling-mpc: {len(TYPES) * seeds} models trained in {time.perf_counter() - started:.0f} s")
    checkpoint = {f"{t} seed {s}": str(pathlib.Path(folders[t]) / f"seed{s}" / "checkpoint.pt")
                  for t in TYPES for s in range(seeds)}
    gates = {name: one_step_gate(str(closed.path), path, config) for name, path in checkpoint.items()}
    split_checkpoint = checkpoint["D seed 0"]
    cache = str(data_folder / "closed_loops")

    def job(model_type, seed, optimizer, split, extra=None, variant=None, name=None, path=None):
        name = name or f"{model_type} seed {seed}"
        return dict(robot=config, dataset=str(closed.path), split_checkpoint=split_checkpoint, split=split,
                    per_pose=design["per_pose"], steps=design["steps"], model=name,
                    checkpoint=checkpoint.get(name) if path is None else path, type=model_type, seed=seed,
                    optimizer=optimizer, extra=extra or {}, variant=variant or optimizer)

    tuning_jobs = [job(kind, 0, name, "val", extra) for kind in ("D", "PE") for name, grid in grids.items()
                   for extra in grid]
    with job_pool(RunnerConfig(workers=workers)) as pool:
        tuning = [row for rows in [future.result() for future in
                                   [pool.submit(closed_loop_group, spec, cache) for spec in tuning_jobs]] for row in rows]
    chosen = {}
    for kind in ("D", "PE"):
        for name, grid in grids.items():
            runs_by = {tuple(sorted(extra.items())): [run for run in tuning if run["type"] == kind and
                                                      run["optimizer"] == name and run["extra"] == extra]
                       for extra in grid}
            chosen[f"{kind} {name}"] = dict(best_setting(runs_by))
    say(f"sampling-mpc: settings chosen on the validation plans in {time.perf_counter() - started:.0f} s: {chosen}")
    test_jobs = [job(t, s, name, "test", chosen.get(f"{family(t)} {name}")) for t in TYPES for s in range(seeds)
                 for name in BUDGETS]
    test_jobs += [job("PE", s, "iCEM", "test", dict(chosen["PE iCEM"], variance_weight=1.0), "iCEM, variance weight 1")
                  for s in range(seeds)]
    test_jobs += [job(name, 0, optimizer, "test", chosen.get(f"D {optimizer}"), name=name,
                      path=None if name == "plant" else "true")
                  for name in ("plant", "true-plant") for optimizer in ("iLQR", "iCEM")]
    with job_pool(RunnerConfig(workers=workers)) as pool:
        futures = [pool.submit(closed_loop_group, spec, cache) for spec in test_jobs]
        runs = [row for future in futures for row in future.result()]
    say(f"sampling-mpc: closed loops in {time.perf_counter() - started:.0f} s")
    rows = summary(runs, seeds, gates)
    return dict(robot=robot.name, design=design, setting=SETTING, budgets=BUDGETS, grids=grids, effects=effects.record(),
                seconds=round(time.perf_counter() - started, 1), gates=gates, chosen=chosen, summary=rows,
                goal=goal(rows), tuning_runs=tuning, runs=runs)


def write_results(results: dict, folder: pathlib.Path) -> None:
    import csv
    import io
    from stdm_drake.files import write_text_atomic
    folder.mkdir(parents=True, exist_ok=True)
    write_text_atomic(folder / "results.json", json.dumps(results, indent=1))
    flat = [dict({k: v for k, v in row.items() if k not in ("ratio", "learned")},
                 ratio=None if not row["ratio"] else row["ratio"]["ratio"],
                 low=None if not row["ratio"] else row["ratio"].get("low"),
                 high=None if not row["ratio"] else row["ratio"].get("high"),
                 learned=None if row["learned"] is None else sum(v.startswith("learned") for v in row["learned"]))
            for row in results["summary"]]
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=list(flat[0]))
    writer.writeheader()
    writer.writerows(flat)
    write_text_atomic(folder / "summary.csv", text.getvalue())


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from studies.affected_plant import add_affected_plant_arguments
    add_affected_plant_arguments(parser, "sampling_mpc", quick_minutes=3)
    parser.add_argument("--run", type=int, choices=sorted(GRIDS_BY_RUN), default=1,
                        help="the design's run: 1 (Part A as designed) or 2 (the sampling grids extended past run 1's "
                             "edge choices; default output docs/results/sampling_mpc/run2)")


def run(args: argparse.Namespace) -> int:
    from studies.affected_plant import ROOT, quick_folders, robot_and_effects
    quick_folders(args, "sampling_mpc")
    if args.run > 1 and not args.quick and args.output == ROOT / "docs" / "results" / "sampling_mpc":
        args.output = args.output / f"run{args.run}"
    robot, effects = robot_and_effects(args)
    results = run_experiment(QUICK if args.quick else FULL, args.data, robot, effects, workers=args.workers,
                             say=lambda line: print(line, flush=True), grids=GRIDS_BY_RUN[args.run])
    results = dict(written_by="tools/study.py sampling-mpc", provenance=args.provenance, quick=args.quick,
                   run=args.run, **results)
    write_results(results, args.output)
    for row in results["summary"]:
        ratio = row["ratio"]
        text = "" if not ratio else (f", {row['against']} / this {ratio['ratio']:.3g}x" +
                                     (f" [{ratio['low']:.3g}, {ratio['high']:.3g}]" if ratio.get("low") else "")
                                     + f": {row['verdict']}")
        print(f"{row['model']:>10} {row['optimizer']:>24}: q MSE {row['q_mse']:.3g} rad²{text}, steps outside the "
              f"limits {row['limit_violations']}, solve {row['solve_ms_mean']:.1f} ms")
    print(results["goal"]["text"])
    print(f"-> {args.output} in {results['seconds']:.0f} s")
    return 0
