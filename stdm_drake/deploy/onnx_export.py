"""A checkpoint as two ONNX files: the model (raw inputs -> next state, everything between them in the graph)
and its Jacobians (for a C++ MPC), with units, the sample period and the feature recipe in their metadata.

For a robot of n joints and m actuated ones, every graph takes float32 rows (batch N, any size):
    "state"   x_k = [q (n) rad, v (n) rad/s]                      (N, 2n)
    "action"  τ_k (m) N m, held over [t_k, t_k + sample period)    (N, m)
    and, for a model whose network sees physics features, one more input (`FEATURE_INPUTS`):
    "nominal_acceleration" (N, n) rad/s², "period_acceleration" (N, n) rad/s² or "plant_next_state" (N, 2n),
    computed by the robot's nominal model as the metadata's "features" says (the graph holds the network, not
    the rigid-body dynamics).
The model graph (`model_graph`) returns "next_state" (N, 2n), the ensemble mean, and for an ensemble or a
probabilistic model "next_state_variance" (N, 2n) (member spread + mean aleatoric variance, rad², rad²/s²) and
"member_next_state" (E, N, 2n) (each member's mean, for trajectory sampling). The Jacobian graph
(`jacobian_graph`) returns "next_state" and d next_state / d state "jacobian_state" (N, 2n, 2n), d / d action
"jacobian_action" (N, 2n, m) and, with features, d / d features "jacobian_features" (N, 2n, k): the chain rule
through the features is the caller's (the Jacobian of φ comes from the same rigid-body library).
The structure's output map is in the graph: the delta x_k + f (or v_k + f), and for velocity-structured models
the trapezoid q_{k+1} = q_k + T (v_k + v_{k+1}) / 2.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.files import path_text
from stdm_drake.deploy.onnx_graph import GraphBuilder, NetworkArrays, network_jacobian, network_outputs, tensor_info
from stdm_drake import __version__
from stdm_drake.learning.models import EnsembleMLP

BATCH = "batch"
# structure inputs -> (graph input name, values per joint, unit, how to compute it)
FEATURE_INPUTS = {
    "nominal_acceleration": ("nominal_acceleration", 1, "rad/s²",
                             "q̈ = M(q)⁻¹(B τ + τ_g(q) − C(q, v) v − D v) of the robot's description (continuous time, "
                             "forward dynamics at (q, v, τ); stdm_drake.dynamics.physics.NominalAcceleration)"),
    "period_acceleration": ("period_acceleration", 1, "rad/s²",
                            "the description's mean acceleration over one sample period T, linearized at (x, τ): "
                            "[Ψ f]_v / T with f = [v, q̈], Ψ = ∫_0^T exp(A_c s) ds, A_c = ∂f/∂x "
                            "(stdm_drake.dynamics.physics.PeriodAcceleration)"),
    "plant_step": ("plant_next_state", 2, "[q̂ (n) rad, v̂ (n) rad/s]",
                   "the plant model's next state x̂_{k+1} from (x_k, τ_k) over one sample period "
                   "(stdm_drake.dynamics.plant_step.PlantStep)"),
}


@dataclasses.dataclass(frozen=True)
class ExportLayout:
    """How the graph inputs [state (2n), action (m), features (k)] become the network's input row (`order`:
    the columns of that concatenation in the network's order) and what the output map is."""
    joints: int
    action_dim: int
    feature_width: int
    order: np.ndarray
    predicts: str
    sample_period: float

    @classmethod
    def of(cls, structure, state_dim: int, action_dim: int, sample_period: float) -> "ExportLayout":
        n = state_dim // 2
        k = 0 if structure.inputs == "raw" else FEATURE_INPUTS[structure.inputs][1] * n
        columns = np.arange(2 * n + action_dim + k)[None]        # the network's order of them: the structure's own split
        state, action, features = columns[:, :2 * n], columns[:, 2 * n:2 * n + action_dim], columns[:, 2 * n + action_dim:]
        order = np.hstack(structure.split(state, action, features if k else None))[0]
        return cls(n, action_dim, k, order, structure.predicts, sample_period)

    @property
    def width(self) -> int:
        return 2 * self.joints + self.action_dim + self.feature_width

    @property
    def permutation(self) -> np.ndarray:
        """(K, W): network input row = permutation @ [state; action; features]."""
        matrix = np.zeros((len(self.order), self.width))
        matrix[np.arange(len(self.order)), self.order] = 1.0
        return matrix


def _network_inputs(b: GraphBuilder, layout: ExportLayout, names: list) -> str:
    joined = b.op("Concat", names, "model_inputs", axis=1) if len(names) > 1 else names[0]
    return b.op("Gather", [joined, b.constant(layout.order, "network_order", np.int64)], "network_inputs", axis=1)


def _assembled(b: GraphBuilder, layout: ExportLayout, output: str, axis: int) -> str:
    """The next state from the network's (delta-added) output: itself ("state") or [q + T (v + v̂) / 2, v̂]."""
    if layout.predicts == "state":
        return output
    n, half = layout.joints, 0.5 * layout.sample_period
    q, v = b.columns("state", 0, n, 1, "q"), b.columns("state", n, 2 * n, 1, "v")
    angle = b.op("Add", [q, b.op("Mul", [b.op("Add", [v, output]), b.constant(half, "half_period")])], "next_angle")
    return b.op("Concat", [angle, output], "assembled", axis=axis)


def _inputs(layout: ExportLayout, structure) -> tuple[list, list]:
    n, m = layout.joints, layout.action_dim
    infos = [tensor_info("state", [BATCH, 2 * n], f"x_k = [q ({n}) rad, v ({n}) rad/s]"),
             tensor_info("action", [BATCH, m], f"joint torques τ_k ({m}) N m, held over one sample period")]
    names = ["state", "action"]
    if layout.feature_width:
        name, _, unit, recipe = FEATURE_INPUTS[structure.inputs]
        infos.append(tensor_info(name, [BATCH, layout.feature_width], f"{unit}: {recipe}"))
        names.append(name)
    return infos, names


def model_graph(net: NetworkArrays, layout: ExportLayout, structure, metadata: dict, *, mean_only: bool = False):
    """The model graph (module docstring) of network `net` laid out by `layout`; mean_only: "next_state" alone, no
    variance or member outputs (ONNX Runtime runs every node of a graph whatever outputs a call asks for)."""
    b = GraphBuilder()
    inputs, names = _inputs(layout, structure)
    member_outputs, residual, variances = network_outputs(b, _network_inputs(b, layout, names), net)
    size, single = 2 * layout.joints, net.members == 1
    member_mean = None if single else b.op("ReduceMean", [member_outputs], "ensemble_output", axes=[0], keepdims=1)
    mean = member_outputs if single else b.op("Squeeze", [member_mean, b.constant([0], "axis", np.int64)])
    if residual is not None:
        mean = b.op("Add", [mean, residual], "ensemble_output_delta")
    b.op("Identity", [_assembled(b, layout, mean, axis=1)], output="next_state")
    outputs = [tensor_info("next_state", [BATCH, size], "x_{k+1}: the ensemble mean, [q rad, v rad/s]")]
    if (not single or variances is not None) and not mean_only:
        if single:          # one network: no spread, its own variance
            total = variances
            members = b.op("Unsqueeze", [mean, b.constant([0], "axis", np.int64)], "member_output")
        else:
            deviation = b.op("Sub", [member_outputs, member_mean])
            total = b.op("ReduceMean", [b.op("Mul", [deviation, deviation])], "spread", axes=[0], keepdims=0)
            if variances is not None:
                total = b.op("Add", [total, b.op("ReduceMean", [variances], axes=[0], keepdims=0)], "total_variance")
            members = member_outputs if residual is None else b.op("Add", [member_outputs, residual], "member_output")
        if layout.predicts == "velocity":      # the angle's variance: (T/2)² the velocity's
            total = b.op("Concat", [b.op("Mul", [total, b.constant((0.5 * layout.sample_period) ** 2, "factor")]),
                                    total], "assembled_variance", axis=1)
        b.op("Identity", [total], output="next_state_variance")
        b.op("Identity", [_assembled(b, layout, members, axis=2)], output="member_next_state")
        outputs += [tensor_info("next_state_variance", [BATCH, size],
                                "predictive variance: spread of the member means + mean aleatoric variance (rad², rad²/s²)"),
                    tensor_info("member_next_state", [net.members, BATCH, size], "each member's mean next state")]
    return b.model(inputs, outputs, name="stdm_model", doc=metadata["description"], metadata=metadata)


def jacobian_graph(net: NetworkArrays, layout: ExportLayout, structure, metadata: dict):
    """The Jacobian graph (module docstring): next state and its Jacobians d/d[state, action, features]."""
    b = GraphBuilder()
    inputs, names = _inputs(layout, structure)
    mean, network = network_jacobian(b, _network_inputs(b, layout, names), net)   # (N, out), (N, out, K)
    jacobian = b.op("MatMul", [network, b.constant(layout.permutation, "input_order")], "output_jacobian")   # (N, out, W)
    n, size = layout.joints, 2 * layout.joints
    if layout.predicts == "velocity":
        half = 0.5 * layout.sample_period
        angle_rows = np.zeros((n, layout.width))
        angle_rows[:, :n], angle_rows[:, n:size] = np.eye(n), half * np.eye(n)
        angle = b.op("Add", [b.op("Mul", [jacobian, b.constant(half, "half_period")]),
                             b.constant(angle_rows, "trapezoid")], "angle_jacobian")
        jacobian = b.op("Concat", [angle, jacobian], "state_jacobian", axis=1)
    b.op("Identity", [_assembled(b, layout, mean, axis=1)], output="next_state")
    parts = [("jacobian_state", 0, size, "d next_state / d state"),
             ("jacobian_action", size, size + layout.action_dim, "d next_state / d action (rad or rad/s per N m)")]
    if layout.feature_width:
        parts.append(("jacobian_features", size + layout.action_dim, layout.width,
                      f"d next_state / d {names[2]} (chain it with the features' own Jacobian)"))
    outputs = [tensor_info("next_state", [BATCH, size], "x_{k+1}: the ensemble mean, [q rad, v rad/s]")]
    for name, start, stop, doc in parts:
        b.op("Identity", [b.columns(jacobian, start, stop, 2, f"{name}_columns")], output=name)
        outputs.append(tensor_info(name, [BATCH, size, stop - start], doc))
    return b.model(inputs, outputs, name="stdm_model_jacobian", doc=metadata["description"] + " Jacobian graph.",
                   metadata=metadata)


def export_metadata(checkpoint, layout: ExportLayout, source_sha256: str) -> dict:
    """The string metadata both graphs carry: units, the sample period, the structure and the feature recipe."""
    structure, recorded = checkpoint.structure, checkpoint.metadata
    config = checkpoint.model_config
    n = layout.joints
    values = {
        "written_by": "stdm-drake export",
        "stdm_drake_version": __version__,
        "description": (f"stdm-drake state-transition model {recorded.model_type or ''}: x_(k+1) = f(x_k, τ_k) every "
                        f"{layout.sample_period} s; {structure.label}").replace("  ", " "),
        "sample_period_s": repr(layout.sample_period),
        "state": f"[q ({n}) rad, v ({n}) rad/s]",
        "action": f"joint torques ({layout.action_dim}) N m, held over the sample period",
        "joint_names": json.dumps(recorded.joint_names or []),
        "model_type": recorded.model_type or "",
        "structure": json.dumps(structure.as_dict(), sort_keys=True),
        "network": f"{config.ensemble_size} member(s) x {config.hidden_layers}x{config.hidden_width} "
                   f"{config.activation}, {'probabilistic' if config.probabilistic else 'deterministic'}, "
                   f"{'delta' if config.residual else 'direct'}",
        "robot_name": recorded.robot_name or "",
        "robot_model_sha256": recorded.robot_model_sha256 or "",
        "checkpoint": path_text(checkpoint.path.name),
        "checkpoint_sha256": source_sha256,
    }
    if layout.feature_width:
        name, _, unit, recipe = FEATURE_INPUTS[structure.inputs]
        values["features"] = f"input {name!r} ({layout.feature_width}) {unit}: {recipe}"
        if structure.physics is not None:
            values["features"] += "; plant parameters: " + json.dumps(structure.physics, sort_keys=True, default=str)
    return values


def checkpoint_graphs(checkpoint, *, mean_only: bool = False):
    """(model graph, Jacobian graph, feature note or None) of a loaded checkpoint (mean_only: `model_graph`'s);
    InputError for a network the ONNX export does not represent (another registered network kind than the ensemble
    MLP)."""
    if type(checkpoint.model) is not EnsembleMLP:   # (a subclass kind may compute otherwise)
        raise InputError(f"{checkpoint.path}: a {checkpoint.model.kind!r} network cannot be exported to ONNX "
                         "(the export represents stdm-drake's ensemble MLP)")
    state_dim, action_dim = checkpoint.model_sizes
    layout = ExportLayout.of(checkpoint.structure, state_dim, action_dim, checkpoint.sample_period)
    metadata = export_metadata(checkpoint, layout, hashlib.sha256(checkpoint.path.read_bytes()).hexdigest())
    net = NetworkArrays.from_network(checkpoint.model)
    note = metadata.get("features")
    return (model_graph(net, layout, checkpoint.structure, metadata, mean_only=mean_only),
            jacobian_graph(net, layout, checkpoint.structure, metadata), note)
