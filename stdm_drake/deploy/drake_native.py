"""A trained model as a diagram of Drake's own C++ systems, no PyTorch and no Python system inside: the
network as `MultilayerPerceptron`s between two `AffineSystem`s that hold the input standardization and the output
structure (delta, the mean over members, the trapezoid rule). Each layer of each member is a perceptron of its own:
Drake finds a system's direct feedthrough by evaluating it symbolically, which for one perceptron of three 100-wide
layers takes minutes (2.5 on this machine) and for one 100-wide layer 20 ms.

Drake's perceptron has tanh, ReLU and the identity (`DRAKE_ACTIVATIONS`), so checkpoints trained with
`--activation tanh` or `--activation relu` are the ones it represents; others are refused in one line.

`NativeModelFile` is the file `stdm-drake export --target drake` writes: a YAML document of Drake's own
serialization (`pydrake.common.yaml`: nested lists of numbers, for a C++ reader of its own), holding, for n joints,
m actions, k feature values and W = 2n + m + k:
    input_map (K, W), input_offset (K,):    z_n = input_map [x; τ; φ] + input_offset, the network's input
    members[e].layers[l].weight (out_l, in_l), .bias (out_l,): the perceptron of member e
    output_map (2n, W + E p), output_offset (2n,): next state = output_map [x; τ; φ; y_1; ...; y_E] + output_offset
(p: the perceptron's outputs; a probabilistic model's log-variance outputs get zero columns: the mean only).
`build_step_diagram` makes the feedthrough step (inputs "state", "action"[, features], output "next_state");
`build_dynamics_diagram` closes it through a `ZeroOrderHold` into a discrete-time system (input "action",
output "state") for models without feature inputs. A perceptron's weights are parameters of its Context:
`NativeModel.set_parameters(diagram, root_context)` puts them in (Drake starts them at zero).
"""

import dataclasses  # (no `from __future__ import annotations`: Drake's YAML reads the field types)
import typing

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.files import line_text
from stdm_drake.outputs import NATIVE_MARKER  # (the first line, how `export` knows its own file)
from stdm_drake.paths import check_input_file

DRAKE_ACTIVATIONS = ("tanh", "relu")


def _empty_matrix():
    return np.zeros((0, 0))


def _empty_vector():
    return np.zeros(0)


@dataclasses.dataclass
class NativeLayer:
    weight: np.ndarray = dataclasses.field(default_factory=_empty_matrix)   # (out, in)
    bias: np.ndarray = dataclasses.field(default_factory=_empty_vector)     # (out,)


@dataclasses.dataclass
class NativeMember:
    layers: typing.List[NativeLayer] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class NativeModelFile:
    """The Drake-native model (module docstring); units: state [q rad, v rad/s], action N m, period s."""
    sample_period: float = 0.0
    joints: int = 0
    action_dim: int = 0
    feature_input: str = ""          # "", "nominal_acceleration", "period_acceleration" or "plant_next_state"
    feature_width: int = 0
    activation: str = "tanh"
    input_map: np.ndarray = dataclasses.field(default_factory=_empty_matrix)
    input_offset: np.ndarray = dataclasses.field(default_factory=_empty_vector)
    members: typing.List[NativeMember] = dataclasses.field(default_factory=list)
    output_map: np.ndarray = dataclasses.field(default_factory=_empty_matrix)
    output_offset: np.ndarray = dataclasses.field(default_factory=_empty_vector)
    description: str = ""


def native_model(checkpoint) -> NativeModelFile:
    """The Drake-native model of a loaded checkpoint; InputError when Drake's perceptron cannot represent it."""
    from stdm_drake.deploy.onnx_export import FEATURE_INPUTS, ExportLayout   # lazy: torch, onnx
    from stdm_drake.deploy.onnx_graph import NetworkArrays   # lazy: torch, onnx
    from stdm_drake.learning.models import EnsembleMLP   # lazy: torch
    config = checkpoint.model_config
    if type(checkpoint.model) is not EnsembleMLP:   # (a subclass kind may compute otherwise)
        raise InputError(f"{checkpoint.path}: a {checkpoint.model.kind!r} network has no Drake-native form")
    if config.activation not in DRAKE_ACTIVATIONS:
        raise InputError(f"{checkpoint.path}: activation {config.activation!r} has no Drake MultilayerPerceptron form "
                         f"(it has {', '.join(DRAKE_ACTIVATIONS)}): retrain with --activation tanh or relu, or export "
                         "to ONNX")
    structure = checkpoint.structure
    state_dim, action_dim = checkpoint.model_sizes
    layout = ExportLayout.of(structure, state_dim, action_dim, checkpoint.sample_period)
    net = NetworkArrays.from_network(checkpoint.model)
    width, out, members = layout.width, net.output_dim, net.members
    order = layout.permutation
    head = net.weights[-1].shape[2]
    network_output = np.zeros((out, width + members * head))     # the delta-added ensemble mean
    if net.residual:
        network_output[:, :width] = order[:out]
    for member in range(members):
        network_output[:, width + member * head + np.arange(out)] = np.diag(net.output_std) / members
    offset = net.output_mean.copy()
    n = layout.joints
    if layout.predicts == "velocity":
        half = 0.5 * layout.sample_period
        angle = half * network_output
        angle[:, :n] += np.eye(n)
        angle[:, n:2 * n] += half * np.eye(n)
        network_output, offset = np.vstack([angle, network_output]), np.concatenate([half * offset, offset])
    feature = FEATURE_INPUTS[structure.inputs][0] if layout.feature_width else ""
    return NativeModelFile(
        sample_period=layout.sample_period, joints=n, action_dim=action_dim, feature_input=feature,
        feature_width=layout.feature_width, activation=config.activation,
        input_map=order / net.input_std[:, None], input_offset=-net.input_mean / net.input_std,
        members=[NativeMember([NativeLayer(w[member].T.copy(), b[member, 0].copy()) for w, b in zip(net.weights, net.biases)])
                 for member in range(members)],
        output_map=network_output, output_offset=offset,
        description=f"{checkpoint.metadata.model_type or 'model'} from {line_text(checkpoint.path.name)}: {structure.label}; "
                    f"{config.ensemble_size} member(s) x {config.hidden_layers}x{config.hidden_width} {config.activation}"
                    + (" (the mean: Drake's system has no variance output)" if config.probabilistic else ""))


def native_text(model: NativeModelFile) -> str:
    """The YAML document of `model`, first line NATIVE_MARKER (what `stdm-drake export` recognizes as its own)."""
    from pydrake.common.yaml import yaml_dump_typed
    return f"{NATIVE_MARKER} {model.description}\n" + yaml_dump_typed(model)


def load_native_model(path) -> NativeModelFile:
    """Read a Drake-native model file (InputError if it is not one)."""
    from pydrake.common.yaml import yaml_load_typed
    path = check_input_file(path, "Drake-native model", missing=FileNotFoundError)
    text = path.read_text(encoding="utf-8", errors="replace")
    if not text.startswith(NATIVE_MARKER):
        raise InputError(f"{path}: not a Drake-native model written by `stdm-drake export --target drake`")
    try:
        return yaml_load_typed(schema=NativeModelFile, data=text)
    except RuntimeError as error:
        raise InputError(f"{path}: unreadable Drake-native model: {str(error).splitlines()[0]}") from None


class NativeModel:
    """The Drake systems of a `NativeModelFile` (module docstring), added to a builder by `add_to`."""

    def __init__(self, model: NativeModelFile):
        self.model = model
        self.perceptrons = []

    def add_to(self, builder, name: str = "stdm"):
        """Add the step's systems to `builder`; returns (input ports [state, action, (features)], next_state port)."""
        from pydrake.systems.primitives import Multiplexer, MultilayerPerceptron, PerceptronActivationType
        model = self.model
        n, m, k = model.joints, model.action_dim, model.feature_width
        sizes = [2 * n, m] + ([k] if k else [])
        joined = builder.AddNamedSystem(f"{name}_inputs", Multiplexer(sizes))
        standardize = builder.AddNamedSystem(f"{name}_standardize", _static_affine(model.input_map, model.input_offset))
        builder.Connect(joined.get_output_port(), standardize.get_input_port())
        hidden = {"tanh": PerceptronActivationType.kTanh, "relu": PerceptronActivationType.kReLU}[model.activation]
        head = model.members[0].layers[-1].weight.shape[0]
        outputs = builder.AddNamedSystem(f"{name}_outputs", Multiplexer([sum(sizes)] + [head] * len(model.members)))
        builder.Connect(joined.get_output_port(), outputs.get_input_port(0))
        for index, member in enumerate(model.members):
            source = standardize.get_output_port()
            for number, layer in enumerate(member.layers):     # one single-layer perceptron per layer (docstring)
                last = number == len(member.layers) - 1
                perceptron = builder.AddNamedSystem(f"{name}_member{index}_layer{number}", MultilayerPerceptron(
                    [layer.weight.shape[1], layer.weight.shape[0]], [PerceptronActivationType.kIdentity if last else hidden]))
                builder.Connect(source, perceptron.get_input_port())
                source = perceptron.get_output_port()
                self.perceptrons.append((perceptron, layer))
            builder.Connect(source, outputs.get_input_port(index + 1))
        assemble = builder.AddNamedSystem(f"{name}_structure", _static_affine(model.output_map, model.output_offset))
        builder.Connect(outputs.get_output_port(), assemble.get_input_port())
        return [joined.get_input_port(i) for i in range(len(sizes))], assemble.get_output_port()

    def set_parameters(self, root_system, root_context) -> None:
        """Put every perceptron's weights into `root_context` (a context of `root_system`, the built diagram)."""
        for perceptron, layer in self.perceptrons:
            context = perceptron.GetMyMutableContextFromRoot(root_context)
            perceptron.SetWeights(context, 0, np.asfortranarray(layer.weight))
            perceptron.SetBiases(context, 0, layer.bias)


def _static_affine(matrix: np.ndarray, offset: np.ndarray):
    """y = matrix u + offset: a stateless AffineSystem (direct feedthrough only)."""
    from pydrake.systems.primitives import AffineSystem
    rows, columns = matrix.shape
    return AffineSystem(np.zeros((0, 0)), np.zeros((0, columns)), np.zeros(0), np.zeros((rows, 0)), matrix, offset)


def build_step_diagram(model: NativeModelFile):
    """(diagram, native): the feedthrough step x_{k+1} = f(x_k, τ_k[, φ_k]) with input ports "state", "action"
    (and the feature input) and output port "next_state"."""
    from pydrake.systems.framework import DiagramBuilder
    builder = DiagramBuilder()
    native = NativeModel(model)
    inputs, output = native.add_to(builder)
    for port, name in zip(inputs, ["state", "action", model.feature_input]):
        builder.ExportInput(port, name)
    builder.ExportOutput(output, "next_state")
    return builder.Build(), native


def build_dynamics_diagram(model: NativeModelFile):
    """(diagram, native): the discrete-time system x_{k+1} = f(x_k, τ_k) every sample period, input port "action"
    (held over the period), output port "state"; its state is a `ZeroOrderHold`'s (x_k, updated to f(x_k, τ_k) at t_k), set the initial state
    with `set_initial_state`. Models with feature inputs need the features computed from the state: refused."""
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ZeroOrderHold
    if model.feature_width:
        raise InputError(f"a model with {model.feature_input!r} inputs needs them computed from the state at every "
                         "step: use build_step_diagram and feed them")
    builder = DiagramBuilder()
    native = NativeModel(model)
    (state, action), output = native.add_to(builder)
    delay = builder.AddNamedSystem("state_memory", ZeroOrderHold(model.sample_period, 2 * model.joints))
    builder.Connect(output, delay.get_input_port())
    builder.Connect(delay.get_output_port(), state)
    builder.ExportInput(action, "action")
    builder.ExportOutput(delay.get_output_port(), "state")
    native.delay = delay
    return builder.Build(), native


def set_initial_state(native: NativeModel, root_context, x0) -> None:
    """The dynamics diagram's state x_0 = [q rad, v rad/s] (2n,) at the start of `root_context`."""
    native.delay.SetVectorState(native.delay.GetMyMutableContextFromRoot(root_context), np.asarray(x0, dtype=float))
