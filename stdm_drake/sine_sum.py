"""The paper's sine-sum study (Kim, Lee & Ryu 2022, section III.B, eq. 6) and `stdm-drake sine-sum`.

Fit y = sin x + sin 0.5x + sin 0.1x on x in [-30π, 30π] from 100 training points (1000
validation, 4000 test; uniform interval sampling) with MLPs of width 100 and 1/3/5 hidden layers,
nine activations, naive (state-only) vs derivative learning (alpha 1e-3, target y'), several
independently initialized networks per configuration, best by validation. Produces the Fig. 6
table and bar chart, Fig. 7 prediction curves, Fig. 8 learning curves, and the Table 1 grid
(loss function x activation, 5 layers) next to the paper's values.

The map x -> y is a generic regression: inputs x (1), outputs y (1), direct parameterization,
tangent ẋ = 1 and derivative target y'. Inputs are standardized (x spans ±94). The networks of one
configuration are trained together as one stacked ensemble without bootstrap: members share the
data and never interact (Adam is elementwise), so each is an independent run from its own
initialization. Training is full-batch Adam (lr 1e-3): one step per epoch.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import multiprocessing
import os
import pathlib
import time

import numpy as np
import torch

from stdm_drake.errors import InputError
from stdm_drake.files import atomic_path, write_text_atomic
from stdm_drake.learn import DEFAULT_ALPHA, RegressionData, TrainingConfig, train_model
from stdm_drake.models import ACTIVATION_NAMES, ModelConfig

PAPER_TABLE1 = {  # paper Table 1: 5 hidden layers, derivative learning, average of 3 runs
    ("mae", "tanh"): 0.0682, ("mae", "relu"): 0.0530, ("mae", "swish"): 0.0962,
    ("mse", "tanh"): 0.0208, ("mse", "relu"): 0.0334, ("mse", "swish"): 0.0006,
    ("huber", "tanh"): 0.0367, ("huber", "relu"): 0.0468, ("huber", "swish"): 0.0023,
}
DOMAIN = (-30.0 * np.pi, 30.0 * np.pi)


def sine_sum(x: np.ndarray) -> np.ndarray:
    """Paper eq. 6: y = sin x + sin 0.5x + sin 0.1x."""
    return np.sin(x) + np.sin(0.5 * x) + np.sin(0.1 * x)


def sine_sum_derivative(x: np.ndarray) -> np.ndarray:
    """dy/dx = cos x + 0.5 cos 0.5x + 0.1 cos 0.1x."""
    return np.cos(x) + 0.5 * np.cos(0.5 * x) + 0.1 * np.cos(0.1 * x)


def sample(points: int):
    """RegressionData of `points` uniformly spaced x in the domain (x, y, ẋ = 1, y')."""
    x = np.linspace(*DOMAIN, points)[:, None]
    return RegressionData(inputs=x, targets=sine_sum(x), input_rates=np.ones_like(x),
                          target_rates=sine_sum_derivative(x))


@dataclasses.dataclass(frozen=True)
class StudyConfig:
    """What the study trains. epochs = full-batch Adam steps per network."""
    layers: tuple = (1, 3, 5)
    activations: tuple = ACTIVATION_NAMES
    seeds: int = 5
    alpha: float = DEFAULT_ALPHA
    epochs: int = 6000
    validation_interval: int = 50
    width: int = 100
    learning_rate: float = 1e-3
    train_points: int = 100
    val_points: int = 1000
    test_points: int = 4000
    table_layers: int = 5
    table_activations: tuple = ("tanh", "relu", "swish")
    table_losses: tuple = ("mae", "mse", "huber")
    table_seeds: int = 3
    seed: int = 0

    def __post_init__(self):
        unknown = [name for name in self.activations if name not in ACTIVATION_NAMES]
        if unknown:
            raise InputError(f"unknown activations {unknown}")
        if self.table_layers not in self.layers or not set(self.table_activations) <= set(self.activations):
            raise InputError("the figure/table configurations (5 layers; tanh, relu, swish) must be in the grid")
        if min(self.seeds, self.table_seeds, self.epochs, self.validation_interval) < 1:
            raise InputError("seeds, table seeds, epochs and validation interval must be positive")


FULL = StudyConfig()
QUICK = StudyConfig(layers=(1, 5), activations=("tanh", "relu", "swish"), seeds=2, epochs=150,
                    validation_interval=25, table_seeds=2)


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """One trained stack of `members` networks."""
    layers: int
    activation: str
    derivative: bool
    loss: str
    members: int

    @property
    def label(self) -> str:
        return (f"{self.layers}L {self.activation} {'derivative' if self.derivative else 'naive'} "
                f"{self.loss} x{self.members}")


def run_specs(config: StudyConfig) -> list[RunSpec]:
    """The Fig. 6 grid (MSE loss, `seeds` networks) then the Table 1 grid (derivative, `table_seeds`)."""
    grid = [RunSpec(layers, activation, derivative, "mse", config.seeds)
            for layers in config.layers for activation in config.activations for derivative in (False, True)]
    table = [RunSpec(config.table_layers, activation, True, loss, config.table_seeds)
             for loss in config.table_losses for activation in config.table_activations]
    return grid + table


def train_run(spec: RunSpec, config: StudyConfig) -> dict:
    """Train one stack; test MSE (raw y units) of every member, the best-by-validation member's
    predictions on the test grid, and the learning curves."""
    started = time.perf_counter()
    train, val, test = sample(config.train_points), sample(config.val_points), sample(config.test_points)
    model_config = ModelConfig(input_dim=1, output_dim=1, residual=False, hidden_width=config.width,
                               hidden_layers=spec.layers, activation=spec.activation, ensemble_size=spec.members)
    training = TrainingConfig(alpha=config.alpha if spec.derivative else 0.0, state_loss=spec.loss,
                              derivative_loss=spec.loss, learning_rate=config.learning_rate,
                              batch_size=config.train_points, max_epochs=config.epochs, patience=config.epochs,
                              validation_interval=config.validation_interval, bootstrap=False, seed=config.seed)
    result = train_model(model_config, training, train, val)
    with torch.no_grad():
        predicted = result.model(torch.from_numpy(test.inputs).float())[0].double().numpy()[..., 0]  # (E, N)
    test_mse = ((predicted - test.targets[None, :, 0]) ** 2).mean(axis=1)
    best = int(np.argmin(result.best_scores))
    return dict(spec=dataclasses.asdict(spec), label=spec.label, member_test_mse=test_mse.tolist(),
                member_val_mse_standardized=list(result.best_scores), best_member=best,
                best_test_mse=float(test_mse[best]), mean_test_mse=float(test_mse.mean()),
                best_epochs=result.best_epochs, best_prediction=predicted[best].tolist(),
                history={key: list(map(float, values)) for key, values in result.history.items()},
                seconds=time.perf_counter() - started)


def _worker(job):
    torch.set_num_threads(1)
    spec, config = job
    return train_run(spec, config)


def run_study(config: StudyConfig, *, workers: int = 1, progress: bool = True) -> dict:
    """Train every run (in `workers` processes) and return {"runs": [...], timings}."""
    from tqdm import tqdm

    specs = run_specs(config)
    started = time.perf_counter()
    jobs = [(spec, config) for spec in specs]
    bar = tqdm(total=len(jobs), desc="sine-sum", unit="run", disable=not progress, dynamic_ncols=True)
    runs = []
    try:
        if workers > 1:
            with multiprocessing.get_context("spawn").Pool(workers) as pool:
                for run in pool.imap(_worker, jobs):
                    runs.append(run)
                    bar.update(1)
        else:
            for job in jobs:
                runs.append(_worker(job))
                bar.update(1)
    finally:
        bar.close()
    return dict(config=dataclasses.asdict(config), runs=runs, workers=workers,
                wall_seconds=time.perf_counter() - started, run_seconds=sum(run["seconds"] for run in runs))


# -- reports ------------------------------------------------------------------------------------------

def _find(runs, **conditions):
    for run in runs:
        if all(run["spec"][key] == value for key, value in conditions.items()):
            return run
    raise KeyError(conditions)


def fig6_rows(study: dict) -> list[dict]:
    config = study["config"]
    rows = []
    for layers in config["layers"]:
        for activation in config["activations"]:
            naive = _find(study["runs"], layers=layers, activation=activation, derivative=False, loss="mse",
                          members=config["seeds"])
            derivative = _find(study["runs"], layers=layers, activation=activation, derivative=True, loss="mse",
                               members=config["seeds"])
            rows.append(dict(layers=layers, activation=activation,
                             naive_mean_test_mse=naive["mean_test_mse"], naive_best_test_mse=naive["best_test_mse"],
                             derivative_mean_test_mse=derivative["mean_test_mse"],
                             derivative_best_test_mse=derivative["best_test_mse"]))
    return rows


def table1_rows(study: dict) -> list[dict]:
    config = study["config"]
    rows = []
    for loss in config["table_losses"]:
        for activation in config["table_activations"]:
            run = _find(study["runs"], layers=config["table_layers"], activation=activation, derivative=True,
                        loss=loss, members=config["table_seeds"])
            rows.append(dict(loss=loss, activation=activation, mean_test_mse=run["mean_test_mse"],
                             member_test_mse=run["member_test_mse"], paper=PAPER_TABLE1.get((loss, activation))))
    return rows


def _csv(rows: list[dict], columns: list[str]) -> str:
    lines = [",".join(columns)]
    for row in rows:
        lines.append(",".join(f"{row[c]:.6g}" if isinstance(row[c], float) else str(row[c]) for c in columns))
    return "\n".join(lines) + "\n"


def _save_figure(figure, path) -> None:
    with atomic_path(path) as temp:
        figure.savefig(temp, format="png", dpi=110, bbox_inches="tight")


def write_reports(study: dict, output: pathlib.Path, quick: bool, partial: bool = False) -> list[pathlib.Path]:
    """Write results.json, CSV/JSON tables, PNG figures and summary.md into `output`."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    output = pathlib.Path(output)
    config = study["config"]
    written = []

    def text(name, content):
        written.append(write_text_atomic(output / name, content))

    def figure(name, fig):
        _save_figure(fig, output / name)
        plt.close(fig)
        written.append(output / name)

    text("results.json", json.dumps(study, indent=1) + "\n")
    fig6 = fig6_rows(study)
    text("fig6_mse_vs_activation.csv", _csv(fig6, list(fig6[0])))
    fig, axes = plt.subplots(1, len(config["layers"]), figsize=(5 * len(config["layers"]), 4), squeeze=False)
    for ax, layers in zip(axes[0], config["layers"]):
        rows = [row for row in fig6 if row["layers"] == layers]
        positions = np.arange(len(rows))
        for offset, (mode, color) in zip((-0.2, 0.2), (("naive", "tab:blue"), ("derivative", "tab:orange"))):
            ax.bar(positions + offset, [row[f"{mode}_mean_test_mse"] for row in rows], width=0.4, color=color,
                   label=f"{mode} (mean of {config['seeds']})")
            ax.plot(positions + offset, [row[f"{mode}_best_test_mse"] for row in rows], "k.", markersize=5)
        ax.set_xticks(positions, [row["activation"] for row in rows], rotation=45, ha="right")
        ax.set_yscale("log")
        ax.set_title(f"{layers} hidden layer{'s' if layers > 1 else ''}")
        ax.set_ylabel("test MSE")
    axes[0][0].legend(title="dots: best by validation", fontsize=8)
    fig.suptitle("Fig. 6: test MSE vs activation, naive vs derivative learning")
    figure("fig6_mse_vs_activation.png", fig)

    x = np.linspace(*DOMAIN, config["test_points"])
    train_x = np.linspace(*DOMAIN, config["train_points"])
    shown = config["table_activations"]
    fig, axes = plt.subplots(len(shown), 1, figsize=(12, 2.6 * len(shown)), squeeze=False, sharex=True)
    for ax, activation in zip(axes[:, 0], shown):
        ax.plot(x, sine_sum(x), "k--", linewidth=1, label="ground truth")
        for derivative, color in ((False, "tab:blue"), (True, "tab:orange")):
            run = _find(study["runs"], layers=config["table_layers"], activation=activation, derivative=derivative,
                        loss="mse", members=config["seeds"])
            ax.plot(x, run["best_prediction"], color=color, linewidth=1,
                    label=f"{'derivative' if derivative else 'naive'} (test MSE {run['best_test_mse']:.3g})")
        ax.plot(train_x, sine_sum(train_x), "k.", markersize=3, label="training points")
        ax.set_title(f"{activation}, {config['table_layers']} hidden layers (best of {config['seeds']} by validation)")
        ax.legend(fontsize=7, loc="upper right", ncol=4)
    axes[-1, 0].set_xlabel("x")
    figure("fig7_predictions.png", fig)

    curves = {}
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for derivative, color in ((False, "tab:blue"), (True, "tab:orange")):
        run = _find(study["runs"], layers=config["table_layers"], activation="swish", derivative=derivative,
                    loss="mse", members=config["seeds"])
        history = run["history"]
        mode = "derivative" if derivative else "naive"
        curves[mode] = history
        ax.plot(history["epoch"], history["train_loss"], color=color, linestyle="-", label=f"{mode} train loss")
        ax.plot(history["epoch"], history["val_loss"], color=color, linestyle="--", label=f"{mode} validation loss")
    ax.set_yscale("log")
    ax.set_xlabel("epoch (full-batch step)")
    ax.set_ylabel(f"loss (standardized, mean of {config['seeds']} networks)")
    ax.set_title(f"Fig. 8: learning curves, swish, {config['table_layers']} hidden layers")
    ax.legend(fontsize=8)
    figure("fig8_learning_curves.png", fig)
    lines = ["mode,epoch,train_loss,val_loss,val_mse_standardized"]
    for mode, history in curves.items():
        for values in zip(history["epoch"], history["train_loss"], history["val_loss"], history["val_mse"]):
            lines.append(f"{mode},{int(values[0])}," + ",".join(f"{v:.6g}" for v in values[1:]))
    text("fig8_learning_curves.csv", "\n".join(lines) + "\n")

    table = table1_rows(study)
    text("table1.csv", _csv(table, ["loss", "activation", "mean_test_mse", "paper"]))
    text("table1.json", json.dumps(table, indent=1) + "\n")
    fig, ax = plt.subplots(figsize=(7, 4))
    labels = [f"{row['loss']}\n{row['activation']}" for row in table]
    positions = np.arange(len(table))
    ax.bar(positions - 0.2, [row["mean_test_mse"] for row in table], width=0.4, label="this run")
    ax.bar(positions + 0.2, [row["paper"] for row in table], width=0.4, color="tab:gray", label="paper")
    ax.set_xticks(positions, labels, fontsize=8)
    ax.set_yscale("log")
    ax.set_ylabel(f"test MSE (mean of {config['table_seeds']})")
    ax.set_title(f"Table 1: loss x activation, derivative learning, {config['table_layers']} hidden layers")
    ax.legend()
    figure("table1.png", fig)

    text("summary.md", summary_markdown(study, fig6, table, quick, partial))
    return written


def summary_markdown(study: dict, fig6: list[dict], table: list[dict], quick: bool, partial: bool = False) -> str:
    config = study["config"]
    runs = study["runs"]
    profile = ("quick profile" if quick else "full profile") + (", with overrides" if partial else "")
    lines = [f"# Sine-sum study ({profile})", "",
             f"y = sin x + sin 0.5x + sin 0.1x on [-30π, 30π]; {config['train_points']} train / "
             f"{config['val_points']} validation / {config['test_points']} test points; width {config['width']}, "
             f"hidden layers {tuple(config['layers'])}; {len(config['activations'])} activations; "
             f"{config['seeds']} networks per configuration; full-batch Adam lr {config['learning_rate']:g}, "
             f"{config['epochs']} epochs, validation every {config['validation_interval']}; "
             f"derivative learning alpha {config['alpha']:g}; standardized input and output.", "",
             f"Time: {len(runs)} runs in {study['wall_seconds']:.1f} s wall with {study['workers']} worker(s) "
             f"({study['run_seconds']:.1f} s of training in total, {study['run_seconds'] / len(runs):.2f} s per run).",
             "", "## Fig. 6: test MSE (mean over networks / best by validation)", "",
             "| layers | activation | naive mean | naive best | derivative mean | derivative best |",
             "|---|---|---|---|---|---|"]
    for row in fig6:
        lines.append(f"| {row['layers']} | {row['activation']} | {row['naive_mean_test_mse']:.4g} | "
                     f"{row['naive_best_test_mse']:.4g} | {row['derivative_mean_test_mse']:.4g} | "
                     f"{row['derivative_best_test_mse']:.4g} |")
    deepest = [row for row in fig6 if row["layers"] == config["table_layers"]]
    winner = min(deepest, key=lambda row: row["derivative_mean_test_mse"])
    better = sum(row["derivative_mean_test_mse"] < row["naive_mean_test_mse"] for row in fig6)
    lines += ["", f"Derivative learning has the lower mean test MSE in {better} of {len(fig6)} configurations; "
              f"at {config['table_layers']} layers the best activation with derivative learning is "
              f"{winner['activation']} ({winner['derivative_mean_test_mse']:.4g}, naive "
              f"{winner['naive_mean_test_mse']:.4g}).", "",
              f"## Table 1: test MSE, derivative learning, {config['table_layers']} layers, "
              f"mean of {config['table_seeds']} networks", "",
              "| loss | " + " | ".join(config["table_activations"]) + " |",
              "|---|" + "---|" * len(config["table_activations"])]
    for loss in config["table_losses"]:
        cells = []
        for activation in config["table_activations"]:
            row = next(r for r in table if r["loss"] == loss and r["activation"] == activation)
            cells.append(f"{row['mean_test_mse']:.4f} (paper {row['paper']:.4f})")
        lines.append(f"| {loss.upper()} | " + " | ".join(cells) + " |")
    lines += ["", "Every number is computed by this run except those labelled paper (Table 1 of the paper).",
              "Files: fig6_mse_vs_activation.csv/.png, fig7_predictions.png, fig8_learning_curves.csv/.png, "
              "table1.csv/.json/.png, results.json.", ""]
    return "\n".join(lines)


# -- `stdm-drake sine-sum` ----------------------------------------------------------------------------

def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--output", "-o", type=pathlib.Path, default=pathlib.Path("runs/sine-sum"),
                        help="output folder (default runs/sine-sum)")
    parser.add_argument("--quick", action="store_true",
                        help="small CI profile: 1 and 5 layers, tanh/relu/swish, 2 networks, 150 epochs")
    parser.add_argument("--epochs", type=int, help="override the profile's epochs (full-batch steps)")
    parser.add_argument("--seeds", type=int, help="override the profile's networks per configuration")
    parser.add_argument("--layers", type=int, nargs="+", help="override the hidden-layer counts (must include 5)")
    parser.add_argument("--activations", nargs="+", choices=ACTIVATION_NAMES,
                        help="override the activations (must include tanh, relu, swish)")
    parser.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                        help="processes, one torch thread each (default min(2, cores)); results do not depend on it")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    config = QUICK if args.quick else FULL
    overrides = {key: (tuple(value) if isinstance(value, list) else value)
                 for key, value in (("epochs", args.epochs), ("seeds", args.seeds), ("layers", args.layers),
                                    ("activations", args.activations)) if value is not None}
    if overrides:
        config = dataclasses.replace(config, **overrides)
    if args.workers < 1:
        raise InputError(f"--workers must be >= 1, got {args.workers}")
    study = run_study(config, workers=args.workers, progress=not args.quiet)
    written = write_reports(study, args.output, quick=args.quick, partial=bool(overrides))
    print(f"{len(study['runs'])} runs in {study['wall_seconds']:.1f} s; wrote {len(written)} files to {args.output}")
    for row in table1_rows(study):
        print(f"  table 1  {row['loss']:>5} {row['activation']:>6}: test MSE {row['mean_test_mse']:.4g} "
              f"(paper {row['paper']:.4g})")
    return 0
