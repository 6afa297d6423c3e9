"""ONNX graphs of a trained ensemble MLP: its forward pass and its forward-mode Jacobian, as ONNX operators
(opset 17) over float32 tensors, so ONNX Runtime (or any ONNX backend) runs them without Python.

`GraphBuilder` collects nodes and constants; `network_outputs` and `network_jacobian` add one network to it:
    z (N, K) raw network inputs -> z_n = (z - μ_z) / σ_z -> L hidden layers (activation) -> head
    member means (E, N, out) = σ_y ⊙ head[..., :out] + μ_y (+ z[:, :out] for a delta network), and for a
    probabilistic network the PETS-bounded log-variance as member variances (E, N, out) in raw units;
    the Jacobian d(ensemble mean)/dz (N, out, K) carries all K unit tangents through the layers at once,
    (E, N, K, H) per layer, as `predict.InferenceModel.mean_and_jacobian` does.
The standardizations are folded into the first and last layers' weights in float64 (`_folded_layers`), as the
toolbox's own inference does: fewer operators per call (what a batch-1 step costs) and the same rounding.
Every activation stdm-drake trains is here (`ACTIVATION_OPS`): the operator ONNX has for it, or its formula
in ONNX operators (swish, GELU), with its slope for the Jacobian.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from stdm_drake.learning.activations import LEAKY_RELU_SLOPE, SELU_ALPHA, SELU_SCALE
from stdm_drake.learning.predict import fold_input_standardization

OPSET = 17     # ONNX Runtime 1.14 and later, TensorRT 8.6, OpenVINO 2023: the deployment stacks of 2023 on
F32 = np.float32


@dataclasses.dataclass(frozen=True)
class NetworkArrays:
    """An ensemble MLP's parameters in float64 (`from_network`). E members, K inputs, H width, out outputs.

    weights[l] (E, in_l, out_l), biases[l] (E, 1, out_l); input_mean/input_std (K,); output_mean/output_std
    (out,); min_logvar/max_logvar (E, 1, out) for probabilistic networks, else None."""
    weights: list
    biases: list
    input_mean: np.ndarray
    input_std: np.ndarray
    output_mean: np.ndarray
    output_std: np.ndarray
    activation: str
    residual: bool
    output_dim: int
    min_logvar: np.ndarray | None = None
    max_logvar: np.ndarray | None = None

    @classmethod
    def from_network(cls, network) -> "NetworkArrays":
        def array(tensor):
            return tensor.detach().cpu().double().numpy().copy()
        config = network.config
        probabilistic = config.probabilistic
        return cls(weights=[array(w) for w in network.weights], biases=[array(b) for b in network.biases],
                   input_mean=array(network.input_normalizer.mean), input_std=array(network.input_normalizer.std),
                   output_mean=array(network.output_normalizer.mean), output_std=array(network.output_normalizer.std),
                   activation=config.activation, residual=config.residual, output_dim=config.output_dim,
                   min_logvar=array(network.min_logvar) if probabilistic else None,
                   max_logvar=array(network.max_logvar) if probabilistic else None)

    @property
    def members(self) -> int:
        return self.weights[0].shape[0]

    @property
    def input_dim(self) -> int:
        return self.weights[0].shape[1]

    @property
    def probabilistic(self) -> bool:
        return self.min_logvar is not None


class GraphBuilder:
    """The nodes and constant tensors (initializers) of one graph; `op` adds a node and returns its output's name."""

    def __init__(self):
        self.nodes: list = []
        self.initializers: list = []
        self._names: dict[str, int] = {}

    def fresh(self, stem: str) -> str:
        count = self._names[stem] = self._names.get(stem, 0) + 1
        return stem if count == 1 else f"{stem}_{count}"

    def constant(self, value, stem: str, dtype=F32) -> str:
        name = self.fresh(stem)
        self.initializers.append(numpy_helper.from_array(np.asarray(value, dtype=dtype), name))
        return name

    def op(self, op_type: str, inputs: list, stem: str | None = None, output: str | None = None, **attributes) -> str:
        name = output or self.fresh(stem or op_type.lower())
        self.nodes.append(helper.make_node(op_type, list(inputs), [name], name=f"{name}_node", **attributes))
        return name

    def columns(self, values: str, start: int, stop: int, axis: int, stem: str) -> str:
        """values[..., start:stop] along `axis` (a Slice)."""
        return self.op("Slice", [values, self.constant([start], "start", np.int64), self.constant([stop], "stop", np.int64),
                                 self.constant([axis], "axis", np.int64)], stem)

    def model(self, inputs: list, outputs: list, *, name: str, doc: str, metadata: dict) -> onnx.ModelProto:
        """The checked model of the graph (opset OPSET), with string metadata (`metadata_props`)."""
        graph = helper.make_graph(self.nodes, name, inputs, outputs, self.initializers, doc_string=doc)
        model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                                  producer_name="stdm-drake", doc_string=doc)
        model.ir_version = 8       # (what ONNX Runtime 1.14 and later read)
        helper.set_model_props(model, {key: str(value) for key, value in metadata.items()})
        onnx.checker.check_model(model, full_check=True)
        return model


def tensor_info(name: str, shape: list, doc: str) -> onnx.ValueInfoProto:
    """A float32 graph input or output; shape entries are ints or symbolic names ("batch")."""
    return helper.make_tensor_value_info(name, TensorProto.FLOAT, shape, doc_string=doc)


# ---- activations: y = f(h) and the slope f'(h), in ONNX operators ----

def _where_positive(b: GraphBuilder, h: str, positive: str, other: str) -> str:
    return b.op("Where", [b.op("Greater", [h, b.constant(0.0, "zero")]), positive, other])


def _exponential_linear_slope(scale: float, alpha: float):
    def slope(b: GraphBuilder, h: str) -> str:
        negative = b.op("Mul", [b.op("Exp", [b.op("Min", [h, b.constant(0.0, "zero")])]),
                                b.constant(scale * alpha, "scale_alpha")])
        return _where_positive(b, h, b.constant(scale, "scale"), negative)
    return slope


def _gelu(b: GraphBuilder, h: str) -> str:
    return b.op("Mul", [h, _normal_cdf(b, h)], "gelu")


def _normal_cdf(b: GraphBuilder, h: str) -> str:
    erf = b.op("Erf", [b.op("Mul", [h, b.constant(1.0 / math.sqrt(2.0), "inv_sqrt2")])])
    return b.op("Mul", [b.op("Add", [erf, b.constant(1.0, "one")]), b.constant(0.5, "half")])


def _gelu_slope(b: GraphBuilder, h: str) -> str:
    density = b.op("Mul", [b.op("Exp", [b.op("Mul", [b.op("Mul", [h, h]), b.constant(-0.5, "minus_half")])]),
                           b.constant(1.0 / math.sqrt(2.0 * math.pi), "inv_sqrt_2pi")])
    return b.op("Add", [_normal_cdf(b, h), b.op("Mul", [h, density])])


def _swish_slope(b: GraphBuilder, h: str) -> str:
    s = b.op("Sigmoid", [h])        # s (1 + h (1 - s))
    return b.op("Mul", [s, b.op("Add", [b.constant(1.0, "one"), b.op("Mul", [h, b.op("Sub", [b.constant(1.0, "one"), s])])])])


def _logistic_slope(b: GraphBuilder, h: str) -> str:
    s = b.op("Sigmoid", [h])
    return b.op("Mul", [s, b.op("Sub", [b.constant(1.0, "one"), s])])


# name -> (f: (builder, h) -> y, slope: (builder, h) -> f'(h))
ACTIVATION_OPS = {
    "tanh": (lambda b, h: b.op("Tanh", [h]),
             lambda b, h: b.op("Sub", [b.constant(1.0, "one"), b.op("Mul", [b.op("Tanh", [h])] * 2)])),
    "sigmoid": (lambda b, h: b.op("Sigmoid", [h]), _logistic_slope),
    "relu": (lambda b, h: b.op("Relu", [h]),
             lambda b, h: b.op("Cast", [b.op("Greater", [h, b.constant(0.0, "zero")])], to=TensorProto.FLOAT)),
    "leaky_relu": (lambda b, h: b.op("LeakyRelu", [h], alpha=LEAKY_RELU_SLOPE),
                   lambda b, h: _where_positive(b, h, b.constant(1.0, "one"), b.constant(LEAKY_RELU_SLOPE, "leak"))),
    "softplus": (lambda b, h: b.op("Softplus", [h]), lambda b, h: b.op("Sigmoid", [h])),
    "selu": (lambda b, h: b.op("Selu", [h], alpha=SELU_ALPHA, gamma=SELU_SCALE),
             _exponential_linear_slope(SELU_SCALE, SELU_ALPHA)),
    "elu": (lambda b, h: b.op("Elu", [h], alpha=1.0), _exponential_linear_slope(1.0, 1.0)),
    "gelu": (_gelu, _gelu_slope),
    "swish": (lambda b, h: b.op("Mul", [h, b.op("Sigmoid", [h])], "swish"), _swish_slope),
}


# ---- the network ----

def _folded_layers(net: NetworkArrays) -> list:
    """(weight, bias) of every layer with the input standardization folded into the first and the output scale
    (σ_y, μ_y) into the mean head of the last, in float64 (as `predict.InferenceModel` does): z_n W + b =
    z (W / σ_z) + (b - (μ_z / σ_z) W). A single network's are 2-D ((in, out), (1, out)): plain Gemm, no batch axis."""
    weights, biases = [w.copy() for w in net.weights], [b.copy() for b in net.biases]
    weights[0], biases[0] = fold_input_standardization(weights[0], biases[0], net.input_mean, net.input_std)
    out = net.output_dim
    weights[-1][..., :out] *= net.output_std
    biases[-1][..., :out] = biases[-1][..., :out] * net.output_std + net.output_mean
    if net.members == 1:
        return [(w[0], b[0]) for w, b in zip(weights, biases)]
    return list(zip(weights, biases))


def _layers(b: GraphBuilder, z: str, layers: list, activation: str, with_slopes: bool):
    """The hidden layers on raw inputs z (N, K): the last hidden output ((E,) N, H) and each layer's slope f'(pre)."""
    function, slope = ACTIVATION_OPS[activation]
    hidden, slopes = z, []
    for index, (weight, bias) in enumerate(layers[:-1]):
        if index == 0 and weight.ndim == 3:   # every member's first layer in one (K, E H) product, then (E, N, H)
            members, width = weight.shape[0], weight.shape[2]
            flat = b.op("Add", [b.op("MatMul", [z, b.constant(weight.transpose(1, 0, 2).reshape(len(weight[0]), -1),
                                                             "weight0")]),
                                b.constant(bias.reshape(-1), "bias0")], "first_layer_standardized_inputs")
            pre = b.op("Transpose", [b.op("Reshape", [flat, b.constant([0, members, width], "shape", np.int64)])],
                       "pre_activation0", perm=[1, 0, 2])
        else:
            stem = "first_layer_standardized_inputs" if index == 0 else f"pre_activation{index}"
            pre = b.op("Add", [b.op("MatMul", [hidden, b.constant(weight, f"weight{index}")]),
                               b.constant(bias, f"bias{index}")], stem)
        if with_slopes:
            slopes.append(slope(b, pre))
        hidden = function(b, pre)
    return hidden, slopes


def network_outputs(b: GraphBuilder, z: str, net: NetworkArrays) -> tuple[str, str | None, str | None]:
    """From raw network inputs z (N, K): member outputs (E, N, out) in raw units without the delta's residual (a
    single network's: (N, out)), the residual z[:, :out] (N, out) (None for a direct network) and, for a
    probabilistic network, member variances of the same shape as the outputs (else None). (The residual, shared by
    all members, is added after their spread is taken.)"""
    layers = _folded_layers(net)
    hidden, _ = _layers(b, z, layers, net.activation, with_slopes=False)
    out, axis = net.output_dim, 1 if net.members == 1 else 2
    head = b.op("Add", [b.op("MatMul", [hidden, b.constant(layers[-1][0], "weight_out")]),
                        b.constant(layers[-1][1], "bias_out")], "head")
    mean = b.columns(head, 0, out, axis, "network_output") if net.probabilistic else head
    residual = b.columns(z, 0, out, 1, "residual") if net.residual else None
    if not net.probabilistic:
        return mean, residual, None
    raw = b.columns(head, out, 2 * out, axis, "raw_logvar")
    bounds = [net.max_logvar, net.min_logvar] if net.members > 1 else [net.max_logvar[0], net.min_logvar[0]]
    top, bottom = b.constant(bounds[0], "max_logvar"), b.constant(bounds[1], "min_logvar")
    upper = b.op("Sub", [top, b.op("Softplus", [b.op("Sub", [top, raw])])])
    logvar = b.op("Add", [bottom, b.op("Softplus", [b.op("Sub", [upper, bottom])])], "logvar")
    variance = b.op("Mul", [b.op("Exp", [logvar]), b.constant(net.output_std ** 2, "output_variance")], "member_variance")
    return mean, residual, variance


def network_jacobian(b: GraphBuilder, z: str, net: NetworkArrays) -> tuple[str, str]:
    """Ensemble-mean output (N, out) (residual added) and its Jacobian d/dz (N, out, K) (residual included),
    forward mode with the K unit tangents of every row: per layer ((E,) N, K, H) = (((E,) N, K, H) @ W) ⊙ f'(pre)."""
    members, width = net.members, net.input_dim
    out = net.output_dim
    layers = _folded_layers(net)
    hidden, slopes = _layers(b, z, layers, net.activation, with_slopes=True)
    single = members == 1
    spread = (lambda w: w) if single else (lambda w: w[:, None])      # a weight over the tangents' K axis
    unsqueeze = b.constant([1 if single else 2], "tangent_axis", np.int64)
    tangent = b.op("Mul", [b.op("Unsqueeze", [slopes[0], unsqueeze]), b.constant(spread(layers[0][0]), "input_tangent")],
                   "tangent0")                                                           # d pre / dz
    for index, (weight, _) in enumerate(layers[1:-1], start=1):
        product = b.op("MatMul", [tangent, b.constant(spread(weight), f"tangent_weight{index}")])
        tangent = b.op("Mul", [product, b.op("Unsqueeze", [slopes[index], unsqueeze])], f"tangent{index}")
    out_weight, out_bias = layers[-1][0][..., :out] / members, layers[-1][1][..., :out]   # the mean over members folded in
    mean = b.op("MatMul", [hidden, b.constant(out_weight, "mean_weight")])
    jacobian = b.op("MatMul", [tangent, b.constant(spread(out_weight), "jacobian_weight")])   # ((E,) N, K, out)
    if single:
        mean = b.op("Add", [mean, b.constant(out_bias, "mean_bias")], "ensemble_output")
    else:
        mean = b.op("Add", [b.op("ReduceSum", [mean, b.constant([0], "axis", np.int64)], keepdims=0),
                            b.constant(out_bias.mean(axis=0)[0], "mean_bias")], "ensemble_output")
        jacobian = b.op("ReduceSum", [jacobian, b.constant([0], "axis", np.int64)], keepdims=0)
    jacobian = b.op("Transpose", [jacobian], "network_jacobian", perm=[0, 2, 1])
    if net.residual:
        mean = b.op("Add", [mean, b.columns(z, 0, out, 1, "residual")], "ensemble_output_delta")
        jacobian = b.op("Add", [jacobian, b.constant(np.eye(out, width), "residual_jacobian")], "network_jacobian_delta")
    return mean, jacobian
