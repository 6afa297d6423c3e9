"""Training settings: `TrainingConfig` (how one model is fitted), the paper's alpha, and the
`stdm-drake train` settings file (`TrainSettings`, typed YAML; command-line flags override it)."""

import argparse
import dataclasses
import math
import typing

import numpy as np
import torch

from stdm_drake.data.dataset import ACTION_RATE_SCHEMES, DERIVATIVE_SOURCES, check_split_options
from stdm_drake import files
from stdm_drake.config import decimal_number
from stdm_drake.errors import InputError
from stdm_drake.learning.activations import ACTIVATION_NAMES
from stdm_drake.learning.loss import LOSS_KINDS
from stdm_drake.learning.trainable import NETWORK_KINDS
from stdm_drake.learning.models import DEFAULT_ENSEMBLE_SIZE, GREY_BOX_TYPES, MODEL_TYPES, parse_model_type
from stdm_drake.learning.structure import INPUT_SETS, PREDICTS, ModelStructure

def network_weights(ensemble_size: int, hidden_layers: int, hidden_width: int) -> int:
    """About how many weights a network of these sizes holds (its hidden layers' matrices dominate)."""
    return ensemble_size * hidden_layers * hidden_width ** 2


# settings beyond which a run does not fit in memory or does not end (checked before any work)
UPPER_BOUNDS = dict(hidden_width=8192, hidden_layers=64, ensemble_size=256, epochs=1_000_000, batch_size=1_000_000,
                    threads=256)   # (torch's thread pool crashed creating a million threads)
MAX_WEIGHTS = 2e8
MAX_SEEDS = 1000
# epochs over all seeds of one run (epochs x seeds): each bound alone let 1,000 seeds of a million epochs start (a run
# of years); a million epochs in all is days of the default model on this kind of machine
MAX_TOTAL_EPOCHS = 1_000_000
MAX_LR = 1.0        # Adam's step is about lr per weight
MIN_LR = 1e-10      # ... so below it no float32 weight of 1e-3 or more changes (1e-320: no training at all)
MAX_ALPHA = 1e6     # beyond it the next-state term is below float32's resolution of the summed loss
MAX_ALPHA_GRID = 100
LR_SCHEDULES = ("constant", "cosine")
DEFAULT_ALPHA = 1e-3   # the paper's derivative-loss weight (found by search over 1e-1 ... 1e-4)
# alpha values tried by `select_alpha` (`reproduce`'s alpha selection): naive (0) and a log grid
DEFAULT_ALPHA_GRID = (0.0, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0)
# `train`'s alphas for DD with alpha "auto": naive (0), so the chosen model is at worst naive training on validation,
# and every raw alpha the settling experiment's validation chose in a cell whose naive model learned (docs/settling.md)
TRAIN_ALPHA_GRID = (0.0, 1e-6, 1e-4, 1e-3, 1e-2, 1e-1)
# How alpha weighs the derivative term per output (`TrainingConfig.alpha_scale`): "raw", the paper's eq. 9 (the
# derivative residual in the state's units, so its weight per output depends on the ratio of rate to one-step
# change: 1/Δt and each joint's bandwidth), or "relative", each output's derivative residual divided by its own
# target's spread, so that alpha = 1 weighs the standardized derivative and state terms of every output alike.
ALPHA_SCALES = ("raw", "relative")
DEFAULT_ALPHA_SCALE = "raw"   # `train`'s (docs/settling.md: the default follows the settling experiment)
# `train`'s model type: naive D. The settling experiment (docs/settling.md) found derivative learning with alpha by
# validation helping in no cell and hurting in some, so by its pre-registered rule the default trains without it; DD
# (--model DD) chooses alpha from TRAIN_ALPHA_GRID, 0 included.
DEFAULT_MODEL_TYPE = "D"
# `train`'s alphas for the relative scale: naive, and from a hundredth of the state term to ten times it
RELATIVE_ALPHA_GRID = (0.0, 1e-2, 1e-1, 1.0, 10.0)


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
    alpha_scale: "raw" (paper eq. 9) or "relative" (each output's derivative residual over its target's spread);
    see ALPHA_SCALES and `trainer`.
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
    alpha_scale: str = "raw"

    def __post_init__(self):
        if self.alpha_scale not in ALPHA_SCALES:
            raise InputError(f"training config: alpha_scale must be one of {ALPHA_SCALES}, got {self.alpha_scale!r}")
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


def parse_alpha(text: str):
    """The flag --alpha's value: a number >= 0 or the word 'auto'."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        value = decimal_number(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0 or 'auto', got {text!r}") from None
    if not (np.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected a number >= 0 or 'auto', got {text!r}")
    return value


def setting(default=dataclasses.MISSING, help: str = "", *, choices: tuple | None = None, parse=None, factory=None):
    """A `TrainSettings` field and its command-line flag (`commands.arguments.add_settings_flags`): help, the flag's
    text ("{default}" in it: the default's value; otherwise "(default ...)" is added, unless the default is None or
    empty, whose meaning the text states); choices, the values accepted (by the flag and by `validate`); parse, the
    flag's conversion of its text (default: the field's type)."""
    metadata = dict(help=help, choices=choices, parse=parse)
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


@dataclasses.dataclass
class TrainSettings:
    """Everything `stdm-drake train` takes besides the dataset and the output folder, as a typed YAML file
    (`--config FILE`; keys left out keep these defaults; a command-line flag overrides its key). Each field is a
    flag of the same name with "-" for "_", whose help text is the field's `setting` (the one place a default is
    stated)."""
    model: str = setting(DEFAULT_MODEL_TYPE, "model type: D/P/DE/PE naive, DD/PD/DED/PED with the derivative loss "
                         "(alpha and derivative targets chosen by validation, naive among them); default {default}: "
                         "derivative learning helped in no cell of the settling experiment (docs/settling.md); G/GD "
                         "the grey box: a D/DD whose delta adds to the plant model's next state (inputs plant_step; "
                         "the plant: the robot's description, or --physics)",
                         choices=tuple(MODEL_TYPES) + tuple(GREY_BOX_TYPES), parse=str.upper)
    derivative: typing.Optional[str] = setting(None, "override the derivative loss the model type implies",
                                               choices=("on", "off"))
    alpha: typing.Union[float, str] = setting(
        "auto", "derivative loss weight as in the paper's eq. 9 (e.g. 1e-3, the paper's number), or 'auto': "
        "chosen by validation state MSE from --alpha-grid, 0 (naive training) included, so the model is "
        "at worst naive on validation", parse=parse_alpha)
    alpha_grid: typing.List[float] = setting(
        help="alphas tried by --alpha auto (unset: 0 and, for the raw scale, "
             f"{', '.join(f'{a:g}' for a in TRAIN_ALPHA_GRID[1:])} (docs/settling.md); for the relative scale "
             f"{RELATIVE_ALPHA_GRID[1]:g} ... {RELATIVE_ALPHA_GRID[-1]:g})", factory=list)
    alpha_scale: str = setting(DEFAULT_ALPHA_SCALE, "raw: alpha as in the paper's eq. 9; relative: each output's "
                               "derivative residual over its own target's spread, so alpha 1 weighs the derivative "
                               "and state terms of every joint alike (default {default}: docs/settling.md)",
                               choices=ALPHA_SCALES)
    network: str = setting("ensemble_mlp", "network kind (default {default}: the paper's MLPs; a registered kind, "
                           "stdm_drake.learning.trainable)", choices=NETWORK_KINDS)
    activation: str = setting("swish", "hidden activation; tanh or relu for a model Drake's MultilayerPerceptron can "
                              "hold (`export --target drake`); `export` to ONNX takes every one",
                              choices=ACTIVATION_NAMES)
    hidden_width: int = setting(100, "units per hidden layer")
    hidden_layers: int = setting(3, "hidden layers")
    ensemble_size: int = setting(DEFAULT_ENSEMBLE_SIZE, "members of DE/PE-type models")
    direct: bool = setting(False, "predict the next state (or velocity) directly instead of its delta from the "
                           "current one")
    predicts: typing.Optional[str] = setting(
        None, "velocity: the network predicts v_{t+1} and q_{t+1} follows by the trapezoid rule (unset: velocity, "
        "except for the grey box G/GD); state: it predicts x_{t+1} (the paper's; the grey box's, whose delta then "
        "adds to the plant's whole next state)", choices=PREDICTS)
    inputs: str = setting("nominal_acceleration", "nominal_acceleration: [q, v, tau] and the acceleration the "
                          "robot's nominal model (--robot) gives; period_acceleration: that model's mean "
                          "acceleration over the sample period instead (for joints damped faster than the period); "
                          "raw: [q, v, tau] (the paper's); plant_step: the grey box (the network's delta adds to the "
                          "plant model's next state; what --model G/GD use)", choices=INPUT_SETS)
    state_loss: str = setting("mse", "the next-state term's loss", choices=LOSS_KINDS)
    derivative_loss: str = setting("mse", "the derivative term's loss", choices=LOSS_KINDS)
    seeds: typing.List[int] = setting(help="one model per seed", factory=lambda: [0])
    train: typing.Optional[int] = setting(None, "training trajectories (per group with --per-group on; unset: 60 %%)")
    val: typing.Optional[int] = setting(None, "validation trajectories (per group with --per-group on; unset: 20 %%)")
    test: typing.Optional[int] = setting(None, "test trajectories (unset: all the rest)")
    per_group: typing.Optional[str] = setting(None, "split per initial-pose group (unset: on for tracking data, off "
                                              "otherwise)", choices=("on", "off"))
    split_seed: int = setting(0, "seed of the trajectory split")
    derivative_source: typing.Optional[str] = setting(
        None, "derivative targets (unset: with --alpha auto chosen by validation from the plan, where the data have "
        "one and its accelerations are within 0.5 (relative RMS) of the recorded ones, and the recorded motion: the "
        "simulation's truth, or a log's smoothed angles; with a fixed alpha the first of these; measured: a log's "
        "velocities and their smoothed derivative)", choices=DERIVATIVE_SOURCES)
    action_rate: str = setting("forward_difference", "how Δa/Δt is formed", choices=ACTION_RATE_SCHEMES)
    epochs: int = setting(500, "maximum epochs")
    patience: int = setting(50, "early-stopping patience in epochs")
    batch_size: int = setting(64, "transitions per minibatch")
    lr: float = setting(1e-3, "Adam learning rate")
    lr_schedule: str = setting("constant", "constant, or cosine decay to --min-lr over the --epochs budget",
                               choices=LR_SCHEDULES)
    min_lr: float = setting(0.0, "final learning rate of the cosine schedule")
    weight_decay: float = setting(0.0, "decoupled weight decay (AdamW; default {default}: plain Adam)")
    checkpoint_every: int = setting(10, "epochs between checkpoint writes")
    threads: int = setting(1, "torch CPU threads (default {default}: bitwise-reproducible on any machine)")

    def validate(self, given: typing.Collection[str] | None = None) -> None:
        """InputError (one line, naming the key and its flag) on a value no flag would accept, or on a setting
        the run would ignore (an alpha grid without alpha auto, ...). given: the keys the user set (flags
        and the settings file's keys): such a setting is refused whatever its value, the default's too;
        None: a value other than the default counts as set."""
        key = lambda name: f"{name} (--{name.replace('_', '-')})"  # noqa: E731
        defaults = TrainSettings()
        def is_set(name: str) -> bool:
            value, default = getattr(self, name), getattr(defaults, name)
            if given is not None:
                return name in given
            return list(value) != list(default) if isinstance(default, list) else value != default
        self.model = str(self.model).upper()
        if isinstance(self.alpha, str) and self.alpha.strip().lower() != "auto":
            try:
                self.alpha = float(self.alpha)
            except ValueError:
                raise InputError(f"{key('alpha')} must be a number >= 0 or 'auto', got {self.alpha!r}") from None
        elif isinstance(self.alpha, str):
            self.alpha = "auto"
        if self.model in GREY_BOX_TYPES:   # G / GD: a D / DD on the plant step's whole next state
            if self.inputs != "plant_step" and is_set("inputs"):    # (the grey box's own, or left out)
                raise InputError(f"{key('model')} {self.model} is the grey box: its inputs are plant_step, not "
                                 f"{self.inputs}")
            self.inputs = "plant_step"
        # each field's choices as they are now (network kinds registered after import count), None where unset is
        choices = {field.name: (*field.metadata["choices"], *((None,) if field.default is None else ()))
                   for field in dataclasses.fields(self) if field.metadata.get("choices")}
        for name, allowed in choices.items():
            if getattr(self, name) not in allowed:
                raise InputError(f"{key(name)} must be one of {[a for a in allowed if a is not None]}, "
                                 f"got {getattr(self, name)!r}")
        if self.inputs == "plant_step":
            kind = parse_model_type(self.model)
            if kind.probabilistic or kind.ensemble or self.direct:
                raise InputError("a grey box (inputs plant_step) is a single deterministic network whose delta adds "
                                 f"to the plant step: not model {self.model}" + (" with --direct" if self.direct else ""))
        if self.alpha != "auto" and not (math.isfinite(self.alpha) and self.alpha >= 0):
            raise InputError(f"{key('alpha')} must be a number >= 0 or 'auto', got {self.alpha!r}")
        if (is_set("alpha_grid") and not self.alpha_grid) or not all(math.isfinite(a) and a >= 0
                                                                      for a in self.alpha_grid):
            raise InputError(f"{key('alpha_grid')} needs numbers >= 0, got {self.alpha_grid}")
        grid = self.grid()
        if len(grid) > MAX_ALPHA_GRID:   # (each alpha is a network of the grid's stack)
            raise InputError(f"{key('alpha_grid')} lists {len(grid)} alphas, at most {MAX_ALPHA_GRID}")
        if max([*grid, 0.0 if self.alpha == "auto" else self.alpha]) > MAX_ALPHA:
            raise InputError(f"{key('alpha')} and {key('alpha_grid')} must be at most {MAX_ALPHA:g}: the next-state "
                             "loss would vanish beside the derivative loss (float32)")
        if self.alpha == "auto" and self.uses_derivative() and max(grid) == 0:
            raise InputError(f"{key('alpha_grid')} holds no alpha above 0, so the derivative loss would never be "
                             f"used; train --model {self.model_name()[:-1] or 'D'} for naive training")
        if self.alpha != "auto" and is_set("alpha_grid"):
            raise InputError(f"{key('alpha_grid')} is what --alpha auto chooses from; with alpha {self.alpha:g} it "
                             "would be ignored")
        if not self.seeds:
            raise InputError(f"{key('seeds')} must list at least one seed")
        if len(self.seeds) > MAX_SEEDS:
            raise InputError(f"{key('seeds')} lists {len(self.seeds)} seeds, at most {MAX_SEEDS}")
        if self.epochs * len(self.seeds) > MAX_TOTAL_EPOCHS:
            raise InputError(f"{key('epochs')} {self.epochs:,} for each of {len(self.seeds)} {key('seeds')} are "
                             f"{self.epochs * len(self.seeds):,} epochs, more than the {MAX_TOTAL_EPOCHS:,} one run may "
                             "train: fewer epochs (early stopping ends most runs far sooner) or fewer seeds per run")
        if any(not 0 <= seed < 2 ** 64 for seed in self.seeds) or len(set(self.seeds)) != len(self.seeds):
            # (torch's generator takes an unsigned 64-bit seed: 2^64 failed after the first seeds had trained)
            raise InputError(f"{key('seeds')} must be distinct integers in 0..2^64-1, got {list(self.seeds)}")
        check_split_options(self.train, self.val, self.test, self.split_seed, key)
        for name in ("hidden_width", "hidden_layers", "ensemble_size", "epochs", "patience", "batch_size",
                     "checkpoint_every", "threads"):
            if int(getattr(self, name)) < 1:
                raise InputError(f"{key(name)} must be >= 1, got {getattr(self, name)}")
            if name in UPPER_BOUNDS and getattr(self, name) > UPPER_BOUNDS[name]:
                raise InputError(f"{key(name)} must be at most {UPPER_BOUNDS[name]}, got {getattr(self, name)}")
        weights = network_weights(self.ensemble_size, self.hidden_layers, self.hidden_width)
        if weights > MAX_WEIGHTS:
            raise InputError(f"the network would hold about {weights:.3g} weights ({key('ensemble_size')} x "
                             f"{key('hidden_layers')} x {key('hidden_width')}²), more than {MAX_WEIGHTS:.0e} "
                             "(a few GB with the optimizer's state)")
        for name in ("lr", "min_lr", "weight_decay"):
            value = getattr(self, name)
            if not (math.isfinite(value) and (value > 0 if name == "lr" else value >= 0)):
                bound = "> 0" if name == "lr" else ">= 0"
                raise InputError(f"{key(name)} must be a finite number {bound}, got {value}")
        if self.lr < MIN_LR:
            raise InputError(f"{key('lr')} must be at least {MIN_LR:g} (Adam moves each weight by about lr per step, "
                             f"so no float32 weight would change), got {self.lr:g}")
        if self.lr > MAX_LR:
            raise InputError(f"{key('lr')} must be at most {MAX_LR:g} (Adam's steps would be as large as the "
                             f"weights), got {self.lr:g}")
        if self.lr * self.weight_decay >= 1:
            raise InputError(f"{key('lr')} x {key('weight_decay')} must be below 1 (each step would scale the "
                             f"weights by 1 - lr x weight_decay <= 0), got {self.lr:g} x {self.weight_decay:g}")
        if is_set("min_lr") and self.lr_schedule != "cosine":
            raise InputError(f"{key('min_lr')} is where --lr-schedule cosine ends; with the {self.lr_schedule} "
                             "schedule it would be ignored")
        if is_set("ensemble_size") and not parse_model_type(self.model).ensemble:
            raise InputError(f"{key('ensemble_size')} is the member count of DE/PE-type models; model "
                             f"{self.model} is one network, so it would be ignored")
        if not self.uses_derivative():
            for name in ("alpha", "alpha_grid", "alpha_scale", "derivative_loss", "derivative_source", "action_rate"):
                if is_set(name) and getattr(self, name) != "auto":   # ("auto" without it: check_alpha's line)
                    why = ("--derivative off turns it off" if self.derivative == "off" else
                           f"model {self.model} trains without it (a DD/PD/DED/PED type, or --derivative on, has it)")
                    raise InputError(f"{key(name)} shapes the derivative loss, and {why}; it would be ignored")

    def check_memory(self, transitions: int, ensemble_size: int, available: float | None = None) -> float:
        """InputError unless one training run on `transitions` (input, target) pairs of a network of
        `ensemble_size` members fits in memory: float32 weights with their gradients and Adam's two moments (4
        copies), and per batch each layer's activations for the value, its tangent (the derivative loss) and
        their gradients (6 copies of ensemble x batch x width). available: bytes (default: the system's
        available memory). Returns the estimate (bytes)."""
        batch = min(self.batch_size, max(int(transitions), 1))
        weights = network_weights(ensemble_size, self.hidden_layers, self.hidden_width)
        activations = ensemble_size * batch * self.hidden_width * self.hidden_layers
        needed = 4.0 * (4 * weights + 6 * activations)
        available = files.available_memory() if available is None else available
        if available is not None and needed > available:
            raise InputError(f"training would need about {files.size_text(needed)} of memory ({ensemble_size} "
                             f"member(s), hidden_layers {self.hidden_layers}, hidden_width "
                             f"{self.hidden_width}, batches of {batch}), {files.size_text(available)} is available; "
                             "lower batch_size, hidden_width or hidden_layers")
        return needed

    def check_alpha(self, given: typing.Collection[str] | None = None) -> None:
        """InputError unless alpha suits the model type: > 0 or "auto" with the derivative loss, no "auto"
        without it when the user set it (given: the keys set, as in `validate`; None: "auto" is the default, so
        it counts as not set);
        checked on the merged settings: a file's alone may be completed by flags."""
        if self.uses_derivative() and self.alpha != "auto" and not self.alpha > 0:
            raise InputError(f"derivative learning needs --alpha > 0 or --alpha auto, got {self.alpha}")
        if self.alpha == "auto" and not self.uses_derivative() and given is not None and "alpha" in given:
            raise InputError(f"--alpha auto chooses the derivative-loss weight; model type {self.model} trains "
                             "without it (use DD, PD, DED or PED, or --derivative on)")

    def uses_derivative(self) -> bool:
        """Whether the derivative loss is on: what the model type implies, unless `derivative` says."""
        return parse_model_type(self.model).derivative if self.derivative is None else self.derivative == "on"

    def model_name(self) -> str:
        """The model type as trained ("D", "PED", ...): the type's heads and ensemble, "D" suffixed when the
        derivative loss is on (so --model D --derivative on trains a "DD")."""
        kind = parse_model_type(self.model)
        if self.inputs == "plant_step" and not (kind.probabilistic or kind.ensemble):
            return "G" + ("D" if self.uses_derivative() else "")
        return ("P" if kind.probabilistic else "D") + ("E" if kind.ensemble else "") + \
            ("D" if self.uses_derivative() else "")

    def structure(self, physics: dict | None = None):
        """The `ModelStructure` of predicts and inputs (and a grey box's `physics` record, see there)."""
        return ModelStructure(predicts=self.predicted(), inputs=self.inputs, physics=physics,
                              plant_integrator="rk4" if self.inputs == "plant_step" else None)

    def predicted(self) -> str:
        """What the network predicts: `predicts`, or None's default: the next state for a grey box (the plant
        step's own q̂ kept; docs/identification.md, run 2), the next velocity otherwise."""
        if self.predicts is not None:
            return self.predicts
        return "state" if self.inputs == "plant_step" else "velocity"

    def alpha_choices(self) -> tuple | None:
        """The alphas that alpha "auto" chooses from by validation (`alpha_selection.fit_model`'s alpha_grid);
        None for a fixed alpha or a model trained without the derivative loss."""
        return self.grid() if self.alpha == "auto" and self.uses_derivative() else None

    def grid(self) -> tuple:
        """alpha_grid, or the alpha scale's default grid when it is empty."""
        if self.alpha_grid:
            return tuple(float(a) for a in self.alpha_grid)
        return RELATIVE_ALPHA_GRID if self.alpha_scale == "relative" else TRAIN_ALPHA_GRID

    def training_config(self, seed: int) -> TrainingConfig:
        """How the model of `seed` is fitted (alpha 0 without the derivative loss, and while "auto" picks it)."""
        alpha = (0.0 if self.alpha == "auto" else float(self.alpha)) if self.uses_derivative() else 0.0
        return TrainingConfig(alpha=alpha, state_loss=self.state_loss, derivative_loss=self.derivative_loss,
                              learning_rate=self.lr, batch_size=self.batch_size, max_epochs=self.epochs,
                              patience=self.patience, seed=seed, lr_schedule=self.lr_schedule,
                              min_learning_rate=self.min_lr, weight_decay=self.weight_decay,
                              alpha_scale=self.alpha_scale)

