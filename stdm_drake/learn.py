"""Training STDMs with and without derivative learning (paper eq. 9), checkpoints, and `stdm-drake train`.

Loss = L_state + alpha * L_derivative with alpha meaning what it means in the paper's eq. 9, where
both MSEs are taken in raw units: the state error x̂_{t+1} - x_{t+1} (output units) and the
derivative error d x̂_{t+1}/dt - ẋ_{t+1} (output units per second). Per output j both residuals
are divided by the same scale, σ_y,j, the spread of the training regression targets (of Δx for the
delta parameterization), so that no output dominates while the ratio of the two terms stays the
raw-unit ratio of eq. 9:
    L = Σ_j (1/σ_j²) [ mean (x̂_j - x_j)² + alpha mean (dx̂_j/dt - ẋ_j)² ] / S,
which is exactly eq. 9 divided by σ² when every σ_j equals σ. In network units
    e_state = f_n(z_n) - y_n,    e_derivative = J_n(z_n) ż_n - (ẏ - r(ż))/σ_y,
with J_n ż_n one Jacobian-vector product (see models.py). MAE and Huber replace the squares where
asked; probabilistic members use the PETS Gaussian NLL plus the log-variance bound penalty for the
state term.

Each ensemble member has its own loss (mean over samples and outputs); the total is their sum, so
members never interact and a member trains exactly as it would alone. Ensembles train each member
on its own bootstrap resample (PETS). An alpha grid (`TrainingConfig.alpha_grid`) is a stack whose
members start from the same initial weights, see the same minibatches and differ only in alpha:
`select_alpha` trains one and keeps the member with the lowest validation state MSE. Validation
keeps each member's best weights (early stopping when no member improved for `patience` epochs).
"""
from __future__ import annotations

import argparse
import csv
import dataclasses
import hashlib
import io
import json
import math
import pathlib
import time
from typing import Callable

import numpy as np
import torch
import torch.nn.functional as F

from stdm_drake.errors import InputError
from stdm_drake.files import atomic_path, json_default, write_text_atomic
from stdm_drake.models import (ACTIVATION_NAMES, DEFAULT_ENSEMBLE_SIZE, MEMBER_PARAMETERS, MODEL_TYPES, EnsembleMLP,
                               ModelConfig, dynamics_config, parse_model_type)

LOSS_KINDS = ("mse", "mae", "huber")
LR_SCHEDULES = ("constant", "cosine")
DEFAULT_ALPHA = 1e-3   # the paper's derivative-loss weight (found by search over 1e-1 ... 1e-4)
# alpha values tried by `select_alpha` (`--alpha auto`): naive (0) and a log grid
DEFAULT_ALPHA_GRID = (0.0, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0)
CHECKPOINT_FORMAT = "stdm-drake-model"
CHECKPOINT_VERSION = 2  # 2: derivative loss scaled by the state spread (alpha as in eq. 9), no rate normalizer
HISTORY_COLUMNS = ("epoch", "train_loss", "train_state_loss", "train_derivative_loss",
                   "val_loss", "val_state_loss", "val_derivative_loss", "val_mse", "seconds")


@dataclasses.dataclass(frozen=True)
class TrainingConfig:
    """How a model is fitted. alpha = 0 is naive (state-only) training; alpha > 0 adds the derivative term.

    patience: stop after this many epochs in which no member's validation MSE improved.
    validation_interval: validate (and record a learning-curve row) every this many epochs.
    bootstrap: ensembles train each member on its own resample with replacement (PETS); single
    models always see the data once per epoch.
    lr_schedule: "constant", or "cosine": the learning rate falls from learning_rate to
    min_learning_rate along half a cosine over the max_epochs budget (per minibatch step).
    weight_decay: decoupled weight decay (AdamW) per step, as a fraction of the learning rate.
    alpha_grid: train one member per alpha (ensemble_size must equal its length) from the same
    initial weights on the same minibatches (no bootstrap); `alpha` is then ignored.
    """
    alpha: float = 0.0
    state_loss: str = "mse"
    derivative_loss: str = "mse"
    huber_delta: float = 1.0
    learning_rate: float = 1e-3
    batch_size: int = 64
    max_epochs: int = 500
    patience: int = 50
    validation_interval: int = 1
    bootstrap: bool = True
    seed: int = 0
    lr_schedule: str = "constant"
    min_learning_rate: float = 0.0
    weight_decay: float = 0.0
    alpha_grid: tuple | None = None

    def __post_init__(self):
        for name in ("state_loss", "derivative_loss"):
            if getattr(self, name) not in LOSS_KINDS:
                raise InputError(f"training config: {name} must be one of {LOSS_KINDS}, got {getattr(self, name)!r}")
        if not (np.isfinite(self.alpha) and self.alpha >= 0):
            raise InputError(f"training config: alpha must be a finite number >= 0, got {self.alpha}")
        if self.alpha_grid is not None:
            object.__setattr__(self, "alpha_grid", tuple(float(value) for value in self.alpha_grid))
            if not self.alpha_grid or not all(np.isfinite(a) and a >= 0 for a in self.alpha_grid):
                raise InputError(f"training config: alpha_grid must be finite numbers >= 0, got {self.alpha_grid}")
        if self.lr_schedule not in LR_SCHEDULES:
            raise InputError(f"training config: lr_schedule must be one of {LR_SCHEDULES}, got {self.lr_schedule!r}")
        for name in ("min_learning_rate", "weight_decay"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise InputError(f"training config: {name} must be a finite number >= 0, got {getattr(self, name)}")
        if self.min_learning_rate > self.learning_rate:
            raise InputError(f"training config: min_learning_rate {self.min_learning_rate} exceeds "
                             f"learning_rate {self.learning_rate}")
        for name in ("huber_delta", "learning_rate"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise InputError(f"training config: {name} must be positive, got {getattr(self, name)}")
        for name in ("batch_size", "max_epochs", "patience", "validation_interval"):
            if int(getattr(self, name)) < 1:
                raise InputError(f"training config: {name} must be a positive integer, got {getattr(self, name)}")

    @property
    def derivative(self) -> bool:
        """Whether any member trains with the derivative term."""
        return max(self.alpha_grid) > 0 if self.alpha_grid is not None else self.alpha > 0

    def member_alphas(self, members: int) -> torch.Tensor:
        """alpha per ensemble member (members,), float64."""
        if self.alpha_grid is None:
            return torch.full((members,), float(self.alpha), dtype=torch.float64)
        if len(self.alpha_grid) != members:
            raise InputError(f"training config: alpha_grid has {len(self.alpha_grid)} values for a model "
                             f"of {members} members")
        return torch.tensor(self.alpha_grid, dtype=torch.float64)

    def learning_rate_at(self, step: int, total_steps: int) -> float:
        """The scheduled learning rate of minibatch step `step` (0-based) of `total_steps`."""
        if self.lr_schedule == "constant":
            return self.learning_rate
        progress = min(step / max(total_steps, 1), 1.0)
        return self.min_learning_rate + 0.5 * (self.learning_rate - self.min_learning_rate) * (
            1.0 + math.cos(math.pi * progress))


@dataclasses.dataclass
class RegressionData:
    """Training pairs in raw units. inputs z (N, in); targets y (N, out); for derivative learning
    also input_rates ż (N, in) (the chain-rule tangent) and target_rates ẏ (N, out)."""
    inputs: np.ndarray
    targets: np.ndarray
    input_rates: np.ndarray | None = None
    target_rates: np.ndarray | None = None

    @classmethod
    def from_transitions(cls, transitions) -> "RegressionData":
        """From a dataset Transitions: z = [x_t, a_t], y = x_{t+1}, ż = [ẋ_t, Δa_t/Δt], ẏ = ẋ_{t+1}."""
        return cls(inputs=np.hstack([transitions.state, transitions.action]),
                   targets=np.asarray(transitions.next_state),
                   input_rates=np.hstack([transitions.state_rate, transitions.action_rate]),
                   target_rates=np.asarray(transitions.next_state_rate))

    @property
    def has_rates(self) -> bool:
        return self.input_rates is not None and self.target_rates is not None

    def __len__(self) -> int:
        return len(self.inputs)

    def check(self, config: ModelConfig, *, need_rates: bool, name: str) -> None:
        """Shapes against the model and finiteness; raises InputError naming the array."""
        expected = {"inputs": config.input_dim, "targets": config.output_dim,
                    "input_rates": config.input_dim, "target_rates": config.output_dim}
        if need_rates and not self.has_rates:
            raise InputError(f"{name} data: derivative learning (alpha > 0) needs input_rates and target_rates")
        count = None
        for field, width in expected.items():
            values = getattr(self, field)
            if values is None:
                continue
            values = np.asarray(values)
            if values.ndim != 2 or values.shape[1] != width:
                raise InputError(f"{name} data: {field} has shape {values.shape}, expected (N, {width})")
            if count is not None and len(values) != count:
                raise InputError(f"{name} data: {field} has {len(values)} rows, expected {count}")
            count = len(values)
            bad = int(np.count_nonzero(~np.isfinite(values)))
            if bad:
                raise InputError(f"{name} data: {field} contains {bad} NaN or inf values")
        if not count:
            raise InputError(f"{name} data is empty")

    def fingerprint(self) -> str:
        digest = hashlib.sha256()
        for field in ("inputs", "targets", "input_rates", "target_rates"):
            values = getattr(self, field)
            if values is not None:
                digest.update(np.ascontiguousarray(values, dtype=np.float64).tobytes())
        return digest.hexdigest()


@dataclasses.dataclass
class StandardizedData:
    """Tensors in the network's units (model dtype): z_n (N, in), y_n (N, out), and for derivative
    learning ż_n = ż/σ_z (N, in) and the derivative target (ẏ - r(ż))/σ_y (N, out); see module doc."""
    inputs: torch.Tensor
    targets: torch.Tensor
    input_rates: torch.Tensor | None
    target_rates: torch.Tensor | None


def fit_normalizers(model: EnsembleMLP, data: RegressionData) -> None:
    """Input and output statistics from training data (raw units, float64). With
    standardize_inputs=False the input normalizer stays the identity."""
    inputs = np.asarray(data.inputs, dtype=np.float64)
    if model.config.standardize_inputs:
        model.input_normalizer.fit(inputs)
    model.output_normalizer.fit(np.asarray(data.targets, dtype=np.float64) - _residual(model.config, inputs))


def _residual(config: ModelConfig, values: np.ndarray) -> np.ndarray:
    return values[:, :config.output_dim] if config.residual else np.zeros((len(values), config.output_dim))


def standardize(model: EnsembleMLP, data: RegressionData) -> StandardizedData:
    """Raw arrays -> network units with the model's normalizers (computed in float64, then cast)."""
    dtype = next(model.parameters()).dtype
    z_mean, z_std = (value.double().numpy() for value in (model.input_normalizer.mean, model.input_normalizer.std))
    y_mean, y_std = (value.double().numpy() for value in (model.output_normalizer.mean, model.output_normalizer.std))
    inputs = np.asarray(data.inputs, dtype=np.float64)
    result = StandardizedData(
        inputs=torch.from_numpy((inputs - z_mean) / z_std).to(dtype),
        targets=torch.from_numpy((np.asarray(data.targets, np.float64) - _residual(model.config, inputs) - y_mean)
                                 / y_std).to(dtype),
        input_rates=None, target_rates=None)
    if data.has_rates:
        input_rates = np.asarray(data.input_rates, dtype=np.float64)
        result.input_rates = torch.from_numpy(input_rates / z_std).to(dtype)
        result.target_rates = torch.from_numpy((np.asarray(data.target_rates, np.float64)
                                                - _residual(model.config, input_rates)) / y_std).to(dtype)
    return result


def member_point_loss(kind: str, prediction: torch.Tensor, target: torch.Tensor,
                      huber_delta: float = 1.0) -> torch.Tensor:
    """MSE, MAE or Huber loss per ensemble member: (E, B, d) pairs -> (E,), the mean over B and d."""
    if kind == "mse":
        values = (prediction - target) ** 2
    elif kind == "mae":
        values = (prediction - target).abs()
    elif kind == "huber":
        values = F.huber_loss(prediction, target, reduction="none", delta=huber_delta)
    else:
        raise InputError(f"loss must be one of {LOSS_KINDS}, got {kind!r}")
    return values.mean(dim=(-2, -1))


def member_gaussian_nll(mean: torch.Tensor, logvar: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """PETS Gaussian negative log-likelihood (without constants) per member: mean of (μ - y)² e^{-s} + s -> (E,)."""
    return ((mean - target) ** 2 * torch.exp(-logvar) + logvar).mean(dim=(-2, -1))


@dataclasses.dataclass
class LossTerms:
    """Per-member loss terms (E,): state term, derivative term (None without derivative learning) and
    total = state + alpha ⊙ derivative. `objective` (their sum over members) is what is minimized."""
    total: torch.Tensor
    state: torch.Tensor
    derivative: torch.Tensor | None

    @property
    def objective(self) -> torch.Tensor:
        return self.total.sum()

    def means(self) -> tuple[float, float, float]:
        """(total, state, derivative) averaged over members, as plain floats (derivative 0 when absent)."""
        return (self.total.mean().item(), self.state.mean().item(),
                self.derivative.mean().item() if self.derivative is not None else 0.0)


def batch_losses(model: EnsembleMLP, config: TrainingConfig, inputs, targets, input_rates=None,
                 target_rates=None) -> LossTerms:
    """Loss terms on standardized tensors (E, B, ·) or (B, ·)."""
    if config.derivative:
        outputs, tangents = model.normalized_outputs_with_tangent(inputs, input_rates)
    else:
        outputs, tangents = model.normalized_outputs(inputs), None
    return losses_from_outputs(model, config, outputs, tangents, targets, target_rates)


def losses_from_outputs(model: EnsembleMLP, config: TrainingConfig, outputs, tangents, targets,
                        target_rates) -> LossTerms:
    """Loss terms from head outputs (E, B, ·) and mean-head tangents J_n ż_n (or None: no derivative term)."""
    mean, logvar = model.split_head(outputs)
    target = model.per_member(targets)
    if logvar is None:
        state_term = member_point_loss(config.state_loss, mean, target, config.huber_delta)
    else:
        state_term = member_gaussian_nll(mean, logvar, target) + model.member_logvar_bound_penalty()
    if tangents is None:
        return LossTerms(total=state_term, state=state_term, derivative=None)
    derivative_term = member_point_loss(config.derivative_loss, tangents, model.per_member(target_rates),
                                        config.huber_delta)
    alphas = config.member_alphas(model.config.ensemble_size).to(derivative_term.dtype)
    return LossTerms(total=state_term + alphas * derivative_term, state=state_term, derivative=derivative_term)


def training_step(model: EnsembleMLP, optimizer: torch.optim.Optimizer, config: TrainingConfig,
                  data: StandardizedData, indices: torch.Tensor) -> tuple[float, float, float]:
    """One optimizer step on the minibatch data[indices] (indices (E, B): per-member rows).
    Returns the loss terms averaged over members."""
    rates = config.derivative
    terms = batch_losses(model, config, data.inputs[indices], data.targets[indices],
                         data.input_rates[indices] if rates else None, data.target_rates[indices] if rates else None)
    optimizer.zero_grad(set_to_none=True)
    terms.objective.backward()
    optimizer.step()
    return terms.means()


@torch.no_grad()
def validation_scores(model: EnsembleMLP, config: TrainingConfig, data: StandardizedData) -> dict:
    """Validation loss terms (same formula as training, averaged over members) and per-member
    standardized MSE of the state (the selection criterion), (E,) float64."""
    if config.derivative and data.input_rates is not None:
        outputs, tangents = model.normalized_outputs_with_tangent(data.inputs, data.input_rates)
    else:
        outputs, tangents = model.normalized_outputs(data.inputs), None
    total, state_term, derivative_term = losses_from_outputs(model, config, outputs, tangents, data.targets,
                                                             data.target_rates).means()
    mean, _ = model.split_head(outputs)
    member_mse = ((mean - data.targets) ** 2).mean(dim=(1, 2)).double()
    return dict(loss=total, state=state_term, derivative=derivative_term, member_mse=member_mse)


@dataclasses.dataclass
class TrainResult:
    """A trained model (each member at its best validation epoch) and its learning curves."""
    model: EnsembleMLP
    history: dict
    best_epochs: list
    best_scores: list
    epochs_run: int
    stopped_early: bool
    member_val_mse: list = dataclasses.field(default_factory=list)  # per validation row: (E,) standardized MSE


def _seeds(seed: int) -> tuple[int, int]:
    """Independent integer seeds for weight initialization and for bootstrap/shuffling."""
    init_seed, data_seed = np.random.SeedSequence(seed).generate_state(2, dtype=np.uint64)
    return int(init_seed % (2 ** 63)), int(data_seed % (2 ** 63))


def build_model(model_config: ModelConfig, seed: int) -> EnsembleMLP:
    """A freshly initialized model (same seed -> same weights)."""
    torch.manual_seed(seed)
    return EnsembleMLP(model_config, generator=torch.Generator().manual_seed(_seeds(seed)[0]))


def train_model(model_config: ModelConfig, training_config: TrainingConfig, train_data: RegressionData,
                val_data: RegressionData, *, checkpoint_path=None, checkpoint_every: int = 10,
                metadata: dict | None = None, resume: bool = False,
                on_epoch: Callable[[dict], None] | None = None) -> TrainResult:
    """Fit a model with Adam on minibatches; keep per-member best-by-validation weights.

    checkpoint_path: written atomically every `checkpoint_every` epochs and at the end (weights =
    current best, plus everything needed to resume), only at validation epochs. resume=True
    continues from that file exactly as if training had not stopped (same weights, same curves).
    on_epoch(row) is called with each new history row.
    """
    derivative = training_config.derivative
    train_data.check(model_config, need_rates=derivative, name="training")
    val_data.check(model_config, need_rates=False, name="validation")
    members = model_config.ensemble_size
    grid = training_config.alpha_grid is not None
    training_config.member_alphas(members)  # checks the grid size
    data_seed = _seeds(training_config.seed)[1]
    fingerprint = hashlib.sha256((train_data.fingerprint() + val_data.fingerprint()).encode()).hexdigest()

    model = build_model(model_config, training_config.seed)
    if grid:  # every member starts from the single model this seed gives
        single = build_model(dataclasses.replace(model_config, ensemble_size=1), training_config.seed)
        with torch.no_grad():
            for name, value in single.named_parameters():
                model.get_parameter(name).copy_(value.expand_as(model.get_parameter(name)))
    fit_normalizers(model, train_data)
    # fused: one kernel for all parameters (elementwise, deterministic; about 1 ms less per step on a CPU)
    if training_config.weight_decay > 0:
        optimizer = torch.optim.AdamW(model.parameters(), lr=training_config.learning_rate,
                                      weight_decay=training_config.weight_decay, fused=True)
    else:
        optimizer = torch.optim.Adam(model.parameters(), lr=training_config.learning_rate, fused=True)
    generator = torch.Generator().manual_seed(data_seed)
    count = len(train_data)
    if members > 1 and training_config.bootstrap and not grid:
        bootstrap = torch.randint(0, count, (members, count), generator=generator)
    else:
        bootstrap = torch.arange(count).expand(members, count).clone()
    history = {column: [] for column in HISTORY_COLUMNS}
    best_weights = {name: value.detach().clone() for name, value in model.state_dict().items()}
    best_scores = torch.full((members,), float("inf"), dtype=torch.float64)
    best_epochs = torch.zeros(members, dtype=torch.int64)
    epoch, since_improvement, stopped_early, finished = 0, 0, False, False

    if resume:
        if checkpoint_path is None:
            raise InputError("resume=True needs the checkpoint_path to continue from")
        state = load_checkpoint(checkpoint_path)
        resume_state = state.resume
        if resume_state is None:
            raise InputError(f"{checkpoint_path}: checkpoint holds no training state to resume")
        if state.model_config != model_config or state.training_config != training_config:
            raise InputError(f"{checkpoint_path}: model or training options differ from the checkpoint's; "
                             "resume with the same options")
        if resume_state["data_fingerprint"] != fingerprint:
            raise InputError(f"{checkpoint_path}: training/validation data differ from the checkpoint's")
        model.load_state_dict(resume_state["weights"])
        optimizer.load_state_dict(resume_state["optimizer"])
        generator.set_state(resume_state["generator"])
        bootstrap = resume_state["bootstrap"]
        best_weights = resume_state["best_weights"]
        best_scores = resume_state["best_scores"]
        best_epochs = resume_state["best_epochs"]
        epoch = int(resume_state["epoch"])
        since_improvement = int(resume_state["epochs_since_improvement"])
        stopped_early = bool(resume_state["stopped_early"])
        finished = bool(resume_state["finished"])
        history = {column: list(state.history.get(column, [])) for column in HISTORY_COLUMNS}

    train_tensors = standardize(model, train_data)
    val_tensors = standardize(model, val_data)
    batch_size = training_config.batch_size

    def snapshot(finished: bool) -> dict:
        return dict(epoch=epoch, weights={k: v.detach().clone() for k, v in model.state_dict().items()},
                    optimizer=optimizer.state_dict(), generator=generator.get_state(), bootstrap=bootstrap,
                    best_weights=best_weights, best_scores=best_scores, best_epochs=best_epochs,
                    epochs_since_improvement=since_improvement, stopped_early=stopped_early,
                    finished=finished, data_fingerprint=fingerprint)

    def write_checkpoint(finished: bool) -> None:
        if checkpoint_path is None:
            return
        best_model = EnsembleMLP(model_config).to(next(model.parameters()).dtype)
        best_model.load_state_dict(best_weights)
        save_checkpoint(checkpoint_path, best_model, training_config=training_config, history=history,
                        metadata=metadata, resume_state=snapshot(finished))

    member_curves = []  # this call's validation rows only (not restored on resume)
    interval = training_config.validation_interval
    steps_per_epoch = -(-count // batch_size)
    total_steps = steps_per_epoch * training_config.max_epochs
    scheduled = training_config.lr_schedule != "constant"
    sums, batches, started, last_written = np.zeros(3), 0, time.perf_counter(), epoch
    while not finished and epoch < training_config.max_epochs and since_improvement < training_config.patience:
        model.train()
        if grid:  # one minibatch order shared by every member
            order = torch.argsort(torch.rand(1, count, generator=generator), dim=1).expand(members, count)
        else:
            order = torch.argsort(torch.rand(members, count, generator=generator), dim=1)
        epoch_rows = bootstrap.gather(1, order)
        for index, start in enumerate(range(0, count, batch_size)):
            if scheduled:
                rate = training_config.learning_rate_at(epoch * steps_per_epoch + index, total_steps)
                for group in optimizer.param_groups:
                    group["lr"] = rate
            sums += training_step(model, optimizer, training_config, train_tensors,
                                  epoch_rows[:, start:start + batch_size])
            batches += 1
        epoch += 1
        if epoch % interval and epoch < training_config.max_epochs:
            continue
        model.eval()
        scores = validation_scores(model, training_config, val_tensors)
        improved = scores["member_mse"] < best_scores
        if bool(improved.any()):
            for name, value in model.state_dict().items():
                if name.split(".")[0] in MEMBER_PARAMETERS:
                    best_weights[name][improved] = value.detach()[improved]
                else:
                    best_weights[name] = value.detach().clone()
            best_scores = torch.where(improved, scores["member_mse"], best_scores)
            best_epochs = torch.where(improved, torch.tensor(epoch), best_epochs)
            since_improvement = 0
        else:
            since_improvement += interval
        stopped_early = since_improvement >= training_config.patience
        means = sums / max(batches, 1)
        row = dict(epoch=epoch, train_loss=means[0], train_state_loss=means[1], train_derivative_loss=means[2],
                   val_loss=scores["loss"], val_state_loss=scores["state"], val_derivative_loss=scores["derivative"],
                   val_mse=float(scores["member_mse"].mean()), seconds=time.perf_counter() - started)
        for column in HISTORY_COLUMNS:
            history[column].append(row[column])
        member_curves.append(scores["member_mse"].tolist())
        sums, batches, started = np.zeros(3), 0, time.perf_counter()
        done = stopped_early or epoch >= training_config.max_epochs
        if checkpoint_path is not None and (done or epoch - last_written >= checkpoint_every):
            write_checkpoint(finished=done)
            last_written = epoch
        if on_epoch is not None:
            on_epoch(row)
        finished = done
    if checkpoint_path is not None and not history["epoch"]:
        write_checkpoint(finished=True)
    model.load_state_dict(best_weights)
    model.eval()
    return TrainResult(model=model, history=history, best_epochs=best_epochs.tolist(),
                       best_scores=best_scores.tolist(), epochs_run=epoch, stopped_early=stopped_early,
                       member_val_mse=member_curves)


@dataclasses.dataclass
class AlphaSelection:
    """Outcome of an alpha grid: per alpha the best validation state MSE (standardized, the mean over
    outputs of ((x̂ - x)/σ_y)²) and the epoch it was reached; `index` is the chosen entry."""
    alphas: tuple
    val_mse: list
    best_epochs: list
    index: int

    @property
    def alpha(self) -> float:
        return float(self.alphas[self.index])

    def as_dict(self) -> dict:
        return dict(alphas=[float(a) for a in self.alphas], val_mse=[float(v) for v in self.val_mse],
                    best_epochs=[int(e) for e in self.best_epochs], chosen_alpha=self.alpha, chosen_index=self.index)

    @classmethod
    def from_dict(cls, values: dict) -> "AlphaSelection":
        return cls(alphas=tuple(values["alphas"]), val_mse=list(values["val_mse"]),
                   best_epochs=list(values["best_epochs"]), index=int(values["chosen_index"]))


def train_alpha_grid(model_config: ModelConfig, training_config: TrainingConfig, train_data: RegressionData,
                     val_data: RegressionData, *, alphas=DEFAULT_ALPHA_GRID,
                     on_epoch: Callable[[dict], None] | None = None) -> tuple[TrainResult, AlphaSelection]:
    """One single-member network per alpha, trained as one stack from the same initial weights on the
    same minibatches (so member k equals training alphas[k] alone), and the selection: the lowest
    validation state MSE (ties go to the earlier alpha). model_config's ensemble_size is ignored.
    Returns the whole stack (member k: alphas[k]) and the selection."""
    alphas = tuple(float(a) for a in alphas)
    grid_config = dataclasses.replace(model_config, ensemble_size=len(alphas))
    grid_training = dataclasses.replace(training_config, alpha_grid=alphas, alpha=0.0)
    result = train_model(grid_config, grid_training, train_data, val_data, on_epoch=on_epoch)
    scores = np.asarray(result.best_scores)
    index = int(np.flatnonzero(scores == scores.min())[0])
    return result, AlphaSelection(alphas=alphas, val_mse=scores.tolist(), best_epochs=list(result.best_epochs),
                                  index=index)


def select_alpha(model_config: ModelConfig, training_config: TrainingConfig, train_data: RegressionData,
                 val_data: RegressionData, *, alphas=DEFAULT_ALPHA_GRID,
                 on_epoch: Callable[[dict], None] | None = None) -> tuple[TrainResult, AlphaSelection]:
    """Choose alpha by validation (`train_alpha_grid`) and return the chosen single-member model (its
    history is the whole grid's) with the selection. With 0 in `alphas` the chosen model is at least as
    good as naive training on validation, by construction."""
    result, selection = train_alpha_grid(model_config, training_config, train_data, val_data, alphas=alphas,
                                         on_epoch=on_epoch)
    index = selection.index
    chosen = TrainResult(model=result.model.member(index), history=result.history,
                         best_epochs=[result.best_epochs[index]], best_scores=[result.best_scores[index]],
                         epochs_run=result.epochs_run, stopped_early=result.stopped_early)
    return chosen, selection


# -- checkpoints ----------------------------------------------------------------------------------

@dataclasses.dataclass
class Checkpoint:
    """A loaded checkpoint: the model (best weights) and what was stored beside it."""
    path: pathlib.Path
    model: EnsembleMLP
    model_config: ModelConfig
    training_config: TrainingConfig | None
    metadata: dict
    history: dict
    resume: dict | None


def save_checkpoint(path, model: EnsembleMLP, *, training_config: TrainingConfig | None = None,
                    history: dict | None = None, metadata: dict | None = None,
                    resume_state: dict | None = None) -> pathlib.Path:
    """Write one file (atomically) holding weights, architecture, normalizers, options and metadata.

    Only tensors and plain Python values are stored, so it loads with torch.load(weights_only=True).
    """
    content = {
        "format": CHECKPOINT_FORMAT,
        "format_version": CHECKPOINT_VERSION,
        "model_config": dataclasses.asdict(model.config),
        "weights": {name: value.detach().cpu().clone() for name, value in model.state_dict().items()},
        "training_config": dataclasses.asdict(training_config) if training_config is not None else None,
        "history": {column: [float(v) for v in values] for column, values in (history or {}).items()},
        "metadata": json.loads(json.dumps(metadata or {}, default=json_default)),
        "resume": resume_state,
    }
    path = pathlib.Path(path)
    with atomic_path(path) as temp:
        torch.save(content, temp)
    return path


def load_checkpoint(path) -> Checkpoint:
    """Read and validate a checkpoint; any problem raises InputError (FileNotFoundError if missing)."""
    path = pathlib.Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint not found: {path}")
    with open(path, "rb") as f:
        magic = f.read(8)
    if not magic.startswith(b"PK\x03\x04"):  # torch.save writes a zip archive
        kind = " (it is an HDF5 file: a dataset?)" if magic == b"\x89HDF\r\n\x1a\n" else ""
        raise InputError(f"{path}: not a readable stdm-drake checkpoint: not a PyTorch checkpoint file{kind}")
    try:
        content = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # truncated zip, disallowed pickle content, ...
        detail = " ".join(str(error).split()).split(". ")[0] or type(error).__name__  # first sentence only
        raise InputError(f"{path}: not a readable stdm-drake checkpoint (truncated or corrupt?): {detail}") from None
    if not isinstance(content, dict) or content.get("format") != CHECKPOINT_FORMAT:
        raise InputError(f"{path}: not a stdm-drake model checkpoint (format field missing or wrong)")
    if content.get("format_version") != CHECKPOINT_VERSION:
        hint = (" (written before the derivative loss took the paper's alpha scaling: retrain it)"
                if content.get("format_version") == 1 else "")
        raise InputError(f"{path}: checkpoint format version {content.get('format_version')}, "
                         f"this stdm-drake reads {CHECKPOINT_VERSION}{hint}")
    try:
        model_config = ModelConfig.from_dict(dict(content["model_config"]))
        training = content.get("training_config")
        training_config = TrainingConfig(**training) if training is not None else None
        model = EnsembleMLP(model_config)
        model.load_state_dict(content["weights"])
    except InputError as error:
        raise InputError(f"{path}: {error}") from None
    except (KeyError, TypeError, RuntimeError, ValueError) as error:
        detail = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise InputError(f"{path}: inconsistent checkpoint contents: {detail}") from None
    if not all(torch.isfinite(value).all() for value in model.state_dict().values()):
        raise InputError(f"{path}: checkpoint weights contain NaN or inf")
    model.eval()
    return Checkpoint(path=path, model=model, model_config=model_config, training_config=training_config,
                      metadata=dict(content.get("metadata") or {}), history=dict(content.get("history") or {}),
                      resume=content.get("resume"))


def load_model(path, *, state_dim: int | None = None, action_dim: int | None = None) -> Checkpoint:
    """load_checkpoint plus a check of the STDM sizes the caller expects (InputError on mismatch)."""
    checkpoint = load_checkpoint(path)
    config = checkpoint.model_config
    wanted = (state_dim if state_dim is not None else config.state_dim,
              action_dim if action_dim is not None else config.action_dim)
    if (config.state_dim, config.action_dim) != wanted:
        raise InputError(f"{checkpoint.path}: model has state dim {config.state_dim} and action dim "
                         f"{config.action_dim}, expected state dim {wanted[0]} and action dim {wanted[1]}")
    return checkpoint


def history_csv(history: dict) -> str:
    """Learning curves as CSV text (one row per epoch, HISTORY_COLUMNS)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(HISTORY_COLUMNS)
    for values in zip(*(history[column] for column in HISTORY_COLUMNS)):
        writer.writerow([int(values[0])] + [f"{value:.9g}" for value in values[1:]])
    return buffer.getvalue()


# -- `stdm-drake train` -----------------------------------------------------------------------------

def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dataset", type=pathlib.Path, help="dataset file written by `stdm-drake collect` (.h5)")
    parser.add_argument("--output", "-o", type=pathlib.Path, required=True,
                        help="output folder: seed<N>/checkpoint.pt, seed<N>/curves.csv, summary.json")
    parser.add_argument("--model", default="DD", type=str.upper, choices=tuple(MODEL_TYPES),
                        help="model type: D/P/DE/PE naive, DD/PD/DED/PED with the derivative loss (default DD)")
    parser.add_argument("--derivative", choices=("on", "off"),
                        help="override the derivative loss the model type implies")
    parser.add_argument("--alpha", type=parse_alpha, default=DEFAULT_ALPHA,
                        help="derivative loss weight as in the paper's eq. 9 (default 1e-3, the paper's), or 'auto': "
                             "chosen by validation state MSE from --alpha-grid (naive included)")
    parser.add_argument("--alpha-grid", type=float, nargs="+", default=list(DEFAULT_ALPHA_GRID),
                        help="alphas tried by --alpha auto (default 0 and 1e-5 ... 1e2)")
    parser.add_argument("--activation", choices=ACTIVATION_NAMES, default="swish", help="hidden activation")
    parser.add_argument("--hidden-width", type=int, default=100, help="units per hidden layer (default 100)")
    parser.add_argument("--hidden-layers", type=int, default=3, help="hidden layers (default 3)")
    parser.add_argument("--ensemble-size", type=int, default=DEFAULT_ENSEMBLE_SIZE,
                        help="members of DE/PE-type models (default 5)")
    parser.add_argument("--direct", action="store_true",
                        help="predict x_{t+1} directly instead of the delta x_{t+1} - x_t")
    parser.add_argument("--state-loss", choices=LOSS_KINDS, default="mse")
    parser.add_argument("--derivative-loss", choices=LOSS_KINDS, default="mse")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="one model per seed (default 0)")
    parser.add_argument("--train", type=int, help="training trajectories (per group with --per-group)")
    parser.add_argument("--val", type=int, help="validation trajectories (per group with --per-group)")
    parser.add_argument("--test", type=int, help="test trajectories (default: all the rest)")
    parser.add_argument("--per-group", choices=("on", "off"),
                        help="split per initial-pose group (default: on for tracking data, off otherwise)")
    parser.add_argument("--split-seed", type=int, default=0, help="seed of the trajectory split (default 0)")
    parser.add_argument("--derivative-source", choices=("true", "planned"),
                        help="derivative targets (default: the dataset's: true for excitation, planned for tracking)")
    parser.add_argument("--action-rate", choices=("forward_difference", "zero_order_hold"),
                        default="forward_difference", help="how Δa/Δt is formed (default forward_difference)")
    parser.add_argument("--epochs", type=int, default=500, help="maximum epochs (default 500)")
    parser.add_argument("--patience", type=int, default=50, help="early-stopping patience in epochs (default 50)")
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate (default 1e-3)")
    parser.add_argument("--lr-schedule", choices=LR_SCHEDULES, default="constant",
                        help="constant, or cosine decay to --min-lr over the --epochs budget (default constant)")
    parser.add_argument("--min-lr", type=float, default=0.0, help="final learning rate of the cosine schedule")
    parser.add_argument("--weight-decay", type=float, default=0.0,
                        help="decoupled weight decay (AdamW), default 0 (plain Adam)")
    parser.add_argument("--checkpoint-every", type=int, default=10, help="epochs between checkpoint writes")
    parser.add_argument("--threads", type=int, default=1,
                        help="torch CPU threads (default 1: bitwise-reproducible on any machine)")
    parser.add_argument("--resume", action="store_true", help="continue interrupted runs in the output folder")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def parse_alpha(text: str):
    """--alpha: a number >= 0 or the word 'auto'."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0 or 'auto', got {text!r}") from None
    if not (np.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected a number >= 0 or 'auto', got {text!r}")
    return value


def fit_model(model_config: ModelConfig, training_config: TrainingConfig, train_data: RegressionData,
              val_data: RegressionData, *, alpha="fixed", alphas=DEFAULT_ALPHA_GRID, checkpoint_path=None,
              checkpoint_every: int = 10, metadata: dict | None = None, resume: bool = False,
              on_epoch: Callable[[dict], None] | None = None) -> tuple[TrainResult, AlphaSelection | None]:
    """Train one model as `stdm-drake train` does. alpha="fixed": training_config.alpha as given;
    alpha="auto": `select_alpha` over `alphas` first; a single-member model is then the chosen grid
    member itself, an ensemble is trained at the chosen alpha. The selection is stored in the
    checkpoint's metadata (`alpha_selection`); resuming an "auto" run reuses a stored selection."""
    metadata = dict(metadata or {})
    selection = None
    if alpha == "auto":
        stored = None
        if resume and checkpoint_path is not None and pathlib.Path(checkpoint_path).exists():
            stored = load_checkpoint(checkpoint_path)
        if stored is not None and "alpha_selection" in stored.metadata:
            selection = AlphaSelection.from_dict(stored.metadata["alpha_selection"])
            if stored.resume is None:  # a finished single-member selection: nothing left to train
                return TrainResult(model=stored.model, history=stored.history,
                                   best_epochs=list(selection.best_epochs[selection.index:selection.index + 1]),
                                   best_scores=[selection.val_mse[selection.index]],
                                   epochs_run=int(stored.history.get("epoch", [0])[-1] if stored.history.get("epoch")
                                                  else 0), stopped_early=False), selection
        else:
            chosen, selection = select_alpha(model_config, training_config, train_data, val_data, alphas=alphas,
                                             on_epoch=on_epoch)
            resume = False
            if model_config.ensemble_size == 1:
                metadata["alpha_selection"] = selection.as_dict()
                if checkpoint_path is not None:
                    save_checkpoint(checkpoint_path, chosen.model,
                                    training_config=dataclasses.replace(training_config, alpha=selection.alpha),
                                    history=chosen.history, metadata=metadata)
                return chosen, selection
        metadata["alpha_selection"] = selection.as_dict()
        training_config = dataclasses.replace(training_config, alpha=selection.alpha)
    result = train_model(model_config, training_config, train_data, val_data, checkpoint_path=checkpoint_path,
                         checkpoint_every=checkpoint_every, metadata=metadata, resume=resume, on_epoch=on_epoch)
    return result, selection


def alpha_selection_csv(selection: AlphaSelection) -> str:
    """The alpha grid's validation curve as CSV: alpha, val_state_mse_standardized, best_epoch, chosen."""
    lines = ["alpha,val_state_mse_standardized,best_epoch,chosen"]
    for index, (alpha, score, epoch) in enumerate(zip(selection.alphas, selection.val_mse, selection.best_epochs)):
        lines.append(f"{alpha:g},{score:.9g},{int(epoch)},{int(index == selection.index)}")
    return "\n".join(lines) + "\n"


def plot_alpha_selection(selection: AlphaSelection, path, title: str = "") -> pathlib.Path:
    """Validation state MSE against alpha (log axes; alpha = 0 drawn as a dashed line), PNG, atomically."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    alphas, scores = np.asarray(selection.alphas), np.asarray(selection.val_mse)
    figure, axis = plt.subplots(figsize=(5.5, 3.8))
    positive = alphas > 0
    axis.loglog(alphas[positive], scores[positive], "o-", color="tab:orange", label="derivative learning")
    for score in scores[~positive]:
        axis.axhline(score, color="tab:blue", linestyle="--", label="naive (alpha = 0)")
    axis.plot([selection.alpha if selection.alpha > 0 else alphas[positive].min()], [scores[selection.index]], "k*",
              markersize=14, label=f"chosen: alpha = {selection.alpha:g}")
    axis.set_xlabel("alpha (paper eq. 9)")
    axis.set_ylabel("validation state MSE (standardized)")
    axis.set_title(title or "alpha chosen by validation")
    axis.legend(fontsize=8)
    path = pathlib.Path(path)
    with atomic_path(path) as temp:
        figure.savefig(temp, format="png", dpi=110, bbox_inches="tight")
    plt.close(figure)
    return path


def default_split_sizes(pool: int, n_train: int | None, n_val: int | None, n_test: int | None):
    """Fill unset split sizes from `pool` trajectories (per group with --per-group): 20 % validation,
    20 % test, the rest training; n_test None means "all the rest" for split_trajectories."""
    n_val = n_val if n_val is not None else max(1, round(0.2 * pool))
    if n_train is None:
        n_train = pool - n_val - (n_test if n_test is not None else max(1, round(0.2 * pool)))
    if n_train < 1:
        raise InputError(f"the split leaves {n_train} training trajectories (of {pool} per split unit)")
    return n_train, n_val, n_test


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from stdm_drake import __version__
    from stdm_drake.dataset import load_dataset, split_trajectories

    if args.threads < 1:
        raise InputError(f"--threads must be >= 1, got {args.threads}")
    torch.set_num_threads(args.threads)
    model_type = parse_model_type(args.model)
    derivative = model_type.derivative if args.derivative is None else args.derivative == "on"
    auto = args.alpha == "auto"
    if derivative and not auto and not args.alpha > 0:
        raise InputError(f"derivative learning needs --alpha > 0 or --alpha auto, got {args.alpha}")
    if auto and not derivative:
        raise InputError(f"--alpha auto chooses the derivative-loss weight; model type {args.model} trains without "
                         "it (use DD, PD, DED or PED, or --derivative on)")
    if auto and (not args.alpha_grid or not all(np.isfinite(a) and a >= 0 for a in args.alpha_grid)):
        raise InputError(f"--alpha-grid needs numbers >= 0, got {args.alpha_grid}")
    dataset = load_dataset(args.dataset)
    per_group = (dataset.protocol == "tracking") if args.per_group is None else args.per_group == "on"
    pool = int(np.unique(dataset.groups, return_counts=True)[1].min()) if per_group else dataset.num_trajectories
    n_train, n_val, n_test = default_split_sizes(pool, args.train, args.val, args.test)
    split = split_trajectories(dataset.groups, n_train, n_val, n_test, args.split_seed, per_group)
    source = args.derivative_source or dataset.default_derivative_source
    train_data = RegressionData.from_transitions(
        dataset.transitions(split.train, derivative_source=source, action_rate=args.action_rate))
    val_data = RegressionData.from_transitions(
        dataset.transitions(split.val, derivative_source=source, action_rate=args.action_rate))
    state_dim, action_dim = train_data.targets.shape[1], train_data.inputs.shape[1] - train_data.targets.shape[1]
    model_config = dynamics_config(
        state_dim=state_dim, action_dim=action_dim, delta=not args.direct, hidden_width=args.hidden_width,
        hidden_layers=args.hidden_layers, activation=args.activation,
        ensemble_size=args.ensemble_size if model_type.ensemble else 1, probabilistic=model_type.probabilistic)
    name = (("P" if model_type.probabilistic else "D") + ("E" if model_type.ensemble else "")
            + ("D" if derivative else ""))
    output = pathlib.Path(args.output)
    summary = dict(model_type=name, dataset=str(args.dataset), dataset_sha256=dataset.sha256,
                   split={key: list(map(int, value)) for key, value in split.as_dict().items()}, seeds={})
    print(f"{name}: {model_config.hidden_layers}x{model_config.hidden_width} {model_config.activation}, "
          f"{model_config.ensemble_size} member(s), {'delta' if model_config.residual else 'direct'}; "
          f"train {len(split.train)} / val {len(split.val)} / test {len(split.test)} trajectories "
          f"({len(train_data)} / {len(val_data)} transitions)")
    for seed in args.seeds:
        training_config = TrainingConfig(
            alpha=(0.0 if auto else args.alpha) if derivative else 0.0, state_loss=args.state_loss,
            derivative_loss=args.derivative_loss, learning_rate=args.lr, batch_size=args.batch_size,
            max_epochs=args.epochs, patience=args.patience, seed=seed, lr_schedule=args.lr_schedule,
            min_learning_rate=args.min_lr, weight_decay=args.weight_decay)
        folder = output / f"seed{seed}"
        checkpoint_path = folder / "checkpoint.pt"
        resume = False
        if checkpoint_path.exists():
            if not args.resume:
                raise InputError(f"{checkpoint_path} exists; pass --resume to continue it or choose another --output")
            resume = True
        metadata = dict(model_type=name, dataset_path=str(args.dataset), dataset_sha256=dataset.sha256,
                        protocol=dataset.protocol, sample_period=dataset.sample_period,
                        split=summary["split"], split_seed=args.split_seed, per_group=per_group,
                        derivative_source=source, action_rate=args.action_rate, threads=args.threads,
                        torch_version=torch.__version__, stdm_drake_version=__version__)
        bar = tqdm(total=args.epochs, desc=f"train {name} seed {seed}", unit="epoch", disable=args.quiet,
                   dynamic_ncols=True)

        def on_epoch(row, bar=bar):
            bar.update(row["epoch"] - bar.n)
            bar.set_postfix(train=f"{row['train_loss']:.3g}", val_mse=f"{row['val_mse']:.3g}")

        try:
            result, selection = fit_model(model_config, training_config, train_data, val_data,
                                          alpha="auto" if auto else "fixed", alphas=tuple(args.alpha_grid),
                                          checkpoint_path=checkpoint_path, checkpoint_every=args.checkpoint_every,
                                          metadata=metadata, resume=resume, on_epoch=on_epoch)
        finally:
            bar.close()
        write_text_atomic(folder / "curves.csv", history_csv(result.history))
        if selection is not None:
            write_text_atomic(folder / "alpha_selection.csv", alpha_selection_csv(selection))
            plot_alpha_selection(selection, folder / "alpha_selection.png", title=f"{name} seed {seed}")
            summary.setdefault("alpha_selection", {})[str(seed)] = selection.as_dict()
            print(f"seed {seed}: alpha chosen by validation: {selection.alpha:g} (validation state MSE "
                  + ", ".join(f"{a:g}: {v:.3g}" for a, v in zip(selection.alphas, selection.val_mse)) + ")")
        summary["seeds"][str(seed)] = dict(checkpoint=str(checkpoint_path), epochs=result.epochs_run,
                                           stopped_early=result.stopped_early, best_epochs=result.best_epochs,
                                           best_val_mse_standardized=result.best_scores)
        print(f"seed {seed}: {result.epochs_run} epochs, best validation MSE (standardized) "
              f"{np.mean(result.best_scores):.4g} at epoch(s) {result.best_epochs} -> {checkpoint_path}")
    write_text_atomic(output / "summary.json", json.dumps(summary, indent=2) + "\n")
    return 0

