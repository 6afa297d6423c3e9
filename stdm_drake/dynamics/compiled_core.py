"""The compiled core's models (`stdm_drake._core`, C++ in stdm_drake/core/control_step.hpp): the toolbox's models as
the core holds them, and their open-loop rollouts there.

What it covers (`compiled_model`): the toolbox's ensemble MLPs (`predict.InferenceModel`: D, DD, DE, P, PE and
their derivative-trained twins) predicting the next state or the next velocity, on raw inputs or with the nominal
acceleration of the robot's rigid-body model (the default structure), and the robot's plant as a model with the
RK4 integrator (the MPC's plant, `PlantModel.for_control`). Other models (the grey boxes on a plant step, the
period-acceleration inputs, network kinds other than the MLP, models of a longer period made of substeps) run
numpy, and say so (the MPC solver's `implementation`, `LearnedModel.rollout_implementation`).

Who uses it: `LearnedModel.rollout` ("mean" propagation: open-loop evaluation, `view`), the sampling MPC's
batched model steps (`closed_loop.sampled_costs`, `step_rows`) and the MPC's compiled control step
(`closed_loop.compiled`). It sits with the models (it reads an MLP's inference engine by its attributes and
imports nothing of learning), so learning and the closed loop both use it from below. The numpy code is the
reference, one setting away (`implementation="numpy"`), and the tests hold the two equal.

Rigid bodies cross as arrays (`rigid_body_arrays`): the Pinocchio model `robots.rigid_body.RigidBodyDynamics`
builds from the Drake plant, joint by joint, with the extra forces (damping, Coulomb friction) and the actuation
matrix, so the C++ side holds the same model.
"""
from __future__ import annotations

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.dynamics.physics import PlantModel

IMPLEMENTATIONS = ("compiled", "numpy")


def core_module():
    """The extension module `stdm_drake._core`; InputError (one line) where it was not built."""
    try:
        from stdm_drake import _core   # lazy: the compiled extension, absent where its build failed
    except ImportError as error:
        raise InputError(f"the compiled core is not built ({error}): reinstall the package on a machine with a C++ "
                         "compiler (pip install -e .), or choose implementation numpy (the MPC settings' `optimizer: "
                         "!Rti {implementation: numpy}` or a sampler's `implementation: numpy`; evaluate "
                         "--implementation numpy)") from None
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
            raise InputError(f"compiled core: Pinocchio joint {name} is not revolute or prismatic about z")
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
    """The arguments of `_core.NetworkModel` for an MLP's numpy inference engine (`predict.InferenceModel`), the
    variance head of probabilistic members included."""
    members = engine.ensemble_size
    head = {}
    if engine.probabilistic:
        head = dict(variance_weight=[engine.logvar_weight[e] for e in range(members)],
                    variance_bias=[engine.logvar_bias[e].reshape(1, -1) for e in range(members)],
                    min_logvar=np.reshape(engine.min_logvar, (members, -1)),
                    max_logvar=np.reshape(engine.max_logvar, (members, -1)),
                    log_output_variance=np.ravel(engine.log_output_variance))
    return dict(**head, first=[engine.input_member_weight[e] for e in range(members)],
                hidden_weight=[[weight[e] for e in range(members)] for weight, _ in engine.hidden],
                hidden_bias=[[bias[e] for e in range(members)] for _, bias in engine.hidden],
                mean_weight=[engine.mean_weight[e] for e in range(members)],
                mean_bias=[engine.mean_bias[e] for e in range(members)],
                residual=bool(engine.residual), activation=str(engine.config.activation))


def compiled_model(model):
    """(the `_core` model of `model`, "") where the compiled core covers it, else (None, why not) (module
    docstring). InputError where the extension is not built."""
    core = core_module()
    if isinstance(model, PlantModel):
        if model.integrator != "rk4":
            return None, "a plant model of the simulator's integrator (control uses rk4)"
        body = core.rigid_body(**rigid_body_arrays(model.dynamics))
        return core.PlantModel(body, model.sample_period, int(model.substeps)), ""
    engine, structure = getattr(model, "engine", None), getattr(model, "structure", None)
    if engine is None or structure is None:
        return None, f"a {type(model).__name__}"
    if not hasattr(engine, "input_member_weight"):
        return None, f"a network of kind {type(engine).__name__} (the compiled core runs the ensemble MLP)"
    if structure.inputs not in ("raw", "nominal_acceleration"):
        return None, f"{structure.inputs.replace('_', '-')} inputs"
    nominal = None
    if structure.inputs == "nominal_acceleration":
        nominal = core.rigid_body(**rigid_body_arrays(model.features.dynamics))
    period = model.sample_period if model.sample_period is not None else 0.0
    return core.NetworkModel(**_network_arguments(engine), state_dim=model.state_dim, action_dim=model.action_dim,
                             predicts_velocity=structure.predicts == "velocity", nominal=nominal,
                             sample_period=float(period)), ""


def compiled_rollout(core_model, x0: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Open-loop "mean" rollout of a `_core.NetworkModel`: x0 (B, S), actions (B, T, m) -> mean and variance
    (B, T, S) of steps 1..T (NaN from the step after a state left the finite numbers)."""
    batch, steps, width = actions.shape
    mean, variance = core_model.rollout(np.ascontiguousarray(x0, dtype=float),
                                        np.ascontiguousarray(actions, dtype=float).reshape(batch * steps, width), steps)
    return mean.reshape(batch, steps, -1), variance.reshape(batch, steps, -1)
