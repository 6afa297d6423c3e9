"""The hidden-layer activations: one record per activation (`Activation`) with its torch pass, its
hand-written tangent (JVP) pass for derivative learning, its NumPy inference pass and that pass's slope.
Adding an activation is one record here; `models.EnsembleMLP` and `predict.InferenceModel` look them up
by name."""
from __future__ import annotations

import dataclasses
import math
from typing import Callable

import numpy as np
import torch
import torch.nn.functional as F
from scipy import special

from stdm_drake.errors import InputError

Tensor = torch.Tensor

ACTIVATION_NAMES = ("tanh", "sigmoid", "relu", "leaky_relu", "softplus", "selu", "elu", "gelu", "swish")
LEAKY_RELU_SLOPE = 0.01
SELU_SCALE = 1.0507009873554804934193349852946
SELU_ALPHA = 1.6732632423543772848170429916717

_CONSTANTS: dict = {}


def _constant(value: float, like: Tensor) -> Tensor:
    """A cached 0-d tensor of `value` with the dtype and device of `like` (for lerp/where/addcmul)."""
    key = (value, like.dtype, like.device)
    if key not in _CONSTANTS:
        _CONSTANTS[key] = torch.tensor(value, dtype=like.dtype, device=like.device)
    return _CONSTANTS[key]


# Tangent rules. Each takes the pre-activation h and its tangent ḣ (both (E, B, H), consumed: they
# may be overwritten) and returns (y, ẏ, slope, curvature_term):
#   y = f(h), ẏ = f'(h) ḣ, slope = f'(h), curvature_term = f''(h) ḣ (None where f'' = 0).
# The backward pass needs exactly slope and curvature_term:
#   ∂L/∂h = ∂L/∂y ⊙ slope + ∂L/∂ẏ ⊙ curvature_term,   ∂L/∂ḣ = ∂L/∂ẏ ⊙ slope.

def _swish_tangent(h, hd):
    s = torch.sigmoid(h)
    y = h.mul_(s)                                   # h s
    slope = torch.lerp(s, _constant(1.0, s), y)     # s + h s (1 - s)
    yd = hd * slope
    # f'' = s (1-s)(2 + h(1-2s)) = s + f' - 2 s f', so f'' ḣ = ẏ + s (ḣ - 2 ẏ)
    curvature = torch.addcmul(yd, s, hd.add_(yd, alpha=-2.0))
    return y, yd, slope, curvature


def _tanh_tangent(h, hd):
    y = torch.tanh(h)
    slope = torch.addcmul(_constant(1.0, y), y, y, value=-1.0)   # 1 - y²
    yd = hd * slope
    curvature = torch.mul(y, yd).mul_(-2.0)                      # f'' = -2 y f'
    return y, yd, slope, curvature


def _sigmoid_tangent(h, hd):
    y = torch.sigmoid(h)
    slope = torch.addcmul(y, y, y, value=-1.0)                   # y (1 - y)
    yd = hd * slope
    curvature = torch.addcmul(yd, y, yd, value=-2.0)             # f'' = f' (1 - 2y)
    return y, yd, slope, curvature


def _relu_tangent(h, hd):
    slope = (h > 0).to(h.dtype)
    return torch.relu(h), hd.mul_(slope), slope, None


def _leaky_relu_tangent(h, hd):
    slope = (h > 0).to(h.dtype).mul_(1.0 - LEAKY_RELU_SLOPE).add_(LEAKY_RELU_SLOPE)
    return F.leaky_relu(h, LEAKY_RELU_SLOPE), hd.mul_(slope), slope, None


def _softplus_tangent(h, hd):
    y = F.softplus(h)
    slope = torch.sigmoid(h)
    yd = hd * slope
    curvature = torch.addcmul(yd, slope, yd, value=-1.0)         # f'' = s (1 - s)
    return y, yd, slope, curvature


def _exponential_linear_tangent(scale: float, alpha: float):
    """ELU-type f = scale * (h if h > 0 else alpha (e^h - 1)); for h <= 0, f' = f'' = f + scale alpha."""
    def tangent(h, hd):
        y = F.selu(h) if scale != 1.0 else F.elu(h, alpha)
        positive = h > 0
        slope = torch.where(positive, _constant(scale, y), y + scale * alpha)
        yd = hd.mul_(slope)
        curvature = torch.where(positive, _constant(0.0, y), yd)
        return y, yd, slope, curvature
    return tangent


_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


def _gelu_tangent(h, hd):
    y = F.gelu(h)
    cdf = torch.special.ndtr(h)
    pdf = torch.exp(-0.5 * h * h).mul_(_INV_SQRT_2PI)
    slope = torch.addcmul(cdf, h, pdf)                            # Φ + h φ
    yd = hd * slope
    curvature = torch.addcmul(_constant(2.0, h), h, h, value=-1.0).mul_(pdf).mul_(hd)   # φ (2 - h²) ḣ
    return y, yd, slope, curvature



# ---- NumPy inference passes and their slopes ----

def _swish(scaled, out):
    """swish(h) = h σ(h) = g (1 + tanh g) with g = h/2 (the 1/2 is folded into the layer weights)."""
    np.tanh(scaled, out=out)
    out *= scaled
    out += scaled
    return out


def _leaky_relu(pre, out):
    np.multiply(pre, LEAKY_RELU_SLOPE, out=out)
    return np.maximum(pre, out, out=out)


def _exponential_linear(scale, alpha):
    def apply(pre, out):
        np.expm1(np.minimum(pre, 0.0), out=out)
        out *= alpha
        np.copyto(out, pre, where=pre > 0)
        out *= scale
        return out
    return apply


def _swish_slope(scaled):
    t = np.tanh(scaled)
    return 1.0 + t + scaled * (1.0 - t * t)


def _exponential_linear_slope(scale, alpha):
    return lambda pre: np.where(pre > 0, scale, scale * alpha * np.exp(np.minimum(pre, 0.0)))


_INV_SQRT_2PI_NUMPY = 0.3989422804014327  # 1 / sqrt(2 pi), a Python float: keeps float32 arrays float32


@dataclasses.dataclass(frozen=True)
class Activation:
    """A hidden-layer nonlinearity, everything stdm-drake computes with it in one record.

    function(h): the plain torch pass; tangent(h, ḣ): the torch JVP pass (y, ẏ, slope, curvature
    term) of derivative learning; numpy(scaled, out) -> out: the NumPy inference pass on the
    pre-activation times numpy_scale (folded into the layer weights by `predict.InferenceModel`);
    numpy_slope(scaled): its derivative in the same variable (the Jacobians the MPC uses)."""
    name: str
    function: Callable[[Tensor], Tensor]
    tangent: Callable[[Tensor, Tensor], tuple]
    numpy_scale: float
    numpy: Callable
    numpy_slope: Callable


ACTIVATIONS: dict[str, Activation] = {activation.name: activation for activation in (
    Activation("tanh", torch.tanh, _tanh_tangent,
               numpy_scale=1.0, numpy=lambda pre, out: np.tanh(pre, out=out),
               numpy_slope=lambda pre: 1.0 - np.tanh(pre) ** 2),
    Activation("sigmoid", torch.sigmoid, _sigmoid_tangent,
               numpy_scale=1.0, numpy=lambda pre, out: special.expit(pre, out=out),
               numpy_slope=lambda pre: special.expit(pre) * special.expit(-pre)),
    Activation("relu", torch.relu, _relu_tangent,
               numpy_scale=1.0, numpy=lambda pre, out: np.maximum(pre, 0.0, out=out),
               numpy_slope=lambda pre: (pre > 0).astype(pre.dtype)),
    Activation("leaky_relu", lambda h: F.leaky_relu(h, LEAKY_RELU_SLOPE), _leaky_relu_tangent,
               numpy_scale=1.0, numpy=_leaky_relu,
               numpy_slope=lambda pre: np.where(pre > 0, 1.0, LEAKY_RELU_SLOPE).astype(pre.dtype)),
    Activation("softplus", F.softplus, _softplus_tangent,
               numpy_scale=1.0, numpy=lambda pre, out: np.logaddexp(pre, 0.0, out=out),
               numpy_slope=lambda pre: special.expit(pre)),
    Activation("selu", F.selu, _exponential_linear_tangent(SELU_SCALE, SELU_ALPHA),
               numpy_scale=1.0, numpy=_exponential_linear(SELU_SCALE, SELU_ALPHA),
               numpy_slope=_exponential_linear_slope(SELU_SCALE, SELU_ALPHA)),
    Activation("elu", F.elu, _exponential_linear_tangent(1.0, 1.0),
               numpy_scale=1.0, numpy=_exponential_linear(1.0, 1.0),
               numpy_slope=_exponential_linear_slope(1.0, 1.0)),
    Activation("gelu", F.gelu, _gelu_tangent,
               numpy_scale=1.0, numpy=lambda pre, out: np.multiply(pre, special.ndtr(pre), out=out),
               numpy_slope=lambda pre: special.ndtr(pre) + pre * np.exp(-0.5 * pre * pre) * _INV_SQRT_2PI_NUMPY),
    Activation("swish", F.silu, _swish_tangent,
               numpy_scale=0.5, numpy=_swish,
               numpy_slope=_swish_slope),
)}
assert tuple(ACTIVATIONS) == ACTIVATION_NAMES


def get_activation(name: str) -> Activation:
    if name not in ACTIVATIONS:
        raise InputError(f"unknown activation {name!r}; choose from {', '.join(ACTIVATION_NAMES)}")
    return ACTIVATIONS[name]
