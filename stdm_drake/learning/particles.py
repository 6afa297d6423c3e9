"""The paper's black box as PyTorch particles on any device: what sampling MPC (`closed_loop.sampling`) rolls
out with `device: cuda`. The same float32 numbers as the NumPy engine (`predict.InferenceModel`), from its
folded weights, so a solve on a GPU and on the CPU agree to float tolerance for the same action samples.

Shapes for an ensemble of E members, M particles per member, state S = 2n, action A = m: particles laid
out member by member, x (E, M, S), a (E, M, A) float32 tensors on the device.
"""
from __future__ import annotations

import numpy as np
import torch

from stdm_drake.devices import torch_device
from stdm_drake.learning.activations import get_activation


class TorchParticles:
    """Particle steps of an ensemble MLP's inference engine (`predict.InferenceModel`) on a PyTorch device.

    step(x, a, generator): next states (E, M, S), block e through member e, a probabilistic member sampled from
    its Gaussian with `generator` (None: its mean); mean_step(x (N, S), a (N, A)): the ensemble mean (N, S).
    """

    def __init__(self, engine, device: str):
        self.device = torch_device(device)
        activation = get_activation(engine.config.activation)
        scale = activation.numpy_scale        # (folded into the engine's weights; the torch pass takes h itself)
        self.function = activation.function

        def tensor(values):
            return torch.as_tensor(np.ascontiguousarray(values, dtype=np.float32), device=self.device)

        self.first = tensor(engine.input_member_weight / scale)                       # (E, S+A+1, H)
        self.hidden = [(tensor(w / scale), tensor(b / scale)) for w, b in engine.hidden]
        self.mean_weight, self.mean_bias = tensor(engine.mean_weight), tensor(engine.mean_bias)
        self.residual, self.probabilistic = engine.residual, engine.probabilistic
        self.members, self.state_dim = engine.ensemble_size, engine.state_dim
        if self.probabilistic:
            self.logvar_weight, self.logvar_bias = tensor(engine.logvar_weight), tensor(engine.logvar_bias)
            self.min_logvar, self.max_logvar = tensor(engine.min_logvar), tensor(engine.max_logvar)
            self.log_output_variance = tensor(engine.log_output_variance)

    def _outputs(self, inputs: torch.Tensor):
        """Per-member (mean, variance or None), each (E, M, S), from inputs (E, M, S+A+1)."""
        hidden = self.function(torch.matmul(inputs, self.first))
        for weight, bias in self.hidden:
            hidden = self.function(torch.baddbmm(bias, hidden, weight))
        mean = torch.baddbmm(self.mean_bias, hidden, self.mean_weight)
        if not self.probabilistic:
            return mean, None
        raw = torch.baddbmm(self.logvar_bias, hidden, self.logvar_weight)
        upper = self.max_logvar - torch.nn.functional.softplus(self.max_logvar - raw)
        logvar = self.min_logvar + torch.nn.functional.softplus(upper - self.min_logvar)
        return mean, torch.exp(logvar + self.log_output_variance)

    def _rows(self, x: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        return torch.cat([x, a, torch.ones(x.shape[:-1] + (1,), dtype=x.dtype, device=x.device)], dim=-1)

    def step(self, x: torch.Tensor, a: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        mean, variance = self._outputs(self._rows(x, a))
        if generator is not None and variance is not None:
            mean = mean + torch.sqrt(variance) * torch.randn(mean.shape, generator=generator, device=self.device)
        return mean + x if self.residual else mean

    def mean_step(self, x: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        rows = self._rows(x, a)
        mean, _ = self._outputs(rows.expand(self.members, *rows.shape))
        mean = mean.mean(dim=0)
        return mean + x if self.residual else mean
