"""The paper's sine-sum study (Kim, Lee & Ryu 2022, section III.B, eq. 6), run by `stdm-drake sine-sum`.

Fit y = sin x + sin 0.5x + sin 0.1x on x in [-30π, 30π] from 100 training points (1000
validation, 4000 test; uniform interval sampling) with MLPs of width 100 and 1/3/5 hidden layers,
nine activations, naive (state-only) vs derivative learning (target y'), several independently
initialized networks per configuration, best by validation. Produces the Fig. 6 table and bar
chart, Fig. 7 prediction curves, Fig. 8 learning curves, the Table 1 grid (loss function x
activation, 5 layers) next to the paper's values, and the alpha sweep that chose alpha.

The map x -> y is a generic regression: inputs x (1), outputs y (1), direct parameterization,
tangent ẋ = 1 and derivative target y'. As in the paper the network sees raw x (no input
standardization: Xavier-scale first-layer weights on x in ±94 start with frequencies of order 1,
which the function needs), and the output is standardized (σ_y ≈ 1.2, so alpha weighs the raw
derivative MSE against the raw state MSE exactly as in eq. 9). Training is full-batch Adam, one step
per epoch, with a cosine learning-rate decay over the budget.

alpha="auto" (the default) chooses alpha first, by validation: one stack of single networks from
the same initialization, one per alpha of `alpha_grid` (5 hidden layers, swish), the lowest
validation MSE wins; every derivative-learning run then uses it. Naive runs do not depend on it and
run meanwhile. The networks of one configuration are trained together as one stacked ensemble
without bootstrap: members share the data and never interact, so each is an independent run from
its own initialization; naive and derivative runs of a configuration share their initializations,
so they are compared in pairs.

Longer than 400 lines on purpose: one self-contained study (its configuration, runs, figures,
tables and command); the figures read the run records' exact layout.
"""
from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import json
import pathlib
import time

import numpy as np
import torch

from stdm_drake.dynamics.verdict import LEARNED_FACTOR
from stdm_drake.errors import InputError
from stdm_drake.files import atomic_path, rows_csv, write_text_atomic
from stdm_drake.learning.regression import RegressionData
from stdm_drake.learning.settings import TrainingConfig
from stdm_drake.learning.alpha_selection import train_alpha_grid
from stdm_drake.learning.trainer import train_model
from stdm_drake.learning.activations import ACTIVATION_NAMES
from stdm_drake.learning.models import ModelConfig
from stdm_drake.provenance import results_header
from stdm_drake.report import markdown_table
from stdm_drake.stats import paired_ratio, ratio_interval_text
from stdm_drake.cluster import RunnerConfig, job_pool, task_error

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
    """What the study trains. epochs = full-batch Adam steps per network; seeds = networks per
    configuration, headline_seeds for the (table_layers, swish) configuration (the paper's Fig. 8 has
    five); alpha = a number, or "auto" (chosen by validation from alpha_grid, see module doc);
    flush_subnormals: train with subnormal floats flushed to zero (see `_numerics`)."""
    layers: tuple = (1, 3, 5)
    activations: tuple = ACTIVATION_NAMES
    seeds: int = 3
    headline_seeds: int = 5
    alpha: float | str = "auto"
    alpha_grid: tuple = (0.0, 1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0)
    epochs: int = 10000
    validation_interval: int = 50
    width: int = 100
    learning_rate: float = 5e-3
    lr_schedule: str = "cosine"
    standardize_inputs: bool = False
    train_points: int = 100
    val_points: int = 1000
    test_points: int = 4000
    table_layers: int = 5
    table_activations: tuple = ("tanh", "relu", "swish")
    table_losses: tuple = ("mae", "mse", "huber")
    table_seeds: int = 3
    seed: int = 0
    flush_subnormals: bool = True

    def __post_init__(self):
        unknown = [name for name in self.activations if name not in ACTIVATION_NAMES]
        if unknown:
            raise InputError(f"unknown activations {unknown}")
        if self.table_layers not in self.layers or not set(self.table_activations) <= set(self.activations):
            raise InputError("the figure/table configurations (5 layers; tanh, relu, swish) must be in the grid")
        if min(self.seeds, self.headline_seeds, self.table_seeds, self.epochs, self.validation_interval) < 1:
            raise InputError("seeds, table seeds, epochs and validation interval must be positive")
        if self.table_seeds > min(self.seeds, self.headline_seeds):
            raise InputError("table seeds must not exceed the networks per configuration (the MSE row reuses them)")
        if self.alpha != "auto" and not (isinstance(self.alpha, (int, float)) and self.alpha > 0):
            raise InputError(f"alpha must be a positive number or 'auto', got {self.alpha!r}")

    def networks(self, layers: int, activation: str) -> int:
        """Networks trained for one configuration of the Fig. 6 grid."""
        return self.headline_seeds if (layers, activation) == (self.table_layers, "swish") else self.seeds


FULL = StudyConfig()
# The quick profile: the headline configuration (5 layers, swish, MSE), 10 paired networks (their interval lay above 1
# on 9 of 10 seeds, 6 networks' on 5: docs/results/quick_sine_sum/), long enough for the paper's effect (the full
# profile's derivative learning pulls ahead after about 5000 of 10 000 steps), at the alpha the full profile's
# validation chose (1; both in docs/results/reproduce/sine_sum/). About 110 s on 2 cores.
QUICK = StudyConfig(layers=(5,), activations=("swish",), seeds=10, headline_seeds=10, epochs=6000,
                    validation_interval=100, table_activations=("swish",), table_losses=("mse",), table_seeds=3,
                    alpha=1.0)


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """One trained stack of `members` networks (alpha 0: naive)."""
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
    """The Fig. 6 grid (MSE loss) then the Table 1 grid (derivative, `table_seeds` networks) less its
    MSE row, which reuses the first networks of the Fig. 6 runs; deepest and slowest first."""
    grid = [RunSpec(layers, activation, derivative, "mse", config.networks(layers, activation))
            for layers in sorted(config.layers, reverse=True) for activation in config.activations
            for derivative in (True, False)]
    table = [RunSpec(config.table_layers, activation, True, loss, config.table_seeds)
             for loss in config.table_losses if loss != "mse" for activation in config.table_activations]
    return grid[:2 * len(config.activations)] + table + grid[2 * len(config.activations):]


def _model_config(config: StudyConfig, layers: int, activation: str, members: int) -> ModelConfig:
    return ModelConfig(input_dim=1, output_dim=1, residual=False, hidden_width=config.width, hidden_layers=layers,
                       activation=activation, ensemble_size=members, standardize_inputs=config.standardize_inputs)


def _training_config(config: StudyConfig, alpha: float, loss: str = "mse") -> TrainingConfig:
    return TrainingConfig(alpha=alpha, state_loss=loss, derivative_loss=loss, learning_rate=config.learning_rate,
                          lr_schedule=config.lr_schedule, batch_size=config.train_points, max_epochs=config.epochs,
                          patience=config.epochs, validation_interval=config.validation_interval, bootstrap=False,
                          seed=config.seed)


@contextlib.contextmanager
def _numerics(config: StudyConfig):
    """Subnormal floats flushed to zero while training, if `config.flush_subnormals`. On raw x (±94) the
    hidden pre-activations are large, so exp(-h²/2) (gelu), exp(-h) (softplus) and e^h (elu) underflow
    into subnormals, which x86 CPUs process many times slower: flushing them makes gelu derivative
    runs about 2.5x faster and changes values only below 1.2e-38."""
    if not config.flush_subnormals:
        yield
        return
    torch.set_flush_denormal(True)
    try:
        yield
    finally:
        torch.set_flush_denormal(False)


def _test_mse(model, test: RegressionData) -> np.ndarray:
    """Test MSE (raw y units) of every member, and the member predictions (E, N)."""
    with torch.no_grad():
        predicted = model(torch.from_numpy(test.inputs).float())[0].double().numpy()[..., 0]
    return ((predicted - test.targets[None, :, 0]) ** 2).mean(axis=1), predicted


def train_run(spec: RunSpec, config: StudyConfig, alpha: float, on_epoch=None) -> dict:
    """Train one stack; test MSE (raw y units) of every member, the best-by-validation member's
    predictions on the test grid, and the learning curves (on_epoch(row): each learning-curve row as it comes)."""
    started = time.perf_counter()
    train, val, test = sample(config.train_points), sample(config.val_points), sample(config.test_points)
    model_config = _model_config(config, spec.layers, spec.activation, spec.members)
    training = _training_config(config, alpha if spec.derivative else 0.0, spec.loss)
    with _numerics(config):
        result = train_model(model_config, training, train, val, on_epoch=on_epoch)
        test_mse, predicted = _test_mse(result.model, test)
    best = int(np.argmin(result.best_scores))
    return dict(spec=dataclasses.asdict(spec), label=spec.label, alpha=training.alpha,
                member_test_mse=test_mse.tolist(), member_val_mse_standardized=list(result.best_scores),
                best_member=best, best_test_mse=float(test_mse[best]), mean_test_mse=float(test_mse.mean()),
                best_epochs=result.best_epochs, best_prediction=predicted[best].tolist(),
                history={key: list(map(float, values)) for key, values in result.history.items()},
                seconds=time.perf_counter() - started)


def alpha_sweep(config: StudyConfig) -> dict:
    """Choose alpha by validation (5 layers, swish, one initialization, `alpha_grid`); the test MSE of
    every alpha is reported beside it, never used for the choice."""
    started = time.perf_counter()
    train, val, test = sample(config.train_points), sample(config.val_points), sample(config.test_points)
    with _numerics(config):
        grid, selection = train_alpha_grid(_model_config(config, config.table_layers, "swish", 1),
                                           _training_config(config, 0.0), train, val, alphas=config.alpha_grid)
        test_mse, _ = _test_mse(grid.model, test)
    return dict(selection.as_dict(), test_mse=test_mse.tolist(), seconds=time.perf_counter() - started)


def _call(function, *arguments):
    """Run one job in a worker process, one torch thread each."""
    torch.set_num_threads(1)
    return function(*arguments)


def run_study(config: StudyConfig, *, workers: int = 1, progress: bool = True, runner=None) -> dict:
    """The alpha sweep (alpha="auto") and every run, in `workers` processes (or on `runner`, a
    `cluster.RunnerConfig`: local processes or Ray): naive runs start at once, derivative runs once alpha is known.
    Returns {"runs": [...] in run_specs order, "alpha_sweep", timings}; the results do not depend on
    `workers` or the backend."""
    from tqdm import tqdm

    runner = runner or RunnerConfig(workers=workers)

    specs = run_specs(config)
    started = time.perf_counter()
    auto = config.alpha == "auto"
    bar = tqdm(total=len(specs) + auto, desc="sine-sum", unit="run", disable=not progress, dynamic_ncols=True)
    results: dict[int, dict] = {}
    sweep = None
    try:
        if workers > 1 or runner.backend != "local":
            with job_pool(runner) as pool:
                pending = {}
                if auto:
                    sweep_future = pool.submit(_call, alpha_sweep, config)
                    pending[sweep_future] = None
                alpha = None if auto else float(config.alpha)
                for index, spec in enumerate(specs):
                    if not spec.derivative or not auto:
                        pending[pool.submit(_call, train_run, spec, config, alpha or 0.0)] = index
                while pending:
                    done, _ = concurrent.futures.wait(pending, return_when=concurrent.futures.FIRST_COMPLETED)
                    for future in done:
                        index = pending.pop(future)
                        bar.update(1)
                        try:
                            result = future.result()
                        except Exception as error:  # one line, whichever backend raised it
                            raise task_error(error, "the alpha sweep" if index is None else
                                             f"sine-sum run {specs[index].label}") from None
                        if index is None:
                            sweep = result
                            for later, spec in enumerate(specs):
                                if spec.derivative:
                                    pending[pool.submit(_call, train_run, spec, config, sweep["chosen_alpha"])] = later
                        else:
                            results[index] = result
        else:
            torch.set_num_threads(1)
            if auto:
                sweep = alpha_sweep(config)
                bar.update(1)
            alpha = sweep["chosen_alpha"] if auto else float(config.alpha)
            for index, spec in enumerate(specs):   # (the bar shows the run's step: a run can take minutes)
                results[index] = train_run(spec, config, alpha, on_epoch=lambda row, label=spec.label:
                                           bar.set_postfix_str(f"{label}: step {row['epoch']}/{config.epochs}"))
                bar.update(1)
    finally:
        bar.close()
    runs = [results[index] for index in range(len(specs))]
    seconds = sum(run["seconds"] for run in runs) + (sweep["seconds"] if sweep else 0.0)
    return dict(config=dataclasses.asdict(config), runs=runs, alpha_sweep=sweep, workers=workers,
                wall_seconds=time.perf_counter() - started, run_seconds=seconds)


# -- reports ------------------------------------------------------------------------------------------

def _find(runs, **conditions):
    for run in runs:
        if all(run["spec"][key] == value for key, value in conditions.items()):
            return run
    raise KeyError(conditions)


def _networks(config: dict, layers: int, activation: str) -> int:
    headline = (layers, activation) == (config["table_layers"], "swish")
    return config["headline_seeds"] if headline else config["seeds"]


def mean_baseline_mse(config: dict) -> float:
    """The learning-free baseline's test MSE (y units): every test point predicted as the training targets' mean."""
    train, test = sample(config["train_points"]), sample(config["test_points"])
    return float(np.mean((test.targets - train.targets.mean()) ** 2))


def fig6_rows(study: dict) -> list[dict]:
    """Per (layers, activation): mean and best-by-validation test MSE, naive and derivative, and the
    paired ratio naive/derivative over the shared initializations with its 95 % interval. Its verdict is
    "uninformative" where neither mode learned: both mean test MSEs within LEARNED_FACTOR of the learning-free
    baseline (`mean_baseline_mse`), as a too short a run leaves them (newcomer pass 2: 20 steps read "helps" at
    1.3 against the paper's 6e-4)."""
    config = study["config"]
    baseline = mean_baseline_mse(config)
    rows = []
    for layers in config["layers"]:
        for activation in config["activations"]:
            members = _networks(config, layers, activation)
            naive, derivative = (_find(study["runs"], layers=layers, activation=activation, derivative=mode,
                                       loss="mse", members=members) for mode in (False, True))
            ratio = paired_ratio(naive["member_test_mse"], derivative["member_test_mse"])
            rows.append(dict(layers=layers, activation=activation, networks=members,
                             naive_mean_test_mse=naive["mean_test_mse"], naive_best_test_mse=naive["best_test_mse"],
                             derivative_mean_test_mse=derivative["mean_test_mse"],
                             derivative_best_test_mse=derivative["best_test_mse"],
                             ratio=ratio.ratio, ratio_low=ratio.low, ratio_high=ratio.high, baseline_test_mse=baseline,
                             verdict=ratio.verdict if min(naive["mean_test_mse"], derivative["mean_test_mse"])
                             < baseline / LEARNED_FACTOR else "uninformative"))
    return rows


def table1_rows(study: dict) -> list[dict]:
    """Table 1: the MSE row is the first `table_seeds` networks of the Fig. 6 derivative runs."""
    config = study["config"]
    rows = []
    for loss in config["table_losses"]:
        for activation in config["table_activations"]:
            if loss == "mse":
                run = _find(study["runs"], layers=config["table_layers"], activation=activation, derivative=True,
                            loss=loss, members=_networks(config, config["table_layers"], activation))
                member_mse = run["member_test_mse"][:config["table_seeds"]]
            else:
                run = _find(study["runs"], layers=config["table_layers"], activation=activation, derivative=True,
                            loss=loss, members=config["table_seeds"])
                member_mse = run["member_test_mse"]
            rows.append(dict(loss=loss, activation=activation, mean_test_mse=float(np.mean(member_mse)),
                             member_test_mse=list(member_mse), paper=PAPER_TABLE1.get((loss, activation))))
    return rows


def verdict_text(row: dict) -> str:
    """A Fig. 6 row's verdict for a sentence: "uninformative" with the reason (`fig6_rows`)."""
    if row["verdict"] != "uninformative":
        return row["verdict"]
    return (f"uninformative: neither mode learned, both within {LEARNED_FACTOR:g}x of the test MSE of predicting the "
            f"mean, {row['baseline_test_mse']:.3g}")


def headline(study: dict) -> dict:
    """5 layers, swish: mean test MSE naive and derivative, their ratio of means, the paired ratio and
    the paper's derivative-learning value (Table 1, 6e-4)."""
    config = study["config"]
    row = next(r for r in fig6_rows(study) if r["layers"] == config["table_layers"] and r["activation"] == "swish")
    return dict(row, ratio_of_means=row["naive_mean_test_mse"] / row["derivative_mean_test_mse"],
                paper_derivative=PAPER_TABLE1[("mse", "swish")],
                alpha=(study.get("alpha_sweep") or {}).get("chosen_alpha", config["alpha"]))


def _save_figure(figure, path) -> None:
    with atomic_path(path) as temp:
        figure.savefig(temp, format="png", dpi=110, bbox_inches="tight")


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_fig6(fig6: list[dict], config: dict):
    """Fig. 6: test MSE per activation, naive against derivative learning, one panel per depth."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(config["layers"]), figsize=(5 * len(config["layers"]), 4), squeeze=False)
    for ax, layers in zip(axes[0], config["layers"]):
        rows = [row for row in fig6 if row["layers"] == layers]
        positions = np.arange(len(rows))
        for offset, (mode, color) in zip((-0.2, 0.2), (("naive", "tab:blue"), ("derivative", "tab:orange"))):
            ax.bar(positions + offset, [row[f"{mode}_mean_test_mse"] for row in rows], width=0.4, color=color,
                   label=f"{mode} (mean of {config['seeds']}; 5L swish {config['headline_seeds']})")
            ax.plot(positions + offset, [row[f"{mode}_best_test_mse"] for row in rows], "k.", markersize=5)
        ax.set_xticks(positions, [row["activation"] for row in rows], rotation=45, ha="right")
        ax.set_yscale("log")
        ax.set_title(f"{layers} hidden layer{'s' if layers > 1 else ''}")
        ax.set_ylabel("test MSE")
    axes[0][0].legend(title="dots: best by validation", fontsize=8)
    fig.suptitle("Fig. 6: test MSE vs activation, naive vs derivative learning")
    return fig


def plot_fig7(study: dict):
    """Fig. 7: the best network's prediction over the domain per shown activation, both modes."""
    plt = _pyplot()
    config = study["config"]
    x = np.linspace(*DOMAIN, config["test_points"])
    train_x = np.linspace(*DOMAIN, config["train_points"])
    shown = config["table_activations"]
    fig, axes = plt.subplots(len(shown), 1, figsize=(12, 2.6 * len(shown)), squeeze=False, sharex=True)
    for ax, activation in zip(axes[:, 0], shown):
        ax.plot(x, sine_sum(x), "k--", linewidth=1, label="ground truth")
        for derivative, color in ((False, "tab:blue"), (True, "tab:orange")):
            run = _find(study["runs"], layers=config["table_layers"], activation=activation, derivative=derivative,
                        loss="mse", members=_networks(config, config["table_layers"], activation))
            ax.plot(x, run["best_prediction"], color=color, linewidth=1,
                    label=f"{'derivative' if derivative else 'naive'} (test MSE {run['best_test_mse']:.3g})")
        ax.plot(train_x, sine_sum(train_x), "k.", markersize=3, label="training points")
        ax.set_title(f"{activation}, {config['table_layers']} hidden layers "
                     f"(best of {_networks(config, config['table_layers'], activation)} by validation)")
        ax.legend(fontsize=7, loc="upper right", ncol=4)
    axes[-1, 0].set_xlabel("x")
    return fig


def plot_fig8(study: dict):
    """Fig. 8: the headline configuration's learning curves, both modes; returns (figure, {mode: history})."""
    plt = _pyplot()
    config = study["config"]
    curves = {}
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for derivative, color in ((False, "tab:blue"), (True, "tab:orange")):
        run = _find(study["runs"], layers=config["table_layers"], activation="swish", derivative=derivative,
                    loss="mse", members=config["headline_seeds"])
        history = run["history"]
        mode = "derivative" if derivative else "naive"
        curves[mode] = history
        ax.plot(history["epoch"], history["train_loss"], color=color, linestyle="-", label=f"{mode} train loss")
        ax.plot(history["epoch"], history["val_loss"], color=color, linestyle="--", label=f"{mode} validation loss")
    ax.set_yscale("log")
    ax.set_xlabel("epoch (full-batch step)")
    ax.set_ylabel(f"loss (standardized, mean of {config['headline_seeds']} networks)")
    ax.set_title(f"Fig. 8: learning curves, swish, {config['table_layers']} hidden layers")
    ax.legend(fontsize=8)
    return fig, curves


def learning_curves_csv(curves: dict) -> str:
    """Fig. 8's curves as CSV: mode, epoch, train_loss, val_loss, val_mse_standardized."""
    lines = ["mode,epoch,train_loss,val_loss,val_mse_standardized"]
    for mode, history in curves.items():
        for values in zip(history["epoch"], history["train_loss"], history["val_loss"], history["val_mse"]):
            lines.append(f"{mode},{int(values[0])}," + ",".join(f"{v:.6g}" for v in values[1:]))
    return "\n".join(lines) + "\n"


def plot_table1(table: list[dict], config: dict):
    """Table 1 as bars: this run's test MSE per loss and activation beside the paper's."""
    plt = _pyplot()
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
    return fig


def alpha_sweep_csv(sweep: dict) -> str:
    """The alpha sweep as CSV: alpha, val_mse_standardized, test_mse, chosen."""
    return "alpha,val_mse_standardized,test_mse,chosen\n" + "".join(
        f"{a:g},{v:.6g},{t:.6g},{int(i == sweep['chosen_index'])}\n"
        for i, (a, v, t) in enumerate(zip(sweep["alphas"], sweep["val_mse"], sweep["test_mse"])))


def plot_alpha_sweep(sweep: dict, config: dict):
    """Validation (which chooses) and test MSE against alpha, naive dashed, the chosen alpha marked."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    alphas = np.asarray(sweep["alphas"])
    positive = alphas > 0
    for key, color, label in (("val_mse", "tab:orange", "validation (standardized), chooses"),
                              ("test_mse", "tab:green", "test (y units), reported only")):
        values = np.asarray(sweep[key])
        ax.loglog(alphas[positive], values[positive], "o-", color=color, label=label)
        ax.axhline(values[~positive][0] if (~positive).any() else np.nan, color=color, linestyle="--",
                   linewidth=0.8)
    ax.axvline(sweep["chosen_alpha"], color="k", linestyle=":", label=f"chosen alpha {sweep['chosen_alpha']:g}")
    ax.set_xlabel("alpha (dashed: naive, alpha = 0)")
    ax.set_ylabel("MSE")
    ax.set_title(f"alpha chosen by validation: {config['table_layers']} layers, swish, one initialization")
    ax.legend(fontsize=8)
    return fig


def write_reports(study: dict, output: pathlib.Path, quick: bool, partial: bool = False) -> list[pathlib.Path]:
    """Write results.json, CSV/JSON tables, PNG figures and summary.md into `output`; returns their paths."""
    plt = _pyplot()
    output = pathlib.Path(output)
    config = study["config"]
    written = []

    def text(name, content):
        written.append(write_text_atomic(output / name, content))

    def figure(name, fig):
        _save_figure(fig, output / name)
        plt.close(fig)
        written.append(output / name)

    text("results.json", json.dumps({**results_header(), **study}, indent=1) + "\n")
    fig6 = fig6_rows(study)
    text("fig6_mse_vs_activation.csv", rows_csv(fig6))
    figure("fig6_mse_vs_activation.png", plot_fig6(fig6, config))
    figure("fig7_predictions.png", plot_fig7(study))
    fig, curves = plot_fig8(study)
    figure("fig8_learning_curves.png", fig)
    text("fig8_learning_curves.csv", learning_curves_csv(curves))
    table = table1_rows(study)
    text("table1.csv", rows_csv(table, ["loss", "activation", "mean_test_mse", "paper"]))
    text("table1.json", json.dumps(table, indent=1) + "\n")
    figure("table1.png", plot_table1(table, config))
    sweep = study.get("alpha_sweep")
    if sweep:
        text("alpha_sweep.csv", alpha_sweep_csv(sweep))
        figure("alpha_sweep.png", plot_alpha_sweep(sweep, config))
    text("summary.md", summary_markdown(study, fig6, table, quick, partial))
    return written


def summary_markdown(study: dict, fig6: list[dict], table: list[dict], quick: bool, partial: bool = False) -> str:
    config = study["config"]
    runs = study["runs"]
    sweep = study.get("alpha_sweep")
    top = headline(study)
    profile = ("quick profile" if quick else "full profile") + (", with overrides" if partial else "")
    alpha_text = (f"alpha {top['alpha']:g}, chosen by validation from {tuple(config['alpha_grid'])}" if sweep
                  else f"alpha {top['alpha']:g}")
    lines = [f"# Sine-sum study ({profile})", "",
             f"y = sin x + sin 0.5x + sin 0.1x on [-30π, 30π]; {config['train_points']} train / "
             f"{config['val_points']} validation / {config['test_points']} test points; width {config['width']}, "
             f"hidden layers {tuple(config['layers'])}; {len(config['activations'])} activations; "
             f"{config['seeds']} networks per configuration ({config['headline_seeds']} for "
             f"{config['table_layers']} layers swish), naive and derivative runs paired by initialization; "
             f"full-batch Adam from lr {config['learning_rate']:g} ({config['lr_schedule']} schedule), "
             f"{config['epochs']} steps, validation every {config['validation_interval']}; derivative learning "
             f"{alpha_text}; {'standardized' if config['standardize_inputs'] else 'raw'} input, standardized output.",
             "", f"Time: {len(runs) + bool(sweep)} runs in {study['wall_seconds']:.1f} s wall with {study['workers']} "
             f"worker(s) ({study['run_seconds']:.1f} s of training in total).", "",
             f"**Headline ({config['table_layers']} layers, swish, mean of {top['networks']} networks):** derivative "
             f"learning {top['derivative_mean_test_mse']:.3g} against naive {top['naive_mean_test_mse']:.3g} "
             f"({top['ratio_of_means']:.3g}x lower; paired ratio and 95 % interval "
             f"{ratio_interval_text(top['ratio'], top['ratio_low'], top['ratio_high'])}: {verdict_text(top)}); the paper reports "
             f"{top['paper_derivative']:g}.", ""]
    if sweep:
        lines += ["## Alpha chosen by validation", "", markdown_table(
            ["alpha", "validation MSE (standardized)", "test MSE"],
            [[f"{alpha:g}" + (" (chosen)" if index == sweep["chosen_index"] else ""), f"{val:.4g}", f"{test:.4g}"]
             for index, (alpha, val, test) in enumerate(zip(sweep["alphas"], sweep["val_mse"], sweep["test_mse"]))])]
        lines += ["", "One initialization, 5 hidden layers, swish; the test column is reported, not used.", ""]
    lines += ["## Fig. 6: test MSE (mean over networks / best by validation)", "", markdown_table(
        ["layers", "activation", "naive mean", "naive best", "derivative mean", "derivative best",
         "naive / derivative (paired, 95 % CI)", "verdict"],
        [[row["layers"], row["activation"], f"{row['naive_mean_test_mse']:.4g}", f"{row['naive_best_test_mse']:.4g}",
          f"{row['derivative_mean_test_mse']:.4g}", f"{row['derivative_best_test_mse']:.4g}",
          ratio_interval_text(row['ratio'], row['ratio_low'], row['ratio_high']), row["verdict"]] for row in fig6])]
    deepest = [row for row in fig6 if row["layers"] == config["table_layers"]]
    winner = min(deepest, key=lambda row: row["derivative_mean_test_mse"])
    counts = {verdict: sum(row["verdict"] == verdict for row in fig6) for verdict in ("helps", "hurts", "uninformative")}
    lines += ["", f"Derivative learning helps (whole 95 % interval of the paired ratio above 1) in {counts['helps']} "
              f"of {len(fig6)} configurations and hurts in {counts['hurts']}"
              + (f"; {counts['uninformative']} are uninformative (neither mode within {LEARNED_FACTOR:g}x below the "
                 f"test MSE of predicting the mean, {fig6[0]['baseline_test_mse']:.3g}: no network learned)"
                 if counts["uninformative"] else "") + f"; at {config['table_layers']} layers the "
              f"best activation with derivative learning is {winner['activation']} "
              f"({winner['derivative_mean_test_mse']:.4g}, naive {winner['naive_mean_test_mse']:.4g}).", "",
              f"## Table 1: test MSE, derivative learning, {config['table_layers']} layers, "
              f"mean of {config['table_seeds']} networks", ""]
    cell = {(r["loss"], r["activation"]): f"{r['mean_test_mse']:.4f} (paper {r['paper']:.4f})" for r in table}
    lines.append(markdown_table(["loss", *config["table_activations"]],
                                [[loss.upper()] + [cell[loss, activation] for activation in config["table_activations"]]
                                 for loss in config["table_losses"]]))
    lines += ["", "Every number is computed by this run except those labelled paper (Table 1 of the paper).",
              "Files: fig6_mse_vs_activation.csv/.png, fig7_predictions.png, fig8_learning_curves.csv/.png, "
              "table1.csv/.json/.png, " + ("alpha_sweep.csv/.png, " if sweep else "") + "results.json.", ""]
    return "\n".join(lines)
