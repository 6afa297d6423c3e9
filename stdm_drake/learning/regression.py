"""Regression data for training: raw arrays (`RegressionData`) and their standardized tensors in the
network's units (`StandardizedData`, what `TrainableModel.standardize` returns)."""
from __future__ import annotations

import dataclasses
import hashlib

import numpy as np
import torch

from stdm_drake.errors import InputError


@dataclasses.dataclass
class RegressionData:
    """Training pairs in raw units. inputs z (N, in); targets y (N, out); for derivative learning
    also input_rates ż (N, in) (the chain-rule tangent) and target_rates ẏ (N, out); groups (N,) int: the
    trajectory each pair comes from, where known (the unit of `alpha_selection`'s paired comparison on
    validation; not part of the fingerprint)."""
    inputs: np.ndarray
    targets: np.ndarray
    input_rates: np.ndarray | None = None
    target_rates: np.ndarray | None = None
    groups: np.ndarray | None = None

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

    def check(self, config, *, need_rates: bool, name: str) -> None:
        """Shapes against the model's config (input_dim, output_dim) and finiteness; raises InputError naming the
        array."""
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
