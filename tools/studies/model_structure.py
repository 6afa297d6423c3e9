"""The structure study: what each modelling choice buys on the UR-10's default excitation protocol.

Each choice beside the physics baselines. Design and success criteria: docs/learning.md, "Models that learn:
the structure study" (written before the first run). Training data: `collect --protocol excitation` with the
default seed 0; the first 40 (or 160) trajectories of a seed-0 split train, 40 validate (early stopping, the
only selection); every number is measured on a second dataset of the same protocol collected with a seed never
used before (HELD_OUT_SEED), all of its trajectories. Each configuration is trained from SEEDS initializations
(3 x 100 swish, Adam 1e-3, batch 64, <= 500 epochs, patience 50: `stdm-drake train`'s defaults).

Configurations (model D unless named; "state" = the network predicts x_{t+1} - x_t, "velocity" =
v_{t+1} - v_t with q by the trapezoid rule; "raw" = inputs [q, v, τ], "nominal" = plus the nominal
model's acceleration M⁻¹(τ + τ_g − C v)):

    paper            state, raw       (the paper's black box)
    velocity         velocity, raw
    nominal          state, nominal
    default          velocity, nominal (what `stdm-drake train` uses)
    default-n160     default with 160 training trajectories
    default-DD       default trained with the derivative loss at alpha 1e-3 ("our units", see docs)

Per run: one-step q and v MSE, open-loop q MSE at step 20, and the ratios to the physics-free
baselines (Euler step for q, "v unchanged" for v, "stays put" for open-loop q). Paired comparisons
(same initialization seed) with 95 % intervals: each choice against the configuration it changes.

    python tools/study.py model-structure [--quick] [--seeds N] [--workers 2] [-o docs/results/model_structure]
"""
import argparse
import json
import pathlib
import time

import numpy as np

from stdm_drake.cluster import RunnerConfig, job_pool
from stdm_drake.files import rows_csv, write_text_atomic
from stdm_drake.stats import paired_ratio
from stdm_drake.robots.robot import UR10_CONFIG, load_robot

HELD_OUT_SEED = 20261124          # never used for anything else; fixed before the first run
TRAIN_SEED = 0                    # the default collection seed
VALIDATION = 40
HORIZON = 20                      # open-loop endpoint (steps)
CONFIGS = {  # name -> (predicts, inputs, training trajectories, alpha)
    "paper": ("state", "raw", 40, 0.0),
    "velocity": ("velocity", "raw", 40, 0.0),
    "nominal": ("state", "nominal_acceleration", 40, 0.0),
    "default": ("velocity", "nominal_acceleration", 40, 0.0),
    "default-n160": ("velocity", "nominal_acceleration", 160, 0.0),
    "default-DD": ("velocity", "nominal_acceleration", 40, 1e-3),
}
COMPARISONS = (  # (baseline configuration, method configuration, what the switch is)
    ("paper", "velocity", "output: next state -> next velocity + trapezoid (raw inputs)"),
    ("paper", "nominal", "inputs: raw -> + nominal acceleration (state output)"),
    ("velocity", "default", "inputs: raw -> + nominal acceleration (velocity output)"),
    ("nominal", "default", "output: next state -> next velocity + trapezoid (nominal inputs)"),
    ("paper", "default", "both (the paper's black box -> the default)"),
    ("default", "default-n160", "data: 40 -> 160 training trajectories"),
    ("default", "default-DD", "derivative learning, alpha 1e-3 (our units), on the default"),
)
ENDPOINTS = (("one_step_q", "one-step q"), ("one_step_v", "one-step v"), ("open_loop_q", f"q at step {HORIZON}"))


def collect(path: pathlib.Path, seed: int, count: int | None) -> None:
    """`collect --protocol excitation --seed SEED [--count COUNT]` (the library's job) into `path` unless it exists."""
    from stdm_drake.collection.collect_job import CollectJob, collect_job
    if not path.exists():
        collect_job(CollectJob(output=path, protocol="excitation", seed=seed, count=count, progress=False))


def problem(train_path, name: str):
    """The TrainingProblem of configuration `name` (features computed once, shared by every seed)."""
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.learning.structure import ModelStructure
    from stdm_drake.learning.problem import training_problem
    predicts, inputs, n_train, _ = CONFIGS[name]
    dataset = load_dataset(train_path)
    order = np.random.default_rng(0).permutation(dataset.num_trajectories)
    split = dict(train=order[VALIDATION:VALIDATION + n_train], val=order[:VALIDATION], test=[])
    return training_problem(dataset, split, model_type="D", structure=ModelStructure(predicts, inputs),
                            robot=load_robot(UR10_CONFIG))


def contact_free_trajectories(path) -> tuple[list[int], list[int]]:
    """(trajectories the robot's plant steps without touching itself, those in which it touched itself
    between two samples): every recorded step is replayed on the plant with and without self-contact,
    and a difference above 1e-6 rad/s in any velocity marks contact."""
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.dynamics.physics import PlantModel
    from stdm_drake.robots.plant import PlantConfig
    dataset = load_dataset(path)
    free = PlantModel(dataset.sample_period, PlantConfig(self_collision=False), robot=load_robot(UR10_CONFIG))
    keep, contact = [], []
    for index in range(dataset.num_trajectories):
        traj = dataset.trajectory(index)
        x = np.hstack([traj.q_true, traj.v_true])
        predicted = free.step(x[:-1], traj.tau)
        (contact if np.abs(predicted - x[1:])[:, dataset.trajectory(index).q.shape[1]:].max() > 1e-6
         else keep).append(index)
    return keep, contact


def run_job(name: str, seed: int, job_problem, held_out_path: str, epochs: int, indices) -> dict:
    import torch

    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.learning.evaluate import compare_with_baselines, physics_baselines, trajectory_rollout_data
    from stdm_drake.learning.learned_model import LearnedModel
    from stdm_drake.learning.settings import TrainingConfig
    from stdm_drake.learning.structure import ModelStructure
    from stdm_drake.learning.alpha_selection import fit_model
    torch.set_num_threads(1)
    predicts, inputs, n_train, alpha = CONFIGS[name]
    started = time.perf_counter()
    result, _ = fit_model(job_problem.model_config, TrainingConfig(alpha=alpha, seed=seed, max_epochs=epochs),
                          job_problem.train, job_problem.val)
    seconds = time.perf_counter() - started
    held_out = load_dataset(held_out_path)
    model = LearnedModel(result.model, name=name, robot=load_robot(UR10_CONFIG), structure=ModelStructure(predicts, inputs),
                         sample_period=held_out.sample_period)
    baselines = physics_baselines(held_out.sample_period, model.state_dim, model.action_dim, plant=False)
    rows = compare_with_baselines([model] + baselines, held_out.transitions(indices),
                                  trajectory_rollout_data(held_out, indices, HORIZON))
    mine, euler, stays = rows
    return dict(config=name, seed=seed, train_trajectories=n_train, alpha=alpha, predicts=predicts, inputs=inputs,
                epochs=result.epochs_run, best_epoch=int(result.best_epochs[0]), train_seconds=round(seconds, 2),
                one_step_q=mine.one_step.angle_mse, one_step_v=mine.one_step.velocity_mse,
                open_loop_q=float(mine.multi_step.angle_mse[-1]),
                euler_q=euler.one_step.angle_mse, unchanged_v=euler.one_step.velocity_mse,
                stays_put_open_loop_q=float(stays.multi_step.angle_mse[-1]),
                ratio_q=mine.ratio_q, ratio_v=mine.ratio_v,
                ratio_open_loop_q=float(stays.multi_step.angle_mse[-1] / mine.multi_step.angle_mse[-1]),
                verdict=mine.verdict)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-o", "--output", type=pathlib.Path, default=pathlib.Path("docs/results/model_structure"))
    parser.add_argument("--data", type=pathlib.Path, default=pathlib.Path("out/model_structure_data"),
                        help="folder for the two datasets (collected when missing)")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--quick", action="store_true", help="2 seeds, 60 epochs, 50 held-out trajectories (pipeline check)")


def run(args: argparse.Namespace) -> int:
    seeds = 2 if args.quick else args.seeds
    epochs = 60 if args.quick else 500
    args.data.mkdir(parents=True, exist_ok=True)
    train_path, held_out_path = args.data / "excitation_seed0.h5", args.data / f"excitation_seed{HELD_OUT_SEED}.h5"
    collect(train_path, TRAIN_SEED, None)
    collect(held_out_path, HELD_OUT_SEED, 50 if args.quick else None)
    started = time.perf_counter()
    keep, contact = contact_free_trajectories(held_out_path)
    print(f"held-out set: {len(keep)} trajectories without self-contact, {len(contact)} with ({contact}): "
          "those are left out", flush=True)
    problems = {name: problem(train_path, name) for name in CONFIGS}
    print(f"training pairs ready in {time.perf_counter() - started:.1f} s", flush=True)
    rows = []
    with job_pool(RunnerConfig(workers=args.workers)) as pool:
        calls = [(run_job, (name, seed, problems[name], str(held_out_path), epochs, keep))
                 for seed in range(seeds) for name in CONFIGS]
        for _, future in pool.completed(calls):
            row = future.result()
            rows.append(row)
            print(f"{row['config']:>13} seed {row['seed']}: q {row['ratio_q']:.3g}x, v {row['ratio_v']:.3g}x, "
                  f"open loop {row['ratio_open_loop_q']:.3g}x ({row['verdict']}; best epoch {row['best_epoch']})",
                  flush=True)
    rows.sort(key=lambda row: (list(CONFIGS).index(row["config"]), row["seed"]))
    by = {name: [row for row in rows if row["config"] == name] for name in CONFIGS}
    summary = []
    for name, runs in by.items():
        entry = dict(config=name, runs=len(runs), learned=sum(row["verdict"] == "learned" for row in runs))
        for key in ("ratio_q", "ratio_v", "ratio_open_loop_q"):
            values = np.array([row[key] for row in runs])
            entry[key] = float(np.exp(np.log(values).mean()))
            entry[key + "_min"] = float(values.min())
        summary.append(entry)
    comparisons = []
    for base, method, what in COMPARISONS:
        for key, label in ENDPOINTS:
            ratio = paired_ratio([row[key] for row in by[base]], [row[key] for row in by[method]])
            learned = all(row["verdict"] == "learned" for row in by[base] + by[method])
            comparisons.append(dict(baseline=base, method=method, switch=what, endpoint=label, **ratio.as_dict(),
                                    both_learned=learned,
                                    reading=ratio.verdict if learned else "uninformative (a model has not learned)"))
    elapsed = time.perf_counter() - started
    args.output.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.output / "runs.csv", rows_csv(rows))
    write_text_atomic(args.output / "summary.csv", rows_csv(summary))
    write_text_atomic(args.output / "comparisons.csv", rows_csv(comparisons))
    write_text_atomic(args.output / "results.json", json.dumps(dict(
        written_by="tools/study.py model-structure", provenance=args.provenance, quick=args.quick, seeds=seeds, epochs=epochs,
        held_out_seed=HELD_OUT_SEED, test_trajectories=keep, left_out_for_self_contact=contact, horizon=HORIZON, seconds=round(elapsed, 1), configs=CONFIGS,
        summary=summary, comparisons=comparisons, runs=rows), indent=2) + "\n")
    print(f"\n{'config':>13} {'learned':>8} {'q vs Euler':>11} {'v vs unchanged':>15} {'q@20 vs stays put':>18}")
    for entry in summary:
        print(f"{entry['config']:>13} {entry['learned']:>4}/{entry['runs']:<3} {entry['ratio_q']:>10.3g}x "
              f"{entry['ratio_v']:>14.3g}x {entry['ratio_open_loop_q']:>17.3g}x")
    for row in comparisons:
        print(f"{row['switch'][:60]:<60} {row['endpoint']:>11}: {row['ratio']:.3g}x [{row['low']:.3g}, {row['high']:.3g}] "
              f"{row['reading']}")
    print(f"{len(rows)} runs in {elapsed:.0f} s -> {args.output}")
    return 0

