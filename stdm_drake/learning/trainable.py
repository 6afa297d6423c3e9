"""The trainable-model interface: what the trainer, the loss, the regression data, the checkpoints and the
inference path see of a network, and the one registry of network kinds.

As in mbrl-lib's `mbrl.models.Model`, a network kind is one `TrainableModel` subclass, which owns its
loss and its validation score; the training loop (`trainer`), the data (`regression`), the files
(`checkpoint`) and the `DynamicsModel` wrapper (`learned_model.LearnedModel`) call only the methods below.
The paper's D/P/DE/PE networks are `models.EnsembleMLP` ("ensemble_mlp").

A new kind of network is three things: the class (subclass `TrainableModel`, with a frozen dataclass
config record), its registration (a line in `NETWORK_KINDS`, or `register_network` at run time, e.g. from
a plugin), and the settings' choice of it (`TrainSettings.network` takes any registered name).

Shapes: E members trained side by side (an ensemble, or an alpha grid's stack), B rows, inputs z = [x, a]
(B, in), outputs the next state (B, out) in raw units (rad, rad/s).
"""
from __future__ import annotations

import abc
import copy
import dataclasses
import importlib
import types

import numpy as np
import torch
from torch import nn

from stdm_drake.errors import InputError
from stdm_drake.learning.loss import member_point_loss

# network kind -> "module:Class" of its TrainableModel (imported when first used)
NETWORK_KINDS: dict[str, str] = {"ensemble_mlp": "stdm_drake.learning.models:EnsembleMLP"}
DEFAULT_NETWORK = "ensemble_mlp"


class TrainableModel(nn.Module, abc.ABC):
    """A network the toolbox can train, save, load and predict with.

    Class attributes: `kind` (its registered name) and `config_type` (a frozen dataclass with at least
    input_dim, output_dim, residual (the delta parameterization x̂ = x + f), ensemble_size (E) and
    probabilistic, and `from_dict`). Instance: `config`. `member_parameters`: the state-dict entries with a
    leading member axis (the trainer keeps each member's best weights separately); the rest is shared.
    Constructor: `__init__(config, generator=None)`, the initial weights drawn from the torch `generator`
    (same generator state, same weights).
    """
    kind: str = ""
    config_type: type = object
    member_parameters: tuple[str, ...] = ()

    def __init__(self, config):
        super().__init__()
        self.config = config
        # (out,) per-output factor on the standardized derivative residual, set by the trainer for the relative
        # alpha (`settings.ALPHA_SCALES`); None: 1 (paper eq. 9's raw weighting). Not saved: a training setting.
        self.derivative_scale: torch.Tensor | None = None

    @classmethod
    @abc.abstractmethod
    def problem_config(cls, *, input_dim: int, output_dim: int, residual: bool, ensemble_size: int,
                       probabilistic: bool, start_at_residual: bool, options: dict):
        """The config record for a training problem: sizes, the delta parameterization, E members, probabilistic
        heads, start_at_residual (the first prediction is the residual part plus the mean delta: a grey box
        starts as its plant model) and the settings' network options (activation, hidden_width,
        hidden_layers: a kind takes those it has)."""

    @abc.abstractmethod
    def fit_normalizers(self, data) -> None:
        """Fix the model's data statistics from the training `regression.RegressionData` (raw units)."""

    @abc.abstractmethod
    def standardize(self, data):
        """`regression.StandardizedData`: the data in the units `loss` and `eval_score` take."""

    @abc.abstractmethod
    def loss(self, training, inputs, targets, input_rates=None, target_rates=None):
        """The training objective's terms per member (`loss.LossTerms`) on a standardized minibatch:
        inputs (E, B, in) or (B, in); targets likewise; the rates only with the derivative loss (paper eq. 9:
        training.alpha weighs the derivative term, `training` a `settings.TrainingConfig`)."""

    def derivative_term(self, training, tangents: torch.Tensor, target_rates: torch.Tensor) -> torch.Tensor:
        """The derivative term per member (E,): training.derivative_loss of the standardized time derivative
        (E, B, out) against its target (E, B, out), each output's residual times `derivative_scale` (the
        relative alpha). Kinds call this in `loss` and `eval_score` so that both alpha scales apply to them."""
        if self.derivative_scale is not None:
            scale = self.derivative_scale.to(tangents.dtype)
            tangents, target_rates = tangents * scale, target_rates * scale
        return member_point_loss(training.derivative_loss, tangents, target_rates, training.huber_delta)

    @abc.abstractmethod
    def eval_score(self, training, data) -> dict:
        """Validation on standardized data: loss, state and derivative terms (floats, mean over members) and
        member_mse (E,) float64, each member's state MSE in standardized units (the early-stopping score)."""

    @abc.abstractmethod
    def member_row_errors(self, data) -> torch.Tensor:
        """Each member's standardized state squared error per row of standardized data, mean over the outputs:
        (E, N) float64 (the paired comparison of alpha selection groups it by trajectory)."""

    @abc.abstractmethod
    def forward(self, inputs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Raw units: z (B, in) -> (mean (E, B, out) with the residual added, variance (E, B, out) or None)."""

    @classmethod
    def describe_config(cls, config) -> str:
        """A few words on the architecture of `config` (the MLP: "3x100 swish")."""
        return cls.kind

    @classmethod
    def weight_count(cls, config) -> int:
        """The number of trainable weights of a network of `config` (what memory and disk checks size)."""
        return sum(parameter.numel() for parameter in cls(config).parameters())

    def config_record(self) -> dict:
        """The config as the checkpoint stores it (plain values; `config_type.from_dict` reads it back)."""
        return dataclasses.asdict(self.config)

    def member(self, index: int) -> "TrainableModel":
        """A one-member copy of member `index` (the alpha grid keeps its chosen member and the naive one):
        the `member_parameters` entries sliced on their member axis, the rest (normalizers) shared."""
        if not 0 <= index < self.config.ensemble_size:
            raise InputError(f"member index {index} out of range 0..{self.config.ensemble_size - 1}")
        single = type(self)(single_member_config(self.config)).to(next(self.parameters()).dtype)
        single.load_state_dict({name: (value[index:index + 1] if name.split(".")[0] in self.member_parameters else value)
                                for name, value in self.state_dict().items()})
        return single

    def inference(self):
        """The float32 NumPy engine `predict` and `LearnedModel` run (see `TorchInference` for its methods);
        kinds with a faster one override this."""
        return TorchInference(self)


def register_network(kind: str, target: str | type) -> None:
    """Register a network kind: `target` a TrainableModel subclass or its "module:Class" name."""
    NETWORK_KINDS[kind] = target if isinstance(target, str) else f"{target.__module__}:{target.__qualname__}"


def network_class(kind: str) -> type:
    """The TrainableModel subclass of a registered kind (InputError naming the registered ones otherwise)."""
    if kind not in NETWORK_KINDS:
        raise InputError(f"unknown network kind {kind!r}; registered: {', '.join(sorted(NETWORK_KINDS))}")
    module, _, name = NETWORK_KINDS[kind].partition(":")
    target = importlib.import_module(module)
    for part in name.split("."):
        target = getattr(target, part)
    return target


def kind_of_config(config) -> str:
    """The registered kind whose config_type `config` is."""
    for kind in NETWORK_KINDS:
        if isinstance(config, network_class(kind).config_type):
            return kind
    raise InputError(f"no registered network kind takes a {type(config).__name__}")


def build_network(config, generator: torch.Generator | None = None) -> TrainableModel:
    """A fresh network of `config`'s kind (its weights drawn from `generator`)."""
    return network_class(kind_of_config(config))(config, generator=generator)


def single_member_config(config):
    """The same config with one member (an alpha grid's members start from one network's weights)."""
    return dataclasses.replace(config, ensemble_size=1)


def input_rows(states: np.ndarray, actions: np.ndarray, state_dim: int, action_dim: int) -> np.ndarray:
    """Rows [x, a, 1] for T steps: states (N, S) at step 0, actions (T, N, A) -> (T+1, N, S+A+1) float32.
    Steps 1..T hold zeros in place of states until a rollout writes its predictions there."""
    steps, count = actions.shape[:2]
    rows = np.zeros((steps + 1, count, state_dim + action_dim + 1), dtype=np.float32)
    rows[0, :, :state_dim] = states
    rows[:steps, :, state_dim:-1] = actions
    rows[..., -1] = 1.0
    return rows


class TorchInference:
    """The inference engine of any `TrainableModel`, from its `forward` (float64 torch) and, for the
    Jacobian, forward-mode automatic differentiation (`torch.func.jacfwd`): what a new kind gets without
    writing a fast path (the ensemble MLP's is `predict.InferenceModel`).

    Engine methods (what `predict` and `LearnedModel` call): input_rows, workspace, hidden_features (here:
    every member's raw outputs without the residual, (E, N, W) with W = out, or 2 out for the mean and the
    variance), ensemble_mean, ensemble_mean_flat, member_outputs, mean_and_jacobian. A snapshot: build a
    new one after the weights change.
    """

    def __init__(self, network: TrainableModel):
        config = network.config
        self.network = copy.deepcopy(network).double().eval()
        self.config, self.ensemble_size = config, config.ensemble_size
        self.state_dim, self.action_dim = config.output_dim, config.input_dim - config.output_dim
        self.residual, self.probabilistic = config.residual, config.probabilistic
        self.width = config.output_dim * (2 if config.probabilistic else 1)

    def input_rows(self, states: np.ndarray, actions: np.ndarray) -> np.ndarray:
        return input_rows(states, actions, self.state_dim, self.action_dim)

    def workspace(self, count: int):
        """The buffer a rollout writes its step means into: `.mean` (count, S) float32."""
        return types.SimpleNamespace(mean=np.empty((count, self.state_dim), dtype=np.float32))

    def _without_residual(self, inputs: torch.Tensor):
        mean, variance = self.network(inputs)
        if self.residual:
            mean = mean - inputs[..., :self.state_dim]
        return mean, variance

    @torch.no_grad()
    def hidden_features(self, inputs: np.ndarray, workspace=None, out: np.ndarray | None = None) -> np.ndarray:
        mean, variance = self._without_residual(torch.from_numpy(np.asarray(inputs[..., :-1], dtype=np.float64)))
        features = mean if variance is None else torch.cat([mean, variance], dim=-1)
        features = features.numpy().astype(np.float32)
        if out is None:
            return features
        out[...] = features
        return out

    def ensemble_mean(self, features: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        mean = features[..., :self.state_dim].mean(axis=0)
        if out is None:
            return mean
        out[...] = mean
        return out

    def ensemble_mean_flat(self, flat: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        return self.ensemble_mean(flat.reshape(len(flat), self.ensemble_size, self.width).transpose(1, 0, 2), out)

    def member_outputs(self, features: np.ndarray):
        mean = features[..., :self.state_dim]
        return mean, (features[..., self.state_dim:] if self.probabilistic else None)

    def mean_and_jacobian(self, inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ensemble-mean output (N, S) without the residual, and d next state / d [x, a] (N, S, S+A) with it."""
        z = torch.from_numpy(np.asarray(inputs[..., :-1], dtype=np.float64))

        def mean_of(row):
            return self.network(row[None])[0].mean(dim=0)[0]    # next state (S,) with the residual

        with torch.no_grad():
            jacobian = torch.func.vmap(torch.func.jacfwd(mean_of))(z)
            mean = self._without_residual(z)[0].mean(dim=0)
        return mean.numpy().astype(np.float32), jacobian.numpy().astype(np.float32)
