"""Regression data for training: raw arrays (`RegressionData`), their standardized tensors in the
network's units (`StandardizedData`), and the normalizers fitted from the training data."""
from __future__ import annotations

import dataclasses
import hashlib

import numpy as np
import torch

from stdm_drake.errors import InputError
from stdm_drake.learning.models import EnsembleMLP, ModelConfig


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


# A delta model's output spread is at least this fraction of its targets' own spread: a grey box on an exact
# plant model has residual targets of rounding size (1e-10 rad/s), which standardized would be fitted as
# signal (and Adam's scale-free steps would move the outputs of all-zero ones by 1e-3 of a unit).
DELTA_SPREAD_FLOOR = 1e-4


def fit_normalizers(model: EnsembleMLP, data: RegressionData) -> None:
    """Input and output statistics from training data (raw units, float64). With
    standardize_inputs=False the input normalizer stays the identity; a delta model's output spread has
    the floor DELTA_SPREAD_FLOOR x its targets' spread."""
    inputs = np.asarray(data.inputs, dtype=np.float64)
    if model.config.standardize_inputs:
        model.input_normalizer.fit(inputs)
    targets = np.asarray(data.targets, dtype=np.float64)
    floor = DELTA_SPREAD_FLOOR * targets.std(axis=0) if model.config.residual else None
    model.output_normalizer.fit(targets - _residual(model.config, inputs), minimum=floor)


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
