"""The loss of paper eq. 9 per ensemble member: state term (MSE, MAE, Huber or PETS Gaussian NLL) plus
alpha times the derivative term on the Jacobian-vector product J_n ż_n (see `stdm_drake.learning.trainer`
for the scaling that gives alpha its eq. 9 meaning)."""
from __future__ import annotations

import dataclasses

import torch
import torch.nn.functional as F

from stdm_drake.errors import InputError
from stdm_drake.learning.models import EnsembleMLP
from stdm_drake.learning.settings import LOSS_KINDS, TrainingConfig


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

