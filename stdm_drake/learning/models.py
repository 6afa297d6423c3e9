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


class _TangentPropagation(torch.autograd.Function):
    """Forward-mode pass through the stacked MLP: (z_n, ż_n) -> (outputs, J_n ż_n), hand-written backward.

    Primal and tangent travel together layer by layer (h = x W + b, ḣ = ẋ W, then f(h), f'(h) ḣ);
    the backward pass returns parameter gradients only (inputs are data). Costs one extra GEMM per
    layer and direction, never a Jacobian.
    """

    @staticmethod
    def forward(ctx, activation, tangent_dim, inputs, input_tangents, *parameters):
        count = len(parameters) // 2
        weights, biases = parameters[:count], parameters[count:]
        x, xd = inputs, input_tangents
        layers = []
        for weight, bias in zip(weights[:-1], biases[:-1]):
            h = torch.baddbmm(bias, x, weight)
            hd = torch.bmm(xd, weight)
            y, yd, slope, curvature = activation.tangent(h, hd)
            layers.append((x, xd, slope, curvature))
            x, xd = y, yd
        out_weight = weights[-1]
        outputs = torch.baddbmm(biases[-1], x, out_weight)
        output_tangents = torch.bmm(xd, out_weight[..., :tangent_dim])
        ctx.save_for_backward(*weights)
        ctx.layers = layers
        ctx.last = (x, xd)
        ctx.tangent_dim = tangent_dim
        return outputs, output_tangents

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_outputs, grad_tangents):
        weights = ctx.saved_tensors
        k = ctx.tangent_dim
        x, xd = ctx.last
        if grad_outputs is None:
            grad_outputs = torch.zeros(x.shape[:2] + (weights[-1].shape[-1],), dtype=x.dtype, device=x.device)
        if grad_tangents is None:
            grad_tangents = torch.zeros(xd.shape[:2] + (k,), dtype=x.dtype, device=x.device)
        out_weight = weights[-1]
        grad_weight = torch.bmm(x.transpose(1, 2), grad_outputs)
        grad_weight[..., :k].baddbmm_(xd.transpose(1, 2), grad_tangents)
        weight_grads = [grad_weight]
        bias_grads = [grad_outputs.sum(1, keepdim=True)]
        gy = torch.bmm(grad_outputs, out_weight.transpose(1, 2))
        gyd = torch.bmm(grad_tangents, out_weight[..., :k].transpose(1, 2))
        for index in range(len(ctx.layers) - 1, -1, -1):
            x, xd, slope, curvature = ctx.layers[index]
            if curvature is None:
                gh = gy.mul_(slope)
            else:
                gh = torch.mul(gyd, curvature).addcmul_(gy, slope)
            ghd = gyd.mul_(slope)
            bias_grads.append(gh.sum(1, keepdim=True))
            weight_grads.append(torch.bmm(x.transpose(1, 2), gh).baddbmm_(xd.transpose(1, 2), ghd))
            if index > 0:
                weight_t = weights[index].transpose(1, 2)
                gy = torch.bmm(gh, weight_t)
                gyd = torch.bmm(ghd, weight_t)
        return (None, None, None, None, *reversed(weight_grads), *reversed(bias_grads))


class EnsembleMLP(nn.Module):
    """Ensemble of `ensemble_size` MLPs with stacked weights, built from a ModelConfig.

    Parameters: weights[l] (E, in_l, out_l), biases[l] (E, 1, out_l), Xavier-uniform weights, zero
    biases; probabilistic members also have min_logvar/max_logvar (E, 1, out_dim). Buffers: input
    and output normalizers (the output spread σ_y also scales the derivative loss, see learn.py).
    """

    def __init__(self, config: ModelConfig, generator: torch.Generator | None = None):
        super().__init__()
        self.config = config
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
        return _TangentPropagation.apply(self.activation, self.config.output_dim,
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

    def member(self, index: int) -> "EnsembleMLP":
        """A single-member copy of member `index` (same normalizers)."""
        if not 0 <= index < self.config.ensemble_size:
            raise InputError(f"member index {index} out of range 0..{self.config.ensemble_size - 1}")
        single = EnsembleMLP(dataclasses.replace(self.config, ensemble_size=1)).to(next(self.parameters()).dtype)
        state = {name: (value[index:index + 1] if name.split(".")[0] in MEMBER_PARAMETERS else value)
                 for name, value in self.state_dict().items()}
        single.load_state_dict(state)
        return single
