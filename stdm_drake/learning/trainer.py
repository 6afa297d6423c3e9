"""Training STDMs with and without derivative learning (paper eq. 9): one model or a stack of members (alpha by
validation and `fit_model`, which `train` runs, are `learning.alpha_selection`'s).

Loss = L_state + alpha * L_derivative with alpha meaning what it means in the paper's eq. 9, where
both MSEs are taken in raw units: the state error x̂_{t+1} - x_{t+1} (output units) and the
derivative error d x̂_{t+1}/dt - ẋ_{t+1} (output units per second). Per output j both residuals
are divided by the same scale, σ_y,j, the spread of the training regression targets (of Δx for the
delta parameterization), so that no output dominates while the ratio of the two terms stays the
raw-unit ratio of eq. 9:
    L = Σ_j (1/σ_j²) [ mean (x̂_j - x_j)² + alpha mean (dx̂_j/dt - ẋ_j)² ] / S,
which is exactly eq. 9 divided by σ² when every σ_j equals σ. In network units
    e_state = f_n(z_n) - y_n,    e_derivative = J_n(z_n) ż_n - (ẏ - r(ż))/σ_y,
with J_n ż_n one Jacobian-vector product (see models.py). With the relative alpha
(`TrainingConfig.alpha_scale="relative"`) the derivative residual of output j is instead divided by τ_j, the
spread of its own derivative targets (of ẏ_j - r(ż)_j), so alpha = 1 weighs the two standardized terms of every
output alike whatever the sample period and the joint's bandwidth:
    L = Σ_j [ mean ((x̂_j - x_j)/σ_j)² + alpha mean ((dx̂_j/dt - ẋ_j)/τ_j)² ] / S
(`relative_derivative_scale`, applied by `TrainableModel.derivative_term`). MAE and Huber replace the squares where
asked; probabilistic members use the PETS Gaussian NLL plus the log-variance bound penalty for the
state term.

Each ensemble member has its own loss (mean over samples and outputs); the total is their sum, so
members never interact and a member trains exactly as it would alone. Ensembles train each member
on its own bootstrap resample (PETS). An alpha grid (`TrainingConfig.alpha_grid`) is a stack whose
members start from the same initial weights, see the same minibatches and differ only in alpha:
`alpha_selection.select_alpha` trains one and keeps the member with the lowest validation state MSE. Validation
keeps each member's best weights (early stopping when no member improved for `patience` epochs).
"""
from __future__ import annotations

import dataclasses
import hashlib
import time
from typing import Callable

import numpy as np
import torch

from stdm_drake.errors import InputError
from stdm_drake.learning.checkpoint import HISTORY_COLUMNS, CheckpointMetadata, load_checkpoint, save_checkpoint
from stdm_drake.learning.regression import RegressionData, StandardizedData
from stdm_drake.learning.settings import TrainingConfig
from stdm_drake.learning.trainable import TrainableModel, build_network, single_member_config


def training_step(model: TrainableModel, optimizer: torch.optim.Optimizer, config: TrainingConfig,
                  data: StandardizedData, indices: torch.Tensor) -> tuple[float, float, float]:
    """One optimizer step on the minibatch data[indices] (indices (E, B): per-member rows).
    Returns the loss terms averaged over members."""
    rates = config.derivative
    terms = model.loss(config, data.inputs[indices], data.targets[indices],
                       data.input_rates[indices] if rates else None, data.target_rates[indices] if rates else None)
    optimizer.zero_grad(set_to_none=True)
    terms.objective.backward()
    optimizer.step()
    return terms.means()


@dataclasses.dataclass
class TrainResult:
    """A trained model (each member at its best validation epoch) and its learning curves."""
    model: TrainableModel
    history: dict
    best_epochs: list
    best_scores: list
    epochs_run: int
    stopped_early: bool
    member_val_mse: list = dataclasses.field(default_factory=list)  # per validation row: (E,) standardized MSE
    naive: TrainableModel | None = None   # an alpha grid's alpha = 0 member (naive training), beside the chosen one


def _seeds(seed: int) -> tuple[int, int]:
    """Independent integer seeds for weight initialization and for bootstrap/shuffling."""
    init_seed, data_seed = np.random.SeedSequence(seed).generate_state(2, dtype=np.uint64)
    return int(init_seed % (2 ** 63)), int(data_seed % (2 ** 63))


def build_model(model_config, seed: int) -> TrainableModel:
    """A freshly initialized network of `model_config`'s kind (same seed -> same weights)."""
    torch.manual_seed(seed)
    return build_network(model_config, generator=torch.Generator().manual_seed(_seeds(seed)[0]))


class Trainer:
    """Fits one model (a `TrainableModel` of `model_config`'s kind) with Adam on minibatches, keeping each member's
    best weights by validation, in small steps (the shape of mbrl-lib's `ModelTrainer`):

    - `train_epoch(tensors, sums)`: one pass over each member's bootstrap rows in a fresh order, the
      loss terms summed into `sums`;
    - the model's `eval_score` for the scores; `keep_best(member_mse)`: each improved
      member's weights kept;
    - `history_row(...)`: one learning-curve row; `write_checkpoint(finished)`: the best weights and
      everything resuming needs (`resume_state`), atomically; `resume(path)`: continue from that file
      exactly as if training had not stopped (same weights, same curves);
    - `fit(on_epoch)`: the loop (early stopping after `patience` epochs without a member improving)
      -> TrainResult with each member at its best epoch.

    Same seed, data and configs -> the same weights, bit for bit.
    """

    def __init__(self, model_config, training_config: TrainingConfig, train_data: RegressionData,
                 val_data: RegressionData, *, checkpoint_path=None, checkpoint_every: int = 10,
                 metadata: CheckpointMetadata | dict | None = None):
        train_data.check(model_config, need_rates=training_config.derivative, name="training")
        val_data.check(model_config, need_rates=False, name="validation")
        self.model_config, self.config = model_config, training_config
        self.checkpoint_path, self.checkpoint_every, self.metadata = checkpoint_path, checkpoint_every, metadata
        self.members = members = model_config.ensemble_size
        self.grid = training_config.alpha_grid is not None
        training_config.member_alphas(members)  # checks the grid size
        self.fingerprint = hashlib.sha256((train_data.fingerprint() + val_data.fingerprint()).encode()).hexdigest()
        self.model = model = build_model(model_config, training_config.seed)
        if self.grid:  # every member starts from the single model this seed gives
            single = build_model(single_member_config(model_config), training_config.seed)
            with torch.no_grad():
                for name, value in single.named_parameters():
                    model.get_parameter(name).copy_(value.expand_as(model.get_parameter(name)))
        model.fit_normalizers(train_data)
        # fused: one kernel for all parameters (elementwise, deterministic; about 1 ms less per step on a CPU)
        if training_config.weight_decay > 0:
            self.optimizer = torch.optim.AdamW(model.parameters(), lr=training_config.learning_rate,
                                               weight_decay=training_config.weight_decay, fused=True)
        else:
            self.optimizer = torch.optim.Adam(model.parameters(), lr=training_config.learning_rate, fused=True)
        self.generator = torch.Generator().manual_seed(_seeds(training_config.seed)[1])
        self.count = count = len(train_data)
        if members > 1 and training_config.bootstrap and not self.grid:
            self.bootstrap = torch.randint(0, count, (members, count), generator=self.generator)
        else:
            self.bootstrap = torch.arange(count).expand(members, count).clone()
        self.history = {column: [] for column in HISTORY_COLUMNS}
        self.best_weights = {name: value.detach().clone() for name, value in model.state_dict().items()}
        self.best_scores = torch.full((members,), float("inf"), dtype=torch.float64)
        self.best_epochs = torch.zeros(members, dtype=torch.int64)
        self.epoch, self.since_improvement, self.stopped_early, self.finished = 0, 0, False, False
        self.train_data, self.val_data = train_data, val_data

    def resume(self) -> None:
        """Continue from `checkpoint_path`: InputError unless it holds the training state of the same
        model and training configs on the same data."""
        path = self.checkpoint_path
        if path is None:
            raise InputError("resume=True needs the checkpoint_path to continue from")
        state = load_checkpoint(path)
        saved = state.resume
        if saved is None:
            raise InputError(f"{path}: checkpoint holds no training state to resume")
        if state.model.config_record() != self.model.config_record() or state.training_config != self.config:
            raise InputError(f"{path}: model or training options differ from the checkpoint's; "
                             "resume with the same options")
        if saved["data_fingerprint"] != self.fingerprint:
            raise InputError(f"{path}: training/validation data differ from the checkpoint's")
        self.model.load_state_dict(saved["weights"])
        self.optimizer.load_state_dict(saved["optimizer"])
        self.generator.set_state(saved["generator"])
        self.bootstrap, self.best_weights = saved["bootstrap"], saved["best_weights"]
        self.best_scores, self.best_epochs = saved["best_scores"], saved["best_epochs"]
        self.epoch, self.since_improvement = int(saved["epoch"]), int(saved["epochs_since_improvement"])
        self.stopped_early, self.finished = bool(saved["stopped_early"]), bool(saved["finished"])
        self.history = {column: list(state.history.get(column, [])) for column in HISTORY_COLUMNS}

    def resume_state(self, finished: bool) -> dict:
        """Everything `resume` needs to continue exactly: weights, optimizer, generator, bootstrap rows,
        the best weights and scores so far, the epoch and early-stopping counters."""
        return dict(epoch=self.epoch, weights={k: v.detach().clone() for k, v in self.model.state_dict().items()},
                    optimizer=self.optimizer.state_dict(), generator=self.generator.get_state(),
                    bootstrap=self.bootstrap, best_weights=self.best_weights, best_scores=self.best_scores,
                    best_epochs=self.best_epochs, epochs_since_improvement=self.since_improvement,
                    stopped_early=self.stopped_early, finished=finished, data_fingerprint=self.fingerprint)

    def write_checkpoint(self, finished: bool) -> None:
        """The best weights so far, the curves, the metadata and the resume state to `checkpoint_path`."""
        if self.checkpoint_path is None:
            return
        best_model = type(self.model)(self.model_config).to(next(self.model.parameters()).dtype)
        best_model.load_state_dict(self.best_weights)
        save_checkpoint(self.checkpoint_path, best_model, training_config=self.config, history=self.history,
                        metadata=self.metadata, resume_state=self.resume_state(finished))

    def train_epoch(self, tensors: StandardizedData, sums: np.ndarray) -> None:
        """One epoch of minibatch steps, each step's (total, state, derivative) loss terms added to
        sums[:3] and its count to sums[3]."""
        config, members, count = self.config, self.members, self.count
        self.model.train()
        if self.grid:  # one minibatch order shared by every member
            order = torch.argsort(torch.rand(1, count, generator=self.generator), dim=1).expand(members, count)
        else:
            order = torch.argsort(torch.rand(members, count, generator=self.generator), dim=1)
        epoch_rows = self.bootstrap.gather(1, order)
        steps_per_epoch = -(-count // config.batch_size)
        total_steps = steps_per_epoch * config.max_epochs
        for index, start in enumerate(range(0, count, config.batch_size)):
            if config.lr_schedule != "constant":
                rate = config.learning_rate_at(self.epoch * steps_per_epoch + index, total_steps)
                for group in self.optimizer.param_groups:
                    group["lr"] = rate
            sums[:3] += training_step(self.model, self.optimizer, config, tensors,
                                      epoch_rows[:, start:start + config.batch_size])
            sums[3] += 1
        self.epoch += 1

    def keep_best(self, member_mse: torch.Tensor) -> None:
        """Keep the weights of each member whose validation MSE (E,) improved; count epochs without one."""
        improved = member_mse < self.best_scores
        if bool(improved.any()):
            for name, value in self.model.state_dict().items():
                if name.split(".")[0] in self.model.member_parameters:
                    self.best_weights[name][improved] = value.detach()[improved]
                else:
                    self.best_weights[name] = value.detach().clone()
            self.best_scores = torch.where(improved, member_mse, self.best_scores)
            self.best_epochs = torch.where(improved, torch.tensor(self.epoch), self.best_epochs)
            self.since_improvement = 0
        else:
            self.since_improvement += self.config.validation_interval
        self.stopped_early = self.since_improvement >= self.config.patience

    def history_row(self, means: np.ndarray, scores: dict, seconds: float) -> dict:
        """One learning-curve row (HISTORY_COLUMNS), appended to the history."""
        row = dict(epoch=self.epoch, train_loss=means[0], train_state_loss=means[1], train_derivative_loss=means[2],
                   val_loss=scores["loss"], val_state_loss=scores["state"], val_derivative_loss=scores["derivative"],
                   val_mse=float(scores["member_mse"].mean()), seconds=seconds)
        for column in HISTORY_COLUMNS:
            self.history[column].append(row[column])
        return row

    def fit(self, on_epoch: Callable[[dict], None] | None = None) -> TrainResult:
        """Train until max_epochs or early stopping, validating every `validation_interval` epochs (and
        at the last), checkpointing every `checkpoint_every` epochs and at the end; on_epoch(row) with
        each new history row. Returns each member at its best validation epoch."""
        config = self.config
        train_tensors, val_tensors = self.model.standardize(self.train_data), self.model.standardize(self.val_data)
        self.model.derivative_scale = relative_derivative_scale(train_tensors) if (
            config.alpha_scale == "relative" and config.derivative) else None
        member_curves = []  # this call's validation rows only (not restored on resume)
        sums, started, last_written = np.zeros(4), time.perf_counter(), self.epoch
        while not self.finished and self.epoch < config.max_epochs and self.since_improvement < config.patience:
            self.train_epoch(train_tensors, sums)
            if not np.all(np.isfinite(sums[:3])):
                weights = f"learning rate {config.learning_rate:g}, weight decay {config.weight_decay:g}" + (
                    f", derivative-loss weight alpha {config.alpha:g}" if config.alpha else "")
                raise InputError(f"training diverged in epoch {self.epoch}: the training loss is {sums[0] / max(sums[3], 1)}"
                                 f" ({weights}); lower them")
            if self.epoch % config.validation_interval and self.epoch < config.max_epochs:
                continue
            self.model.eval()
            scores = self.model.eval_score(config, val_tensors)
            self.keep_best(scores["member_mse"])
            row = self.history_row(sums[:3] / max(sums[3], 1), scores, time.perf_counter() - started)
            member_curves.append(scores["member_mse"].tolist())
            sums, started = np.zeros(4), time.perf_counter()
            done = self.stopped_early or self.epoch >= config.max_epochs
            if self.checkpoint_path is not None and (done or self.epoch - last_written >= self.checkpoint_every):
                self.write_checkpoint(finished=done)
                last_written = self.epoch
            if on_epoch is not None:
                on_epoch(row)
            self.finished = done
        if self.checkpoint_path is not None and not self.history["epoch"]:
            self.write_checkpoint(finished=True)
        self.model.load_state_dict(self.best_weights)
        self.model.eval()
        return TrainResult(model=self.model, history=self.history, best_epochs=self.best_epochs.tolist(),
                           best_scores=self.best_scores.tolist(), epochs_run=self.epoch,
                           stopped_early=self.stopped_early, member_val_mse=member_curves)


def relative_derivative_scale(tensors: StandardizedData) -> torch.Tensor:
    """The relative alpha's factor per output (out,) float64: 1 / the spread of the standardized training derivative
    targets, i.e. σ_j / τ_j with σ_j the spread of output j's regression targets (the state term's scale) and τ_j
    that of its derivative targets (of ẏ_j - r(ż)_j for the delta parameterization), so that the derivative
    residual is measured in units of its own target's spread as the state residual is. A target without spread
    (below 1e-8 of the state scale) keeps the factor 1, as the normalizers keep constant columns unscaled."""
    spread = tensors.target_rates.double().std(dim=0, correction=0)
    return torch.where(spread > 1e-8, 1.0 / spread.clamp_min(1e-8), torch.ones_like(spread))


def train_model(model_config, training_config: TrainingConfig, train_data: RegressionData,
                val_data: RegressionData, *, checkpoint_path=None, checkpoint_every: int = 10,
                metadata: CheckpointMetadata | dict | None = None, resume: bool = False,
                on_epoch: Callable[[dict], None] | None = None) -> TrainResult:
    """Fit a model with a `Trainer`; keep per-member best-by-validation weights.

    checkpoint_path: written atomically every `checkpoint_every` epochs and at the end (weights =
    current best, plus everything needed to resume), only at validation epochs. resume=True
    continues from that file exactly as if training had not stopped (same weights, same curves).
    on_epoch(row) is called with each new history row.
    """
    trainer = Trainer(model_config, training_config, train_data, val_data, checkpoint_path=checkpoint_path,
                      checkpoint_every=checkpoint_every, metadata=metadata)
    if resume:
        trainer.resume()
    return trainer.fit(on_epoch)
