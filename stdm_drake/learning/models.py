"""Networks for state-transition dynamics models (STDMs): one ensemble MLP class for D, P, DE, PE.

The network is a generic regressor from inputs z (in_dim) to outputs (out_dim); the STDM is a thin
layer on top (in_dim = S + A with z = [x, a], out_dim = S, and the delta parameterization adds x:
x̂_{t+1} = x_t + f(z)). Every model is an ensemble of `ensemble_size` members whose weights are
stacked on a leading axis, so all members run in one batched matmul (ensemble_size=1 for D/P).

Inside, the network works on standardized data: z_n = (z - μ_z)/σ_z, and its output is the
standardized regression target y_n = (y - r(z) - μ_y)/σ_y, where r(z) = z[:out_dim] for the delta
(residual) parameterization and 0 otherwise. Probabilistic members also output a log-variance of
y_n, softly bounded between learnable limits (PETS, Chua et al. 2018, appendix A.1).

Derivative learning needs d x̂/dt = J(z) ż, one Jacobian-vector product of the raw map
z -> x̂ with the tangent ż = [ẋ_t, ȧ_t]. With the affine maps above it is exactly
    d x̂/dt = r(ż) + σ_y ⊙ J_n(z_n) (ż / σ_z),
so only the normalized network is differentiated, by a hand-written forward-mode pass that carries
(h, ḣ) through the layers (`normalized_outputs_with_tangent`), with a hand-written backward; each
activation's tangent pass (value, slope, curvature) is in `stdm_drake.learning.activations`.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from stdm_drake.errors import InputError
from stdm_drake.learning.activations import get_activation
from stdm_drake.learning.tangent import TangentPropagation
from stdm_drake.learning.loss import LossTerms, member_gaussian_nll, member_point_loss
from stdm_drake.learning.trainable import TrainableModel
from stdm_drake.learning.regression import StandardizedData
from stdm_drake.learning.predict import InferenceModel

# A delta model's output spread is at least this fraction of its targets' own spread: a grey box on an exact
# plant model has residual targets of rounding size (1e-10 rad/s), which standardized would be fitted as
# signal (and Adam's scale-free steps would move the outputs of all-zero ones by 1e-3 of a unit).
DELTA_SPREAD_FLOOR = 1e-4

# PETS soft bounds on the log-variance: initial limits and the weight of their penalty in the loss.
MIN_LOGVAR_INIT = -10.0
MAX_LOGVAR_INIT = 0.5
LOGVAR_BOUND_PENALTY = 0.01
# state-dict entries with a leading ensemble axis (everything else, the normalizers, is shared)
MEMBER_PARAMETERS = ("weights", "biases", "min_logvar", "max_logvar")

Tensor = torch.Tensor



@dataclasses.dataclass(frozen=True)
class ModelType:
    """The paper's model families: D, P, DE, PE, and the same trained with the derivative loss."""
    name: str
    ensemble: bool
    probabilistic: bool
    derivative: bool


MODEL_TYPES: dict[str, ModelType] = {
    name: ModelType(name, ensemble="E" in name, probabilistic=name.startswith("P"), derivative=derivative)
    for name, derivative in (("D", False), ("P", False), ("DE", False), ("PE", False),
                             ("DD", True), ("PD", True), ("DED", True), ("PED", True))
}
DEFAULT_ENSEMBLE_SIZE = 5
# The grey box (issue 23): a D (G) or DD (GD) whose delta adds to a plant model's next state
# (`structure.ModelStructure` with plant-step inputs); not one of the paper's types.
GREY_BOX_TYPES: dict[str, ModelType] = {"G": ModelType("G", False, False, False), "GD": ModelType("GD", False, False, True)}


def parse_model_type(name: str) -> ModelType:
    key = name.upper()
    kinds = {**MODEL_TYPES, **GREY_BOX_TYPES}
    if key not in kinds:
        raise InputError(f"unknown model type {name!r}; choose from {', '.join(kinds)}")
    return kinds[key]


@dataclasses.dataclass(frozen=True)
class ModelConfig:
    """Architecture of an ensemble MLP (everything needed to rebuild it from a checkpoint).

    input_dim: size of z; output_dim: size of the prediction; residual: predict
    z[:output_dim] + network (the STDM delta parameterization) instead of the network directly.
    standardize_inputs: scale inputs to zero mean and unit spread (False: the network sees raw z,
    e.g. the sine-sum's x in [-30π, 30π], whose Xavier-scale first layer then starts with
    frequencies of order 1 instead of 1/σ_x).
    zero_output: the output layer's weights start at 0, so a delta model starts predicting its residual
    part plus the targets' mean delta (a grey box starts as its plant model with a constant correction;
    the hidden layers keep their random start, and reach the loss as soon as the output layer moves).
    """
    input_dim: int
    output_dim: int
    residual: bool = False
    hidden_width: int = 100
    hidden_layers: int = 3
    activation: str = "swish"
    ensemble_size: int = 1
    probabilistic: bool = False
    standardize_inputs: bool = True
    zero_output: bool = False

    def __post_init__(self):
        for field in ("input_dim", "output_dim", "hidden_width", "hidden_layers", "ensemble_size"):
            value = getattr(self, field)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise InputError(f"model config: {field} must be a positive integer, got {value!r}")
        get_activation(self.activation)
        if self.residual and self.input_dim < self.output_dim:
            raise InputError(f"model config: the residual (delta) parameterization needs input_dim >= "
                             f"output_dim, got {self.input_dim} < {self.output_dim}")

    @property
    def state_dim(self) -> int:
        """S when used as an STDM (outputs are next states)."""
        return self.output_dim

    @property
    def action_dim(self) -> int:
        """A when used as an STDM (inputs are [state, action])."""
        return self.input_dim - self.output_dim

    @classmethod
    def from_dict(cls, values: dict) -> "ModelConfig":
        names = {field.name for field in dataclasses.fields(cls)}
        unknown = sorted(set(values) - names)
        if unknown:
            raise InputError(f"model config: unknown fields {unknown}")
        return cls(**values)


def dynamics_config(*, state_dim: int, action_dim: int, delta: bool = True, **network_options) -> ModelConfig:
    """ModelConfig of an STDM x_{t+1} = f(x_t, a_t): inputs [x (S), a (A)], outputs x_{t+1} (S)."""
    if isinstance(action_dim, bool) or not isinstance(action_dim, (int, np.integer)) or action_dim < 0:
        raise InputError(f"action_dim must be a non-negative integer, got {action_dim!r}")
    return ModelConfig(input_dim=state_dim + action_dim, output_dim=state_dim, residual=delta, **network_options)


class Normalizer(nn.Module):
    """Per-feature affine standardization x_n = (x - mean) / std, statistics from training data.

    Features with (near) zero spread keep std = 1, so constant columns pass through unscaled.
    """

    def __init__(self, dim: int):
        super().__init__()
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("std", torch.ones(dim))

    def fit(self, data, minimum=None) -> "Normalizer":
        """Set mean/std from data (N, dim) (numpy or torch), computed in float64; minimum (dim,): a floor
        on std (a spread below it is noise, not signal: see `regression.fit_normalizers`)."""
        values = np.asarray(data.detach().cpu().numpy() if isinstance(data, Tensor) else data, dtype=np.float64)
        if values.ndim != 2 or values.shape[1] != self.mean.numel() or len(values) == 0:
            raise InputError(f"normalizer: data must have shape (N>0, {self.mean.numel()}), got {values.shape}")
        mean = values.mean(axis=0)
        std = values.std(axis=0)
        if minimum is not None:
            std = np.maximum(std, minimum)
        std[~(std > 1e-8 * np.maximum(1.0, np.abs(mean)))] = 1.0
        self.mean.copy_(torch.from_numpy(mean))
        self.std.copy_(torch.from_numpy(std))
        return self

    def normalize(self, values: Tensor) -> Tensor:
        return (values - self.mean) / self.std

    def denormalize(self, values: Tensor) -> Tensor:
        return values * self.std + self.mean


def bounded_logvar(raw: Tensor, min_logvar: Tensor, max_logvar: Tensor) -> Tensor:
    """PETS soft clamp of a log-variance into (min_logvar, max_logvar) with softplus hinges."""
    upper = max_logvar - F.softplus(max_logvar - raw)
    return min_logvar + F.softplus(upper - min_logvar)


class EnsembleMLP(TrainableModel):
    """Ensemble of `ensemble_size` MLPs with stacked weights, built from a ModelConfig: the paper's D, P, DE,
    PE networks (the "ensemble_mlp" kind of `trainable.TrainableModel`).

    Parameters: weights[l] (E, in_l, out_l), biases[l] (E, 1, out_l), Xavier-uniform weights, zero
    biases; probabilistic members also have min_logvar/max_logvar (E, 1, out_dim). Buffers: input
    and output normalizers (the output spread σ_y also scales the derivative loss, see `trainer`).
    """
    kind = "ensemble_mlp"
    config_type = ModelConfig
    member_parameters = MEMBER_PARAMETERS

    def __init__(self, config: ModelConfig, generator: torch.Generator | None = None):
        super().__init__(config)
        self.activation = get_activation(config.activation)
        members = config.ensemble_size
        head = config.output_dim * (2 if config.probabilistic else 1)
        sizes = [config.input_dim] + [config.hidden_width] * config.hidden_layers + [head]
        self.weights = nn.ParameterList(
            nn.Parameter(torch.empty(members, fan_in, fan_out)) for fan_in, fan_out in zip(sizes[:-1], sizes[1:]))
        self.biases = nn.ParameterList(nn.Parameter(torch.zeros(members, 1, fan_out)) for fan_out in sizes[1:])
        with torch.no_grad():
            for weight in self.weights:
                for member_weight in weight:
                    nn.init.xavier_uniform_(member_weight, generator=generator)
            if config.zero_output:
                self.weights[-1].zero_()
        if config.probabilistic:
            self.min_logvar = nn.Parameter(torch.full((members, 1, config.output_dim), MIN_LOGVAR_INIT))
            self.max_logvar = nn.Parameter(torch.full((members, 1, config.output_dim), MAX_LOGVAR_INIT))
        self.input_normalizer = Normalizer(config.input_dim)
        self.output_normalizer = Normalizer(config.output_dim)

    # -- shapes ---------------------------------------------------------------------------------
    def per_member(self, values: Tensor) -> Tensor:
        """(B, d) -> (E, B, d) shared by all members (a view); (E, B, d) passes through."""
        if values.dim() == 2:
            return values.unsqueeze(0).expand(self.config.ensemble_size, -1, -1)
        if values.dim() == 3 and values.shape[0] == self.config.ensemble_size:
            return values
        raise InputError(f"expected inputs of shape (B, d) or ({self.config.ensemble_size}, B, d), "
                         f"got {tuple(values.shape)}")

    def residual(self, values: Tensor) -> Tensor:
        """r(z): z[..., :out_dim] for the delta parameterization, else 0 (also maps tangents ż)."""
        if self.config.residual:
            return values[..., :self.config.output_dim]
        return torch.zeros(values.shape[:-1] + (self.config.output_dim,), dtype=values.dtype, device=values.device)

    # -- normalized network ------------------------------------------------------------------------
    def normalized_outputs(self, inputs_n: Tensor) -> Tensor:
        """Plain pass: z_n (B, in) or (E, B, in) -> raw head outputs (E, B, out_dim [x2 if probabilistic])."""
        h = self.per_member(inputs_n)
        for weight, bias in zip(self.weights[:-1], self.biases[:-1]):
            h = self.activation.function(torch.baddbmm(bias, h, weight))
        return torch.baddbmm(self.biases[-1], h, self.weights[-1])

    def normalized_outputs_with_tangent(self, inputs_n: Tensor, tangents_n: Tensor) -> tuple[Tensor, Tensor]:
        """JVP pass: (z_n, ż_n) -> (head outputs (E, B, ·), J_n ż_n of the mean head (E, B, out_dim))."""
        return TangentPropagation.apply(self.activation, self.config.output_dim,
                                         self.per_member(inputs_n), self.per_member(tangents_n),
                                         *self.weights, *self.biases)

    def split_head(self, outputs: Tensor) -> tuple[Tensor, Tensor | None]:
        """Head outputs -> (standardized mean, bounded standardized log-variance or None)."""
        out = self.config.output_dim
        if not self.config.probabilistic:
            return outputs, None
        return outputs[..., :out], bounded_logvar(outputs[..., out:], self.min_logvar, self.max_logvar)

    def member_logvar_bound_penalty(self) -> Tensor:
        """PETS regularizer 0.01 (Σ max_logvar - Σ min_logvar) of each member, (E,)."""
        return LOGVAR_BOUND_PENALTY * (self.max_logvar - self.min_logvar).sum(dim=(1, 2))

    # -- raw units (reference implementation; the fast inference path is stdm_drake.learning.predict) --------
    def forward(self, inputs: Tensor) -> tuple[Tensor, Tensor | None]:
        """z (B, in) raw -> (mean (E, B, out), variance (E, B, out) or None) in raw output units."""
        stacked = self.per_member(inputs)
        mean_n, logvar_n = self.split_head(self.normalized_outputs(self.input_normalizer.normalize(stacked)))
        mean = self.residual(stacked) + self.output_normalizer.denormalize(mean_n)
        variance = None if logvar_n is None else torch.exp(logvar_n) * self.output_normalizer.std ** 2
        return mean, variance

    def time_derivative(self, inputs: Tensor, input_rates: Tensor) -> Tensor:
        """d mean/dt = J(z) ż in raw units: z, ż (B, in) -> (E, B, out) (chain rule of paper eq. 7-8)."""
        stacked, rates = self.per_member(inputs), self.per_member(input_rates)
        _, tangent_n = self.normalized_outputs_with_tangent(
            self.input_normalizer.normalize(stacked), rates / self.input_normalizer.std)
        return self.residual(rates) + tangent_n * self.output_normalizer.std

    # -- the trainable-model interface (`trainable.TrainableModel`) ---------------------------------------
    @classmethod
    def problem_config(cls, *, input_dim: int, output_dim: int, residual: bool, ensemble_size: int,
                       probabilistic: bool, start_at_residual: bool, options: dict) -> ModelConfig:
        return ModelConfig(input_dim=input_dim, output_dim=output_dim, residual=residual,
                           hidden_width=options["hidden_width"], hidden_layers=options["hidden_layers"],
                           activation=options["activation"], ensemble_size=ensemble_size, probabilistic=probabilistic,
                           zero_output=start_at_residual)

    def fit_normalizers(self, data) -> None:
        """Input and output statistics from training data (raw units, float64). With standardize_inputs=False
        the input normalizer stays the identity; a delta model's output spread has the floor
        DELTA_SPREAD_FLOOR x its targets' spread."""
        inputs = np.asarray(data.inputs, dtype=np.float64)
        if self.config.standardize_inputs:
            self.input_normalizer.fit(inputs)
        targets = np.asarray(data.targets, dtype=np.float64)
        floor = DELTA_SPREAD_FLOOR * targets.std(axis=0) if self.config.residual else None
        self.output_normalizer.fit(targets - self._raw_residual(inputs), minimum=floor)

    def _raw_residual(self, values: np.ndarray) -> np.ndarray:
        out = self.config.output_dim
        return values[:, :out] if self.config.residual else np.zeros((len(values), out))

    def standardize(self, data):
        """Raw arrays -> network units with the normalizers (computed in float64, then cast): z_n, y_n, and
        for derivative learning ż_n = ż/σ_z and (ẏ - r(ż))/σ_y (see the module docstring)."""
        dtype = next(self.parameters()).dtype
        z_mean, z_std = (value.double().numpy() for value in (self.input_normalizer.mean, self.input_normalizer.std))
        y_mean, y_std = (value.double().numpy() for value in (self.output_normalizer.mean, self.output_normalizer.std))
        inputs = np.asarray(data.inputs, dtype=np.float64)
        result = StandardizedData(
            inputs=torch.from_numpy((inputs - z_mean) / z_std).to(dtype),
            targets=torch.from_numpy((np.asarray(data.targets, np.float64) - self._raw_residual(inputs) - y_mean)
                                     / y_std).to(dtype),
            input_rates=None, target_rates=None)
        if data.has_rates:
            input_rates = np.asarray(data.input_rates, dtype=np.float64)
            result.input_rates = torch.from_numpy(input_rates / z_std).to(dtype)
            result.target_rates = torch.from_numpy((np.asarray(data.target_rates, np.float64)
                                                    - self._raw_residual(input_rates)) / y_std).to(dtype)
        return result

    def loss(self, training, inputs, targets, input_rates=None, target_rates=None) -> LossTerms:
        """Loss terms per member on standardized tensors (E, B, ·) or (B, ·): the state term (MSE, MAE, Huber,
        or the PETS Gaussian NLL with the log-variance bound penalty) plus alpha times the derivative term on
        J_n ż_n (one forward-mode pass) where `training.derivative`."""
        if training.derivative:
            outputs, tangents = self.normalized_outputs_with_tangent(inputs, input_rates)
        else:
            outputs, tangents = self.normalized_outputs(inputs), None
        return self.losses_from_outputs(training, outputs, tangents, targets, target_rates)

    def losses_from_outputs(self, training, outputs, tangents, targets, target_rates) -> LossTerms:
        """Loss terms per member from head outputs (E, B, ·) and mean-head tangents J_n ż_n (None: no derivative term)."""
        mean, logvar = self.split_head(outputs)
        target = self.per_member(targets)
        if logvar is None:
            state_term = member_point_loss(training.state_loss, mean, target, training.huber_delta)
        else:
            state_term = member_gaussian_nll(mean, logvar, target) + self.member_logvar_bound_penalty()
        if tangents is None:
            return LossTerms(total=state_term, state=state_term, derivative=None)
        derivative_term = self.derivative_term(training, tangents, self.per_member(target_rates))
        alphas = training.member_alphas(self.config.ensemble_size).to(derivative_term.dtype)
        return LossTerms(total=state_term + alphas * derivative_term, state=state_term, derivative=derivative_term)

    @torch.no_grad()
    def eval_score(self, training, data) -> dict:
        """Validation loss terms (the training formula, averaged over members) and each member's standardized
        state MSE (E,) float64, the selection criterion."""
        if training.derivative and data.input_rates is not None:
            outputs, tangents = self.normalized_outputs_with_tangent(data.inputs, data.input_rates)
        else:
            outputs, tangents = self.normalized_outputs(data.inputs), None
        total, state_term, derivative_term = self.losses_from_outputs(training, outputs, tangents, data.targets,
                                                          data.target_rates).means()
        mean, _ = self.split_head(outputs)
        member_mse = ((mean - data.targets) ** 2).mean(dim=(1, 2)).double()
        return dict(loss=total, state=state_term, derivative=derivative_term, member_mse=member_mse)

    @torch.no_grad()
    def member_row_errors(self, data) -> torch.Tensor:
        mean, _ = self.split_head(self.normalized_outputs(data.inputs))
        return ((mean - data.targets) ** 2).mean(dim=2).double()

    @classmethod
    def describe_config(cls, config: ModelConfig) -> str:
        return f"{config.hidden_layers}x{config.hidden_width} {config.activation}"

    @classmethod
    def weight_count(cls, config: ModelConfig) -> int:
        """E L W², the hidden layers' weights (the sizing the settings' checks use, without a network built)."""
        return config.ensemble_size * config.hidden_layers * config.hidden_width ** 2

    def config_record(self) -> dict:
        """The config without zero_output (how the weights started: the weights themselves are stored)."""
        return {key: value for key, value in dataclasses.asdict(self.config).items() if key != "zero_output"}

    def inference(self):
        """The fast float32 NumPy engine (`predict.InferenceModel`)."""
        return InferenceModel(self)
