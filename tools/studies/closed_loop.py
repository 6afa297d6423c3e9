"""Closed-loop MPC with the trained model as the unit: D against DD over 10 initialization seeds.

Design and reading: docs/learning.md, "Closed loop with the trained model as the unit" (fixed before
the run). Identification data as `stdm-drake reproduce` collects them; D and DD of each seed share
the initialization; every model controls the same held-out plans; the seed-level ratio D/DD (plans
averaged within a seed) gets a Student-t 95 % interval over seeds.

    python tools/study.py closed-loop [--seeds 10] [--plans 10] [--quick] [-o docs/results/closed_loop]
"""
import argparse
import json
import pathlib
import sys
import time

import numpy as np

from stdm_drake.cluster import RunnerConfig, job_pool
from stdm_drake.files import rows_csv, write_text_atomic
from stdm_drake.robots.robot import UR10_CONFIG, load_robot

ROOT = pathlib.Path(__file__).resolve().parents[2]

ALPHA = 1e-3
TYPES = {"D": 0.0, "DD": ALPHA}


def identification_dataset(folder: pathlib.Path, count: int):
    from stdm_drake.experiments.jobs import ensure_dataset
    return ensure_dataset("tracking", count, 0, folder, False, name="identification", robot=UR10_CONFIG,
                          controller=str(ROOT / "controllers" / "pid_dither.yaml"),
                          sensor=str(ROOT / "controllers" / "sensor_ideal.yaml"))


def train_job(path: str, split: dict, model_type: str, seed: int, epochs: int, folder: str) -> dict:
    import torch

    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.learning.checkpoint import save_checkpoint
    from stdm_drake.dynamics.model_files import load_model
    from stdm_drake.learning.evaluate import compare_with_baselines, physics_baselines, trajectory_rollout_data
    from stdm_drake.learning.settings import TrainingConfig
    from stdm_drake.learning.structure import PAPER
    from stdm_drake.learning.problem import training_problem
    from stdm_drake.learning.alpha_selection import fit_model
    torch.set_num_threads(1)
    dataset = load_dataset(path)
    problem = training_problem(dataset, split, model_type=model_type, derivative_source="true",
                               action_rate="zero_order_hold", structure=PAPER, threads=1)
    started = time.perf_counter()
    result, _ = fit_model(problem.model_config, TrainingConfig(alpha=TYPES[model_type], seed=seed, max_epochs=epochs),
                          problem.train, problem.val, metadata=problem.metadata)
    seconds = time.perf_counter() - started
    checkpoint = pathlib.Path(folder) / f"{model_type}_seed{seed}.pt"
    save_checkpoint(checkpoint, result.model, training_config=TrainingConfig(alpha=TYPES[model_type], seed=seed,
                                                                           max_epochs=epochs),
                    history=result.history, metadata=problem.metadata)
    model = load_model(checkpoint, load_robot(UR10_CONFIG))
    test = split["test"]
    mine, _, _ = compare_with_baselines([model] + physics_baselines(dataset.sample_period, model.state_dim, model.action_dim, plant=False),
                                        dataset.transitions(test), trajectory_rollout_data(dataset, test, 20))
    return dict(model_type=model_type, seed=seed, checkpoint=str(checkpoint), epochs=result.epochs_run,
                best_epoch=int(result.best_epochs[0]), train_seconds=round(seconds, 1),
                one_step_q=mine.one_step.angle_mse, one_step_v=mine.one_step.velocity_mse,
                ratio_to_euler_q=mine.ratio_q, ratio_to_unchanged_v=mine.ratio_v, verdict=mine.verdict)


def mpc_job(name: str, checkpoint: str | None, references, sample_period: float) -> list[dict]:
    import torch

    from stdm_drake.closed_loop.comparison import compare_controllers
    from stdm_drake.closed_loop.mpc import load_mpc_config
    from stdm_drake.dynamics.model_files import load_model
    from stdm_drake.dynamics.physics import PlantModel
    torch.set_num_threads(1)
    robot = load_robot(UR10_CONFIG)
    model = (PlantModel(sample_period, robot=robot, integrator="rk4") if checkpoint is None
             else load_model(checkpoint, robot, name=name, for_control=True))
    runs = compare_controllers([model], references, load_mpc_config(), progress=False, robot=robot)
    return [dict(model=name, plan=run.trajectory, q_mse=run.q_mse_rad2, v_mse=run.v_mse,
                 limit_violations=run.limit_violations, fallbacks=run.fallbacks, solve_ms=run.solve_ms_mean)
            for run in runs]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-o", "--output", type=pathlib.Path, default=ROOT / "docs" / "results" / "closed_loop")
    parser.add_argument("--data", type=pathlib.Path, default=ROOT / "out" / "closed_loop_data")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--plans", type=int, default=10)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--quick", action="store_true", help="2 seeds, 2 plans of 30 steps, 20 epochs (pipeline check)")


def run(args: argparse.Namespace) -> int:
    from stdm_drake.closed_loop.comparison import held_out_references
    from stdm_drake.data.dataset import split_trajectories
    from stdm_drake.learning.checkpoint import load_checkpoint
    from stdm_drake.stats import paired_ratio
    seeds, plans, epochs, count = (2, 2, 20, 20) if args.quick else (args.seeds, args.plans, 300, 100)
    per_pose = (3, 1, 1) if args.quick else (18, 2, 5)
    args.data.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    dataset = identification_dataset(args.data, count)
    split = split_trajectories(dataset.groups, *per_pose, seed=0, per_group=True).as_dict()
    split = {key: [int(i) for i in value] for key, value in split.items()}
    with job_pool(RunnerConfig(workers=args.workers)) as pool:
        trained = [future.result() for future in [pool.submit(train_job, str(dataset.path), split, model_type, seed,
                                                              epochs, str(args.data))
                                                  for seed in range(seeds) for model_type in TYPES]]
        print(f"{len(trained)} models trained ({time.perf_counter() - started:.0f} s)", flush=True)
        references = held_out_references(dataset, [load_checkpoint(row["checkpoint"]) for row in trained], plans)
        if args.quick:
            from stdm_drake.closed_loop.mpc import Reference
            references = [(i, Reference(q=r.q[:31], v=r.v[:31])) for i, r in references]
        specs = [("plant", None)] + [(f"{row['model_type']} seed {row['seed']}", row["checkpoint"]) for row in trained]
        runs = [run for future in [pool.submit(mpc_job, name, path, references, dataset.sample_period)
                                   for name, path in specs] for run in future.result()]
    print(f"{len(runs)} closed-loop runs ({time.perf_counter() - started:.0f} s)", flush=True)

    def per_seed(model_type):   # geometric mean over plans of each seed's closed-loop q MSE
        return [float(np.exp(np.mean([np.log(run["q_mse"]) for run in runs if run["model"] == f"{model_type} seed {s}"])))
                for s in range(seeds)]
    plant = float(np.exp(np.mean([np.log(run["q_mse"]) for run in runs if run["model"] == "plant"])))
    seed_means = {model_type: per_seed(model_type) for model_type in TYPES}
    ratio = paired_ratio(seed_means["D"], seed_means["DD"])
    summary = dict(plant_q_mse=plant, seeds=seeds, plans=len(references),
                   per_seed_q_mse=seed_means, D_over_DD=ratio.as_dict(),
                   over_plant={t: paired_ratio(values, [plant] * seeds).as_dict() | dict(
                       geometric_mean=float(np.exp(np.mean(np.log(np.array(values) / plant)))))
                       for t, values in seed_means.items()},
                   limit_violations={t: sum(run["limit_violations"] for run in runs if run["model"].startswith(t + " "))
                                     for t in TYPES},
                   gate={t: [row["verdict"] for row in trained if row["model_type"] == t] for t in TYPES},
                   solve_ms={name: float(np.mean([run["solve_ms"] for run in runs if run["model"].split(" seed")[0] == name]))
                             for name in ["plant", *TYPES]})
    elapsed = time.perf_counter() - started
    args.output.mkdir(parents=True, exist_ok=True)
    trained = [dict(row, checkpoint=pathlib.Path(row["checkpoint"]).name) for row in trained]   # (in --data)
    write_text_atomic(args.output / "models.csv", rows_csv(trained))
    write_text_atomic(args.output / "runs.csv", rows_csv(runs))
    write_text_atomic(args.output / "results.json", json.dumps(dict(
        written_by="tools/study.py closed-loop", provenance=args.provenance, quick=args.quick, alpha=ALPHA, epochs=epochs, split=split,
        references=[index for index, _ in references], seconds=round(elapsed, 1), summary=summary,
        models=trained, runs=runs), indent=2) + "\n")
    print(f"plant MPC q MSE {plant:.3g}; D/DD over {seeds} seeds: {ratio.text()} {ratio.verdict}")
    for t in TYPES:
        print(f"{t}: {summary['over_plant'][t]['geometric_mean']:.3g}x the plant MPC's q MSE, "
              f"{summary['limit_violations'][t]} limit violations, gate {summary['gate'][t]}")
    print(f"{elapsed:.0f} s -> {args.output}")
    violated = {run["model"] for run in runs if run["limit_violations"]}
    for name in sorted(violated):
        steps = sum(run["limit_violations"] for run in runs if run["model"] == name)
        print(f"error: the closed loop of {name} left the robot's joint limits on {steps} steps", file=sys.stderr)
    return 2 if violated else 0

