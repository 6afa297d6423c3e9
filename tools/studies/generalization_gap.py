"""The generalization gap of naive one-step models of the simulated UR-10, and what closes it.

Why naive one-step models of the simulated UR-10 generalize poorly, what closes the gap, and whether
derivative learning helps once the baseline is strong.

Data: excitation trajectories (trajectories/excitation.yaml, start poses over most of joint space),
collected here with seed 0; validation 40 and test 120 trajectories fixed, training sets nested.
Every job trains one alpha grid (learn.train_alpha_grid: single 3 x 100 swish delta models from one
initialization on the same minibatches, alpha in ALPHAS), so each yields the naive model (alpha 0)
and the derivative model with alpha chosen by validation, paired. Variants (all else as in
`stdm-drake reproduce`: Adam 1e-3, batch 64, at most 500 epochs, patience 50):

  baseline        40 training trajectories, inputs [q, q̇, τ]
  wd1e-4, wd1e-3  decoupled weight decay (AdamW) 1e-4 / 1e-3
  cosine          cosine learning-rate decay over 200 epochs, no early stop before the end
  sincos          inputs [sin q, cos q, q̇, τ] (joint angles enter the dynamics only through sin/cos);
                  the chain-rule tangent becomes [cos q ⊙ q̇, -sin q ⊙ q̇, q̈, Δτ/Δt]
  n160, n280      160 / 280 training trajectories
  sincos-n280     both

Per variant: train and test q MSE of the naive model (rad²), test/train (the gap), the test q and v
MSE of naive and derivative models, and paired ratios (95 % intervals over seeds) of each variant's
naive test q MSE against the baseline's and of naive against derivative within the variant.

    python tools/study.py generalization-gap [--quick] [--seeds N] [-o out/generalization_gap]
"""
import argparse
import json
import pathlib
import time

import numpy as np

from stdm_drake.cluster import RunnerConfig, job_pool
from stdm_drake.files import write_text_atomic
from stdm_drake.stats import paired_ratio
from stdm_drake.robots.robot import UR10_CONFIG, load_robot

ALPHAS = (0.0, 1e-3, 1e-2, 0.1, 1.0, 10.0)
VARIANTS = {  # name -> (training trajectories, input features, TrainingConfig changes)
    "baseline": (40, "raw", {}),
    "wd1e-4": (40, "raw", {"weight_decay": 1e-4}),
    "wd1e-3": (40, "raw", {"weight_decay": 1e-3}),
    "cosine": (40, "raw", {"lr_schedule": "cosine", "max_epochs": 200, "patience": 200}),
    "sincos": (40, "sincos", {}),
    "n160": (160, "raw", {}),
    "n280": (280, "raw", {}),
    "sincos-n280": (280, "sincos", {}),
}
VALIDATION, TEST = 40, 120


def regression_data(transitions, features: str):
    """RegressionData for raw inputs [x, a] (delta model) or sin/cos inputs (targets x_{t+1} - x_t)."""
    from stdm_drake.learning.regression import RegressionData
    if features == "raw":
        return RegressionData.from_transitions(transitions)
    state, rate = np.asarray(transitions.state), np.asarray(transitions.state_rate)
    q, v, qd, qdd = state[:, :6], state[:, 6:], rate[:, :6], rate[:, 6:]
    inputs = np.hstack([np.sin(q), np.cos(q), v, transitions.action])
    input_rates = np.hstack([np.cos(q) * qd, -np.sin(q) * qd, qdd, transitions.action_rate])
    return RegressionData(inputs=inputs, targets=np.asarray(transitions.next_state) - state, input_rates=input_rates,
                          target_rates=np.asarray(transitions.next_state_rate) - rate)


def member_mse(model, data) -> np.ndarray:
    """(E, 2): per member the q and v MSE of the predicted next state (raw units; for sin/cos inputs
    the targets are x_{t+1} - x_t, whose errors are those of x_{t+1})."""
    import torch
    with torch.no_grad():
        predicted = model(torch.from_numpy(data.inputs).float())[0].double().numpy()
    squared = (predicted - data.targets[None]) ** 2
    return np.stack([squared[..., :6].mean(axis=(1, 2)), squared[..., 6:].mean(axis=(1, 2))], axis=1)


def run_job(job: tuple) -> dict:
    import torch
    torch.set_num_threads(1)
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.learning.settings import TrainingConfig
    from stdm_drake.learning.alpha_selection import train_alpha_grid
    from stdm_drake.learning.models import ModelConfig

    path, variant, seed, split, max_epochs = job
    size, features, changes = VARIANTS[variant]
    dataset = load_dataset(path)
    data = {name: dataset.transitions(split[name][:size] if name == "train" else split[name])
            for name in ("train", "val", "test")}
    regression = {name: regression_data(value, features) for name, value in data.items()}
    inputs = regression["train"].inputs.shape[1]
    config = ModelConfig(input_dim=inputs, output_dim=12, residual=features == "raw", activation="swish",
                         ensemble_size=1)
    training = TrainingConfig(seed=seed, **({"max_epochs": max_epochs} | changes))
    started = time.perf_counter()
    grid, selection = train_alpha_grid(config, training, regression["train"], regression["val"], alphas=ALPHAS)
    errors = {name: member_mse(grid.model, regression[name]) for name in ("train", "test")}
    return dict(variant=variant, seed=seed, chosen=selection.index, chosen_alpha=ALPHAS[selection.index],
                best_epochs=list(map(int, grid.best_epochs)), val_mse=list(map(float, grid.best_scores)),
                train=errors["train"].tolist(), test=errors["test"].tolist(),
                seconds=time.perf_counter() - started)


def summarize(rows: list[dict], seeds: int) -> str:
    by = {(r["variant"], r["seed"]): r for r in rows}
    variants = [v for v in VARIANTS if all((v, s) in by for s in range(seeds))]
    base = [by[("baseline", s)]["test"][0][0] for s in range(seeds)]
    lines = ["| variant | train q MSE | test q MSE | test / train | vs baseline (test q) | naive epochs | "
             "derivative: alpha | derivative test q MSE | derivative test v MSE (naive) | naive / derivative, q |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for variant in variants:
        runs = [by[(variant, s)] for s in range(seeds)]
        train_q = np.array([r["train"][0][0] for r in runs])
        test_q = np.array([r["test"][0][0] for r in runs])
        test_v = np.array([r["test"][0][1] for r in runs])
        deriv_q = np.array([r["test"][r["chosen"]][0] for r in runs])
        deriv_v = np.array([r["test"][r["chosen"]][1] for r in runs])
        versus = paired_ratio(base, test_q)
        versus = "" if variant == "baseline" else f"{versus.text()} {versus.verdict}"
        gain = paired_ratio(test_q, deriv_q)
        epochs = ", ".join(str(r["best_epochs"][0]) for r in runs)
        alphas = ", ".join(f"{r['chosen_alpha']:g}" for r in runs)
        lines.append(f"| {variant} | {train_q.mean():.3g} | {test_q.mean():.3g} | {np.mean(test_q / train_q):.3g} "
                     f"| {versus} | {epochs} | {alphas} | {deriv_q.mean():.3g} "
                     f"| {deriv_v.mean():.3g} ({test_v.mean():.3g}) | {gain.text()} {gain.verdict} |")
    return "\n".join(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="2 variants, 1 seed, 20 epochs (a smoke run)")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("-o", "--output", type=pathlib.Path, default=pathlib.Path("out/generalization_gap"))


def run(args: argparse.Namespace) -> int:
    from stdm_drake.collection.collect import CollectionRequest, collect
    from stdm_drake.robots.station import StationConfig
    from stdm_drake.collection.protocols import load_protocol
    from stdm_drake.data.dataset import load_dataset, split_trajectories
    from stdm_drake.data.writer import write_dataset
    from stdm_drake.paths import TRAJECTORIES_DIR

    args.output.mkdir(parents=True, exist_ok=True)
    largest = max(size for size, _, _ in VARIANTS.values())
    count = largest + VALIDATION + TEST
    path = args.output / f"excitation_n{count}_seed0.h5"
    if not path.exists():
        excitation = load_protocol(TRAJECTORIES_DIR / "excitation.yaml", "excitation")
        request = CollectionRequest("excitation", count, 0, StationConfig(robot=load_robot(UR10_CONFIG)), excitation=excitation,
                                    workers=args.workers)
        write_dataset(path, *collect(request, progress=False))
    dataset = load_dataset(path)
    split = split_trajectories(dataset.groups, largest, VALIDATION, TEST, seed=0, per_group=False)
    split = {"train": split.train.tolist(), "val": split.val.tolist(), "test": split.test.tolist()}
    variants, seeds, epochs = (["baseline", "sincos"], 1, 20) if args.quick else (list(VARIANTS), args.seeds, 500)
    jobs = [(str(path), variant, seed, split, epochs) for variant in variants for seed in range(seeds)]
    started = time.perf_counter()
    with job_pool(RunnerConfig(workers=args.workers)) as pool:
        rows = []
        for row in pool.map(run_job, jobs):
            rows.append(row)
            print(f"{row['variant']:12s} seed {row['seed']}: naive test q {row['test'][0][0]:.3g}, "
                  f"alpha {row['chosen_alpha']:g} test q {row['test'][row['chosen']][0]:.3g} ({row['seconds']:.0f} s)",
                  flush=True)
    wall = time.perf_counter() - started
    table = summarize(rows, seeds)
    write_text_atomic(args.output / "results.json", json.dumps(dict(provenance=args.provenance, rows=rows, wall_seconds=wall, alphas=ALPHAS)))
    write_text_atomic(args.output / "summary.md", table + f"\n\n{len(jobs)} jobs in {wall:.0f} s wall.\n")
    print(table)
    print(f"{len(jobs)} jobs in {wall:.0f} s wall")
    return 0

