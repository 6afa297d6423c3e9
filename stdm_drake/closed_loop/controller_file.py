"""The MPC controller as a file for the compiled controller outside Python (`stdm-drake export --target controller`,
`export_controller`; the C++ reader and program: closed_loop/core/controller.hpp, mpc_controller.cpp).

What the file holds (text; its first line `# stdm-drake controller 1 ...`, then one entry per line,
`array NAME ROWS COLS values...` row-major or `text NAME VALUE`), for n joints, m actuated, S = 2n:

    text model              "network" (an ensemble MLP `train` wrote) or "plant" (the plant as model, RK4)
    state_dim, action_dim   S and m
    sample_period           s; the controller's period
    horizon, iterations, jacobian_refresh, regularization, terminal_factor, disturbance_gain
                            the MPC settings (`closed_loop.mpc.MpcConfig`, `rti.Rti`; jacobian_refresh 0: all)
    Q (S,), R (m,)          the tracking cost's diagonals
    effort_limit (m,)       N m: the torque box
    constrained, hard, lower (S,), upper (S,), penalty_weight
                            the state limits of `constraints:` (their bounds: the plant's limits moved inside by the
                            margins; constrained 0 is mode off: torques clipped after the step)
    network                 members, hidden_layers, residual, text activation, predicts_velocity, nominal (the
                            nominal acceleration among its inputs), first.E (K+1, W), hidden_weight.L.E (W, W),
                            hidden_bias.L.E (1, W), mean_weight.E (W, outputs), mean_bias.E (1, outputs): the float32
                            inference copy (`predict.InferenceModel`: normalizers folded in)
    substeps                the plant model's RK4 steps per period
    dynamics.*              the prediction model's rigid body (the nominal acceleration's, or the plant's):
                            `compiled_core.rigid_body_arrays`
    description.*           the robot's description (the feedforward's gravity torque at the plan's states)
"""
from __future__ import annotations

import pathlib

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.files import line_text, atomic_path

from stdm_drake.outputs import CONTROLLER_MARKER as MARKER   # (the first line `outputs` recognizes)
from stdm_drake.dynamics.compiled_core import compiled_model, rigid_body_arrays
from stdm_drake.dynamics.physics import PlantModel
from stdm_drake.closed_loop.rti import Rti
from stdm_drake.dynamics.model_files import load_model, model_file_kinds
from stdm_drake.outputs import check_output_file


def _array(name: str, values) -> str:
    values = np.atleast_2d(np.asarray(values, dtype=np.float64))
    if values.ndim != 2:
        raise ValueError(f"controller entry {name}: {values.shape}")
    numbers = " ".join(repr(float(value)) for value in values.ravel())
    return f"array {name} {values.shape[0]} {values.shape[1]} {numbers}"


def _rigid_body(prefix: str, arrays: dict) -> list[str]:
    return [_array(prefix + name, value if name not in ("friction", "friction_scale") else np.reshape(value, (1, -1)))
            for name, value in arrays.items()]


def controller_text(model, config, robot, written_by: str = "stdm-drake export") -> str:
    """The controller file of `model` (a checkpoint's `LearnedModel` or a `PlantModel`) under the MPC settings
    `config` (`MpcConfig`) for `robot` (its plant's limits, its description's gravity); InputError for a model the
    compiled controller does not cover (`compiled_core.compiled_model`)."""
    from stdm_drake.robots.plant import Dynamics, joint_limits   # lazy: pydrake
    from stdm_drake.robots.rigid_body import robot_dynamics   # lazy: pydrake
    config.validate()
    core, why_not = compiled_model(model)
    if core is None:
        raise InputError(f"the compiled controller does not cover {why_not}")
    if not isinstance(config.optimizer, Rti):   # (the samplers have an `implementation` too: of their model steps)
        raise InputError(f"the compiled controller runs the real-time iteration (`optimizer: !Rti {{}}`), not "
                         f"!{type(config.optimizer).__name__}")
    limits = joint_limits(Dynamics(robot).plant)
    bounds = config.constraints.bounds(limits.position_lower, limits.position_upper, limits.velocity, robot.joint_names)
    cost = config.cost(len(limits.effort))
    S = model.state_dim
    lines = [f"{MARKER} (written by {written_by}; stdm_drake/closed_loop/controller_file.py documents the entries)",
             "text model " + ("plant" if isinstance(model, PlantModel) else "network")]
    scalars = dict(state_dim=S, action_dim=model.action_dim, sample_period=model.sample_period,
                   horizon=config.horizon, iterations=config.optimizer.iterations,
                   jacobian_refresh=config.optimizer.refresh_count(),
                   regularization=config.optimizer.regularization, terminal_factor=cost.terminal_factor,
                   disturbance_gain=config.disturbance_gain, constrained=int(bounds is not None),
                   hard=int(bounds is not None and bounds.hard),
                   penalty_weight=bounds.penalty_weight if bounds is not None else 1.0)
    lines += [_array(name, value) for name, value in scalars.items()]
    lines += [_array("Q", np.diag(cost.Q)), _array("R", np.diag(cost.R)), _array("effort_limit", limits.effort),
              _array("lower", bounds.lower if bounds is not None else np.full(S, -np.inf)),
              _array("upper", bounds.upper if bounds is not None else np.full(S, np.inf))]
    if isinstance(model, PlantModel):
        lines.append(_array("substeps", model.substeps))
        lines += _rigid_body("dynamics.", rigid_body_arrays(model.dynamics))
    else:
        engine = model.engine
        lines += [_array("members", engine.ensemble_size), _array("hidden_layers", len(engine.hidden)),
                  _array("residual", int(engine.residual)), f"text activation {engine.config.activation}",
                  _array("predicts_velocity", int(model.structure.predicts == "velocity")),
                  _array("nominal", int(model.features is not None))]
        for e in range(engine.ensemble_size):
            lines.append(_array(f"first.{e}", engine.input_member_weight[e]))
            lines.append(_array(f"mean_weight.{e}", engine.mean_weight[e]))
            lines.append(_array(f"mean_bias.{e}", engine.mean_bias[e]))
            for layer, (weight, bias) in enumerate(engine.hidden):
                lines.append(_array(f"hidden_weight.{layer}.{e}", weight[e]))
                lines.append(_array(f"hidden_bias.{layer}.{e}", bias[e]))
        if model.features is not None:
            lines += _rigid_body("dynamics.", rigid_body_arrays(model.features.dynamics))
    lines += _rigid_body("description.", rigid_body_arrays(robot_dynamics(robot)))
    return "\n".join(lines) + "\n"


def export_controller(checkpoint: pathlib.Path, output: pathlib.Path, robot_config: pathlib.Path | None = None,
                      mpc_config: pathlib.Path | None = None, force: bool = False, say=print) -> pathlib.Path:
    """`export --target controller`: the controller file of a `train` checkpoint (.pt) for the robot config
    `robot_config` (None: the UR-10's) under the MPC settings `mpc_config` (None: controllers/mpc.yaml), written
    atomically to `output` (.controller); every check before any work (InputError, nothing written)."""
    from stdm_drake.closed_loop.mpc import DEFAULT_MPC_CONFIG, load_mpc_config   # lazy: pydrake
    from stdm_drake.data.compatibility import resolve_robot   # lazy: pydrake
    if pathlib.Path(output).suffix.lower() != ".controller":
        raise InputError(f"-o/--output {output}: the controller target writes a .controller file")
    inputs = [path for path in (checkpoint, robot_config, mpc_config) if path is not None]
    check_output_file("-o/--output", output, kind="controller", inputs=inputs, force=force)
    # a train checkpoint, read by the model-file registry's checkpoint kind (its one-line refusals for other files)
    loaded = next(kind for kind in model_file_kinds() if kind.name == "checkpoint").function("load")(checkpoint)
    robot = resolve_robot(robot_config, None)
    text = controller_text(load_model(loaded, robot), load_mpc_config(mpc_config or DEFAULT_MPC_CONFIG), robot)
    with atomic_path(output) as path:
        path.write_text(text)
    say(f"{line_text(loaded.path.name)} ({loaded.structure.label}, every {loaded.sample_period} s) under the MPC "
        f"settings of {line_text(mpc_config or 'controllers/mpc.yaml')} for robot {line_text(robot.name)} -> "
        f"{line_text(output)}")
    return pathlib.Path(output)
