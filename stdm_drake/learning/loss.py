"""The pieces of paper eq. 9's loss per member, for any network kind: point losses (MSE, MAE, Huber), the PETS
Gaussian NLL, and `LossTerms` (state term + alpha x derivative term), what `TrainableModel.loss` returns
(see `stdm_drake.learning.trainer` for the scaling that gives alpha its eq. 9 meaning)."""
from __future__ import annotations

import dataclasses

import torch
import torch.nn.functional as F

from stdm_drake.errors import InputError

LOSS_KINDS = ("mse", "mae", "huber")   # the point losses of the state and derivative terms


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
