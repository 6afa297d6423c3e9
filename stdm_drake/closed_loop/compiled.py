"""The compiled control step: the real-time iteration of `rti.py` and the limits of `constraints.py` in C++
(`closed_loop/core/control_step.hpp`, built at install as the extension module `closed_loop._core`), with the
prediction models it covers linearized there too, so that nothing returns to Python within a control step.

What it covers (`compiled_model`): the toolbox's ensemble MLPs (`predict.InferenceModel`: D, DD, DE, P, PE and
their derivative-trained twins) predicting the next state or the next velocity, on raw inputs or with the nominal
acceleration of the robot's rigid-body model (the default structure), and the robot's plant as a model with the
RK4 integrator (the MPC's plant, `PlantModel.for_control`). Other models (the grey boxes on a plant step, the
period-acceleration inputs, network kinds other than the MLP, models of a longer period made of substeps) run the
numpy step, and the solver says so (`implementation`); the MPC's outputs record which step ran.

The numpy implementation (`rti.RtiSolver`, `Rti(implementation="numpy")`) is the reference: the tests hold the
compiled step's torques equal to it (tests/test_compiled_step.py). The one place where the two may part is a QP
that does not settle within the iteration budget (`constraints.MAX_QP_ITERATIONS`): DAQP counts its active-set
changes, the compiled dual active-set method (Goldfarb & Idnani) counts its own, so the step that falls back to
the torque box alone may differ.

Rigid bodies cross as arrays (`rigid_body_arrays`): the Pinocchio model `robots.rigid_body.RigidBodyDynamics`
builds from the Drake plant, joint by joint, with the extra forces (damping, Coulomb friction) and the actuation
matrix, so the C++ side holds the same model.
"""
from __future__ import annotations

import numpy as np

from stdm_drake.closed_loop.constraints import StateBounds
from stdm_drake.closed_loop.optimizer import OptimizerResult, TrackingCost, TrajectoryOptimizer
from stdm_drake.errors import InputError

IMPLEMENTATIONS = ("compiled", "numpy")


def core_module():
    """The extension module `stdm_drake.closed_loop._core`; InputError (one line) where it was not built."""
    try:
        from stdm_drake.closed_loop import _core
    except ImportError as error:
        raise InputError(f"the compiled MPC control step is not built ({error}): reinstall the package on a machine "
                         "with a C++ compiler (pip install -e .), or set `implementation: numpy` in the MPC settings' "
                         "`optimizer: !Rti {...}`") from None
    return _core


def rigid_body_arrays(dynamics) -> dict:
    """The arguments of `_core.rigid_body` for a `robots.rigid_body.RigidBodyDynamics`: its Pinocchio model joint
    by joint (parent, RZ or PZ, placement, the joint's bodies' mass, centre of mass and rotational inertia about it),
    armature and gravity, the joint order, damping, Coulomb friction and actuation matrix."""
    model = dynamics.model
    joints = range(1, model.njoints)
    kinds = []
    for index in joints:
        name = model.joints[index].shortname()
        if name not in ("JointModelRZ", "JointModelPZ"):
            raise InputError(f"compiled control step: Pinocchio joint {name} is not revolute or prismatic about z")
        kinds.append(0 if name == "JointModelRZ" else 1)
    inertias = [model.inertias[index] for index in joints]
    friction, scale = (np.zeros(0), np.zeros(0)) if dynamics.coulomb is None else dynamics.coulomb
    return dict(parents=[int(model.parents[index]) for index in joints], kinds=kinds,
                rotations=np.array([model.jointPlacements[index].rotation.ravel() for index in joints]),
                translations=np.array([model.jointPlacements[index].translation for index in joints]),
                masses=np.array([inertia.mass for inertia in inertias]),
                centers=np.array([inertia.lever for inertia in inertias]),
                inertias=np.array([inertia.inertia.ravel() for inertia in inertias]),
                armature=np.asarray(model.armature, dtype=float), gravity=np.asarray(model.gravity.linear, dtype=float),
                to_pin=[int(i) for i in dynamics._to_pin], damping=np.asarray(dynamics.damping, dtype=float),
                friction=np.asarray(friction, dtype=float), friction_scale=np.asarray(scale, dtype=float),
                actuation=np.asarray(dynamics.actuation, dtype=float))


def _network_arguments(engine) -> dict:
    """The arguments of `_core.NetworkModel` for an MLP's numpy inference engine (`predict.InferenceModel`)."""
    members = engine.ensemble_size
    return dict(first=[engine.input_member_weight[e] for e in range(members)],
                hidden_weight=[[weight[e] for e in range(members)] for weight, _ in engine.hidden],
                hidden_bias=[[bias[e] for e in range(members)] for _, bias in engine.hidden],
                mean_weight=[engine.mean_weight[e] for e in range(members)],
                mean_bias=[engine.mean_bias[e] for e in range(members)],
                residual=bool(engine.residual), activation=str(engine.config.activation))


def compiled_model(model):
    """(the `_core` model of `model`, "") where the compiled step covers it, else (None, why not) (module
    docstring). InputError where the extension is not built."""
    core = core_module()
    from stdm_drake.dynamics.physics import PlantModel
    if isinstance(model, PlantModel):
        if model.integrator != "rk4":
            return None, "a plant model of the simulator's integrator (control uses rk4)"
        body = core.rigid_body(**rigid_body_arrays(model.dynamics))
        return core.PlantModel(body, model.sample_period, int(model.substeps)), ""
    engine, structure = getattr(model, "engine", None), getattr(model, "structure", None)
    if engine is None or structure is None:
        return None, f"a {type(model).__name__}"
    if not hasattr(engine, "input_member_weight"):
        return None, f"a network of kind {type(engine).__name__} (the compiled step runs the ensemble MLP)"
    if structure.inputs not in ("raw", "nominal_acceleration"):
        return None, f"{structure.inputs.replace('_', '-')} inputs"
    nominal = None
    if structure.inputs == "nominal_acceleration":
        nominal = core.rigid_body(**rigid_body_arrays(model.features.dynamics))
    period = model.sample_period if model.sample_period is not None else 0.0
    return core.NetworkModel(**_network_arguments(engine), state_dim=model.state_dim, action_dim=model.action_dim,
                             predicts_velocity=structure.predicts == "velocity", nominal=nominal,
                             sample_period=float(period)), ""


class CompiledRtiSolver(TrajectoryOptimizer):
    """The real-time iteration of `rti.RtiSolver` (same settings, same results) with the whole control step in
    C++; `core_model` from `compiled_model`."""
    implementation = "compiled"

    def __init__(self, model, cost: TrackingCost, effort_limit: np.ndarray, config, bounds: StateBounds | None,
                 core_model):
        super().__init__(model, cost, effort_limit, bounds)
        self.config = config
        core = core_module()
        size = self.state_dim
        lower = bounds.lower if bounds is not None else np.full(size, -np.inf)
        upper = bounds.upper if bounds is not None else np.full(size, np.inf)
        self._core = core.RealTimeIteration(
            core_model, int(config.iterations), float(config.regularization), np.diag(cost.Q).astype(float),
            np.diag(cost.R).astype(float), float(cost.terminal_factor), self.effort_limit.astype(float),
            bounds is not None, bool(bounds is not None and bounds.hard), np.asarray(lower, dtype=float),
            np.asarray(upper, dtype=float), float(bounds.penalty_weight) if bounds is not None else 1.0)

    def solve(self, x0: np.ndarray, u_init: np.ndarray, reference: np.ndarray, u_ff: np.ndarray,
              offset: np.ndarray | None = None, x_init: np.ndarray | None = None) -> OptimizerResult:
        """As `rti.RtiSolver.solve`: x0 (2n,), u_init (H, m), reference (H+1, 2n), u_ff (H, m), offset (2n,),
        x_init (H+1, 2n) or None."""
        offset = np.zeros(self.state_dim) if offset is None else np.asarray(offset, dtype=float)
        as_float = np.ascontiguousarray
        u, x, cost, iterations, finite, active, slack = self._core.solve(
            as_float(x0, dtype=float), as_float(u_init, dtype=float), as_float(reference, dtype=float),
            as_float(u_ff, dtype=float), offset, None if x_init is None else as_float(x_init, dtype=float))
        return OptimizerResult(u, x, float(cost), int(iterations), bool(finite), bool(active), float(slack))

    def control_step(self, reference: np.ndarray, feedforward: np.ndarray, horizon: int, disturbance_gain: float):
        """policy.MpcStep's step in C++ over this solver (`_core.ControlStep`): reference (T, 2n) states and
        feedforward (T, m) N m at the sample period, held past the end."""
        return core_module().ControlStep(self._core, np.ascontiguousarray(reference, dtype=float),
                                         np.ascontiguousarray(feedforward, dtype=float), int(horizon),
                                         float(disturbance_gain))


def build_controller_program(output, compiler: str = "c++") -> None:
    """Compile the controller program (core/mpc_controller.cpp: reads a controller file and a plan, then a state per
    line on standard input, writes a torque per line) to the executable `output`, with this environment's Eigen
    (cmeel-eigen), Pinocchio (its headers and libpinocchio_default) and `compiler`; InputError (one line) where the
    compiler or the headers are missing or the build fails (about a minute on 2 cores)."""
    import pathlib
    import shutil
    import subprocess
    import cmeel
    if shutil.which(compiler) is None:
        raise InputError(f"no C++ compiler ({compiler!r} not found): the controller program needs one")
    prefix = pathlib.Path(cmeel.__file__).resolve().parent.parent / "cmeel.prefix"
    if not (prefix / "include" / "eigen3").is_dir() or not (prefix / "include" / "pinocchio").is_dir():
        raise InputError(f"Eigen's or Pinocchio's headers are missing under {prefix} (pip install cmeel-eigen pin)")
    core = pathlib.Path(__file__).resolve().parent / "core"
    command = [compiler, "-std=c++17", "-O3", "-DNDEBUG", "-w", "-DPINOCCHIO_ENABLE_TEMPLATE_INSTANTIATION",
               "-DBOOST_MPL_LIMIT_LIST_SIZE=30", "-DBOOST_MPL_LIMIT_VECTOR_SIZE=30",
               "-DBOOST_MPL_CFG_NO_PREPROCESSED_HEADERS", "-DBOOST_FUSION_INVOKE_MAX_ARITY=12",
               f"-I{prefix / 'include'}", f"-I{prefix / 'include' / 'eigen3'}", str(core / "mpc_controller.cpp"),
               str(core / "rigid_body.cpp"), "-o", str(output), f"-L{prefix / 'lib'}", "-lpinocchio_default",
               f"-Wl,-rpath,{prefix / 'lib'}"]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        first = next((line for line in result.stderr.splitlines() if "error" in line), result.stderr.strip()[:200])
        raise InputError(f"the controller program did not build: {first}")
