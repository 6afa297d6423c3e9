"""Model predictive control of a robot arm (any robot config: the UR-10 by default), any prediction model.

The optimizer is a tagged value of the settings (`optimizer: !Rti {...}` in controllers/mpc.yaml; the Union
`OptimizerConfig` lists those a file may name, each settings class builds its solver): the default is the real-time
iteration (`rti.Rti`: one multiple-shooting Gauss-Newton step per control step on the model's Jacobians, every node
linearized in one batched call, in C++ by default: `compiled`); the iLQR (`ilqr.Ilqr`: single shooting with a line
search) and the sampling optimizers iCEM, MPPI and CEM (`sampling`) are the others; any `optimizer.TrajectoryOptimizer`
can replace them. The gradient-based default: the learned models are smooth, their Jacobians cost one pass, and
derivative training is what makes those Jacobians right, so the controller uses what the method improves; the sampling
optimizers need no Jacobian and serve models without one (how they compare on learned models: docs/sampling_mpc.md); and
the plant itself is the reference model (its dynamics in RK4 steps, exact Jacobians: `PlantModel(integrator="rk4")`).

Cost over the horizon H (k = 0..H-1, reference r from a planner, u_ff = g(q_ref) the static
gravity torque at the reference):
    sum_k (x_k+1 - r_k+1)^T Q (x_k+1 - r_k+1) + (u_k - u_ff,k)^T R (u_k - u_ff,k),
with the last state term weighted by `terminal_factor`, plus the exact penalty of the predicted states'
crossings of the robot's position and velocity limits; the torques stay within their effort limits as hard
constraints of every optimizer's problem (`constraints`: the settings' `constraints:` block, soft by default;
`mode: off` clips the torques of an unconstrained step instead). The first torque is applied, the rest warm-starts the next
solve; by default one iteration per control step (the real-time iteration: with the warm start, more
iterations changed the closed-loop tracking by less than 0.5 %).

Offset-free MPC: every prediction over the horizon is shifted by a disturbance estimate d, the model's latest one-step
error x_k - f(x_k-1, u_k-1) (filtered by `disturbance_gain`), so a model's slowly varying bias does not become a
tracking error. For the plant as model d is ~0.

Every prediction model is a `DynamicsModel` (`dynamics.model`) with its `sample_period` (s); the optimizers call its
one-row `step_single` and its batched `linearize(x (H, 2n), u (H, m)) -> (x_next (H, 2n), A (H, 2n, 2n), B (H, 2n, m))`;
a model with only `step` and `jacobians` gets both from those.

Modules: the tracking cost and the optimizer interfaces (`optimizer`), the robot's limits as constraints and their QPs
(`constraints`), the optimizers and their settings (`rti`, `compiled`, `ilqr`, `sampling`), these settings, this
controller and its closed loop (here), the comparison of prediction models (`comparison`), the setting each model is
tuned to (`tuning`) and the study `stdm-drake mpc` runs (`study`); the plant as a prediction model is
`dynamics.physics.PlantModel`."""
import dataclasses
import inspect
import pathlib
import time
import typing

import numpy as np
import yaml
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from stdm_drake.closed_loop.constraints import Constraints
from stdm_drake.closed_loop.ilqr import Ilqr
from stdm_drake.closed_loop.optimizer import (LINEARIZATION_STEPS, MAX_WORK_PER_STEP, OptimizerSettings, TrackingCost,
                                              TrajectoryOptimizer)
from stdm_drake.closed_loop.policy import MpcStep, StepMemory
from stdm_drake.closed_loop.push import JointPush, add_push
from stdm_drake.closed_loop.rti import Rti
from stdm_drake.closed_loop.sampling import Cem, Icem, Mppi, SamplingSettings
from stdm_drake.config import YAML_LOADER, check_joint_vector, load_yaml_config, read_yaml_document
from stdm_drake.errors import InputError
from stdm_drake.paths import CONTROLLERS_DIR
from stdm_drake.robots.effect_systems import TorqueNoise, actuation_input, measured_state_output, start_actuators
from stdm_drake.robots.plant import Dynamics, JointLimits, PlantConfig, joint_limits, make_plant
from stdm_drake.robots.robot import Robot
from stdm_drake.robots.simulation_errors import simulation_errors

DEFAULT_MPC_CONFIG = CONTROLLERS_DIR / "mpc.yaml"
MAX_WEIGHT = 1e12      # a cost weight (and the terminal factor) beyond this swamps every other term
MIN_WEIGHT = 1e-12     # the smallest position weight that makes the controller track (1e-320 is 0 in all but name)
MAX_HORIZON = 1000     # sample periods predicted per control step (10 s at 0.01 s): more is a run that does not end

# The optimizers a settings file may name, each by its class's tag (`optimizer: !Rti {...}`), the first the
# default: a new optimizer is one `OptimizerSettings` class added here.
OptimizerConfig = typing.Union[Rti, Ilqr, Icem, Mppi, Cem]
OPTIMIZER_TAGS = tuple(f"!{cls.__name__}" for cls in typing.get_args(OptimizerConfig))
SAMPLER_TAGS = tuple(cls.__name__ for cls in typing.get_args(OptimizerConfig) if issubclass(cls, SamplingSettings))


@dataclasses.dataclass
class MpcConfig:
    """MPC settings (controllers/mpc.yaml).

    optimizer: the optimizer and its own settings, a tagged value (`!Rti {iterations, regularization}`, the
    real-time iteration, the default; `!Ilqr {max_iterations, line_search, regularization}`, single shooting
    line-searched: for horizons beyond the RTI's dense system; in code any `OptimizerSettings`);
    position_weight (n) 1/rad^2, velocity_weight (n) s^2/rad^2, effort_weight (n) 1/(N m)^2 on the torque
    beyond the reference's gravity torque (one per joint, or one for all); horizon in sample periods;
    disturbance_gain in [0, 1]: observer gain of the offset-free disturbance estimate (0 = off);
    constraints: how the optimizer keeps the robot's limits (`constraints.Constraints`: torque box hard, position
    and velocity limits soft inside margins, by default; `mode: off` clips torques after an unconstrained step).
    """
    optimizer: OptimizerConfig = dataclasses.field(default_factory=Rti)
    horizon: int = 20
    position_weight: list[float] = dataclasses.field(default_factory=lambda: [1e4] * 6)
    velocity_weight: list[float] = dataclasses.field(default_factory=lambda: [10.0] * 6)
    effort_weight: list[float] = dataclasses.field(default_factory=lambda: [1e-4, 1e-4, 1e-3, 0.1, 1.0, 100.0])
    terminal_factor: float = 10.0
    disturbance_gain: float = 1.0
    constraints: Constraints = dataclasses.field(default_factory=Constraints)

    def validate(self) -> None:
        """InputError for settings no controller can use: weights negative, not finite or beyond MAX_WEIGHT
        (the squared errors they weigh overflow, and the other terms vanish beside them), position weights all
        zero, effort weights not positive, a terminal factor outside [0, MAX_WEIGHT], an observer gain outside
        [0, 1], a horizon outside 1..MAX_HORIZON sample periods, an optimizer that is none, and the optimizer's
        own settings (its `validate`) and the constraints' (`Constraints.validate`)."""
        for name in ("position_weight", "velocity_weight", "effort_weight"):
            weights = check_joint_vector(f"mpc {name}", getattr(self, name), nonnegative=True)
            if np.any(weights > MAX_WEIGHT):
                raise InputError(f"mpc {name} must be at most {MAX_WEIGHT:g}, got {getattr(self, name)}")
        if not np.any(np.asarray(self.position_weight, dtype=float) >= MIN_WEIGHT):   # (1e-320: zero in all but name)
            raise InputError(f"mpc position_weight must be at least {MIN_WEIGHT:g} for at least one joint (all zero: the "
                             "controller would not track the plan's positions)")
        if np.any(np.asarray(self.effort_weight) <= 0):
            raise InputError("mpc effort_weight must be > 0 for every joint (the torque problem must be convex)")
        if not (np.isfinite(self.terminal_factor) and 0.0 <= self.terminal_factor <= MAX_WEIGHT):
            raise InputError(f"mpc terminal_factor must be in [0, {MAX_WEIGHT:g}], got {self.terminal_factor}")
        if not 0.0 <= self.disturbance_gain <= 1.0:
            raise InputError(f"mpc disturbance_gain must be in [0, 1], got {self.disturbance_gain}")
        if not 1 <= self.horizon <= MAX_HORIZON:
            raise InputError(f"mpc horizon must be in 1..{MAX_HORIZON} sample periods, got {self.horizon}")
        if not isinstance(self.optimizer, OptimizerSettings):
            raise InputError(f"mpc optimizer must be one of {', '.join(OPTIMIZER_TAGS)} (an OptimizerSettings), got "
                             f"{self.optimizer!r}")
        self.optimizer.validate()
        self.optimizer.check_horizon(self.horizon)
        work = self.optimizer.work_per_step(self.horizon)
        if work > MAX_WORK_PER_STEP:
            raise InputError(f"mpc optimizer !{type(self.optimizer).__name__} over horizon {self.horizon} would evaluate "
                             f"about {work:.3g} model steps per control step"
                             + ("" if hasattr(self.optimizer, "samples") else
                                f" (a node's linearization counted as {LINEARIZATION_STEPS})") + f", beyond the budget of {MAX_WORK_PER_STEP:.0e}: fewer samples, iterations or "
                             "particles, or a shorter horizon")
        if not isinstance(self.constraints, Constraints):
            raise InputError(f"mpc constraints must be a mapping of mode, position_margin, velocity_margin and "
                             f"penalty_weight, got {self.constraints!r}")
        self.constraints.validate()

    def cost(self, joints: int) -> TrackingCost:
        """The tracking cost of these weights for `joints` joints (one weight each, or one for all)."""
        weight = {name: check_joint_vector(f"mpc {name}", getattr(self, name), count=joints, nonnegative=True)
                  for name in ("position_weight", "velocity_weight", "effort_weight")}
        return TrackingCost.from_weights(weight["position_weight"], weight["velocity_weight"],
                                         weight["effort_weight"], self.terminal_factor)

    def solver(self, model, limits: JointLimits, names=None) -> TrajectoryOptimizer:
        """The optimizer these settings name, for `model` and a robot of these `limits` (`plant.joint_limits`:
        its effort limits the torque box, its position and velocity limits the state bounds of `constraints`;
        names: the joints', for messages)."""
        bounds = self.constraints.bounds(limits.position_lower, limits.position_upper, limits.velocity, names)
        return self.optimizer.solver(model, self.cost(len(limits.effort)), limits.effort, self.horizon, bounds)

    def record(self) -> dict:
        """What an output records of these settings: their fields, the optimizer's with its tag as "type"."""
        return dict(dataclasses.asdict(self), optimizer=self.optimizer.record())

    @classmethod
    def derived_for(cls, robot: Robot) -> "MpcConfig":
        """Settings for a robot without an MPC file: controllers/mpc.yaml's, with the effort weights given
        by the power law that fits that file's hand-tuned UR-10 weights against each joint's effective
        inertia at home, M_eff,i = 1 / (M^-1)_ii (log-log least squares over the 6 joints:
        R_i = 7.8e-4 M_eff,i^-1.4, within a factor of 2 of every UR-10 weight)."""
        config = load_mpc_config(DEFAULT_MPC_CONFIG)
        weights = 7.8e-4 * Dynamics(robot).effective_inertia(robot.home) ** -1.4
        return dataclasses.replace(config, effort_weight=[float(f"{w:.3g}") for w in weights])


def load_mpc_config(path=DEFAULT_MPC_CONFIG) -> MpcConfig:
    """The MPC settings of a YAML file (`MpcConfig`; InputError, one line, for the layout before the optimizer's tag,
    naming the tagged value to write, and for constraint settings the optimizer would not use)."""
    _check_optimizer_layout(path)
    config = load_yaml_config(path, MpcConfig, what="MPC config")
    config.constraints.check_used(path, config.optimizer, hard_capable=isinstance(config.optimizer, Rti))
    return config


OLD_OPTIMIZER_KEYS = ("max_iterations", "line_search", "regularization")   # top-level keys before the tag


def _check_optimizer_layout(path) -> None:
    """InputError naming the tagged `optimizer:` to write when the file at `path` sets the optimizer the old
    way (its name as a plain value, its settings at the top level), names an unknown tag or gives a tag no
    mapping (Drake's typed load would read a plain value into the default optimizer's first field); and for a
    sampler's particle settings that its mean propagation would ignore."""
    document = read_yaml_document(path)
    if not isinstance(document, dict):
        return   # (missing, unreadable, not a mapping: the typed load says why)
    node = next((value for key, value in yaml.compose(pathlib.Path(path).read_text(), Loader=YAML_LOADER).value
                 if key.value == "optimizer"), None)
    tag = node.tag[1:] if node is not None and node.tag.startswith("!") else None
    if tag is not None and f"!{tag}" not in OPTIMIZER_TAGS:
        raise InputError(f"{path}: unknown optimizer !{tag}; the MPC's optimizers are {', '.join(OPTIMIZER_TAGS)} "
                         "(e.g. `optimizer: !Rti {iterations: 1}`)")
    if tag is not None and not isinstance(node, yaml.MappingNode):
        raise InputError(f"{path}: optimizer !{tag} takes its settings as a mapping: write `optimizer: !{tag} {{}}` "
                         "for its defaults")
    if tag == "Rti" and any(key.value == "max_iterations" for key, _ in node.value):
        raise InputError(f"{path}: optimizer !Rti runs a fixed number of iterations per control step: write "
                         "`iterations:` for its `max_iterations:`")
    # a sampler's particle settings with mean propagation (written or by default), which would ignore them: refused
    # at any value, their defaults too
    settings = document.get("optimizer") if tag in SAMPLER_TAGS else None
    ignored = [key for key in ("particles", "variance_weight") if key in settings] if isinstance(settings, dict) and \
        settings.get("propagation", "mean") == "mean" else []
    if tag == "Icem" and isinstance(settings, dict) and "population_decay" in settings and settings.get("iterations") == 1:
        raise InputError(f"{path}: !Icem's population_decay acts between iterations, so with iterations: 1 it is ignored")
    if ignored:
        raise InputError(f"{path}: optimizer !{tag}'s {' and '.join(ignored)} {'need' if len(ignored) > 1 else 'needs'} "
                         "`propagation: ts1` or `tsinf`; with `propagation: mean` each sample rolls out one particle (the "
                         "ensemble's mean) and would ignore them, whatever their value")
    old = [key for key in OLD_OPTIMIZER_KEYS if key in document]
    if not old and (node is None or isinstance(node, yaml.MappingNode)):
        return
    value = document.get("optimizer")
    name = tag.lower() if tag is not None else str(value if value is not None else "rti").strip().lower()
    kind = Ilqr if name == "ilqr" else Rti
    renamed = {"max_iterations": "iterations"} if kind is Rti else {}
    own = {field.name for field in dataclasses.fields(kind)}
    fields = {renamed.get(key, key): document[key] for key in old if renamed.get(key, key) in own}
    tagged = f"optimizer: !{kind.__name__} " + yaml.safe_dump(fields, default_flow_style=True, sort_keys=False).strip()
    if tag is not None:   # (the tagged value's own settings come first; the old keys fill the rest)
        fields = {**fields, **{key.value: yaml.safe_load(yaml.serialize(item)) for key, item in node.value}}
        tagged = f"optimizer: !{kind.__name__} " + yaml.safe_dump(fields, default_flow_style=True, sort_keys=False).strip()
    replaced = ", ".join(f"`{key}:`" for key in (["optimizer"] if node is not None else []) + old)
    unknown = "" if name in ("rti", "ilqr") else f" (optimizer {value!r} is none of rti, ilqr)"
    raise InputError(f"{path}: the optimizer and its settings are one tagged value now{unknown}: replace "
                     f"{replaced} with `{tagged}` (one of {', '.join(OPTIMIZER_TAGS)}; see controllers/mpc.yaml)")


def mpc_settings_file(robot: Robot, path=None):
    """The MPC settings file a job reads: `path`, or without one the file the robot's config names
    (`defaults.mpc`; the UR-10's controllers/mpc.yaml); None: none, the settings are derived."""
    return path or robot.default_file("mpc")


def mpc_config_for(robot: Robot, path=None) -> MpcConfig:
    """The MPC settings of `mpc_settings_file(robot, path)`, or without one `MpcConfig.derived_for` the robot."""
    path = mpc_settings_file(robot, path)
    return MpcConfig.derived_for(robot) if path is None else load_mpc_config(path)


@dataclasses.dataclass
class Reference:
    """A reference trajectory at the control period: q (N+1, n) rad, v (N+1, n) rad/s.

    Past its end the reference holds its last sample (at rest).
    """
    q: np.ndarray
    v: np.ndarray

    def window(self, k: int, length: int) -> np.ndarray:
        """States r_k .. r_k+length-1 as (length, 2n), holding the last sample past the end."""
        index = np.minimum(np.arange(k, k + length), len(self.q) - 1)
        return np.hstack([self.q[index], self.v[index]])


@dataclasses.dataclass
class MpcLog:
    """What the controller did at each control step (diagnostics, appended as it runs)."""
    time: list = dataclasses.field(default_factory=list)
    state: list = dataclasses.field(default_factory=list)
    torque: list = dataclasses.field(default_factory=list)
    solve_seconds: list = dataclasses.field(default_factory=list)
    fallback: list = dataclasses.field(default_factory=list)
    constraint_active: list = dataclasses.field(default_factory=list)   # a limit active in the step's solution
    slack: list = dataclasses.field(default_factory=list)               # its largest accepted crossing (rad, rad/s)
    implementation: str = ""    # the control step's implementation (`rti.Rti.implementation`: compiled or numpy, why)


def control_step_implementation(solver) -> str:
    """What runs an optimizer's control step: "compiled" (C++), "numpy (why)" for the real-time iteration, else the
    optimizer's class (the iLQR and the samplers run in numpy)."""
    return getattr(solver, "implementation", None) or f"numpy ({type(solver).__name__})"


class MpcController(LeafSystem):
    """Discrete-time MPC: every `model.sample_period` it solves the tracking problem from the measured
    state (with the settings' optimizer unless another is given) and holds the first torque until the next sample.

    For a robot of n joints (`robot`): input "state" (2n: [q rad, v rad/s]);
    output "torque" (n, N m).

    Timing: a discrete plant steps at multiples of its step h; the controller updates at
    t_k - h/2, where the plant's state already equals x(t_k), so the torque it computes is the one
    the plant integrates over the whole period [t_k, t_k+1). The first torque comes from an
    initialization event at t = 0.

    State: the torque being applied, the disturbance estimate and the prediction of the next
    measured state made with both (discrete), the warm-start plan: torques and predicted states, shifted
    by one period (abstract).

    Limits: the optimizer keeps the torques within the robot's effort limits and the predicted states within
    its position and velocity limits (the plant's, the robot config's overrides included) as `config.constraints`
    says (soft by default); `log.constraint_active` and `log.slack` record, per step, whether a limit was active
    in the solution and the largest crossing it accepted. If the model's predictions are not finite, the
    controller applies gravity compensation at the measured q, clipped to the effort limits, and records the
    step in `log.fallback`.

    optimizer: the `TrajectoryOptimizer` that solves each step (default: `config.solver`, the config's
    optimizer of `model` with its cost, settings and the robot's limits); it brings its own model, cost and
    limits.
    """

    def __init__(self, model, reference: Reference, config: MpcConfig, plant_time_step: float,
                 robot: Robot, optimizer: TrajectoryOptimizer | None = None):
        super().__init__()
        config.validate()
        self.dynamics = Dynamics(robot)
        self.dynamics.robot.check_fully_actuated("MPC")
        self.model = model
        self.reference = reference
        self.config = config
        self.joints = joints = self.dynamics.robot.num_joints
        self.state_dim = state_dim = 2 * joints
        limits = joint_limits(self.dynamics.plant)
        self.effort_limit = limits.effort
        self.solver = optimizer or config.solver(model, limits, self.dynamics.robot.joint_names)
        # (an optimizer written before warm-start states existed takes no x_init: it gets none)
        self._warm_states = "x_init" in inspect.signature(self.solver.solve).parameters
        self.log = MpcLog(implementation=control_step_implementation(self.solver))
        period = model.sample_period
        if not 0 < plant_time_step <= period:
            raise InputError(f"plant time step {plant_time_step} s must be in (0, {period}] s")
        self._period = period
        self._state_input = self.DeclareVectorInputPort("state", state_dim)
        self._torque_index = self.DeclareDiscreteState(joints)
        self._predicted_index = self.DeclareDiscreteState(state_dim)
        self._disturbance_index = self.DeclareDiscreteState(state_dim)
        self._plan_index = self.DeclareAbstractState(AbstractValue.Make(np.zeros((config.horizon, joints))))
        self._nodes_index = self.DeclareAbstractState(AbstractValue.Make(np.full((config.horizon + 1, state_dim),
                                                                                 np.nan)))
        self.DeclareStateOutputPort("torque", self._torque_index)
        self.DeclareInitializationUnrestrictedUpdateEvent(self._update)
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, period - 0.5 * plant_time_step, self._update)
        self._step = MpcStep(self.solver, reference, self.dynamics.gravity_torque, config.horizon,
                             config.disturbance_gain, self.effort_limit, self._warm_states)

    def get_state_input_port(self):
        """Input "state": the measured plant state [q (n) rad, v (n) rad/s]."""
        return self.GetInputPort("state")

    def get_torque_output_port(self):
        """Output "torque": the joint torques (n) N m applied until the next control step."""
        return self.GetOutputPort("torque")

    def _update(self, context, state):
        x = np.asarray(self._state_input.Eval(context))
        # updates fall at k period - h/2 (h <= period): the nearest sample at or after, also when h = period
        k = int(np.floor(context.get_time() / self._period + 0.5 + 1e-9))
        memory = StepMemory(predicted=context.get_discrete_state(int(self._predicted_index)).get_value().copy(),
                            disturbance=context.get_discrete_state(int(self._disturbance_index)).get_value().copy(),
                            plan=state.get_mutable_abstract_state(int(self._plan_index)).get_value(),
                            nodes=state.get_mutable_abstract_state(int(self._nodes_index)).get_value())
        started = time.perf_counter()
        torque, memory, status = self._step(k, x, memory)
        elapsed = time.perf_counter() - started
        state.get_mutable_discrete_state(int(self._torque_index)).set_value(torque)
        state.get_mutable_discrete_state(int(self._predicted_index)).set_value(memory.predicted)
        state.get_mutable_discrete_state(int(self._disturbance_index)).set_value(memory.disturbance)
        state.get_mutable_abstract_state(int(self._plan_index)).set_value(memory.plan)
        state.get_mutable_abstract_state(int(self._nodes_index)).set_value(memory.nodes)
        self.log.time.append(context.get_time())
        self.log.state.append(np.array(x))
        self.log.torque.append(torque.copy())
        self.log.solve_seconds.append(elapsed)
        self.log.fallback.append(status.fallback)
        self.log.constraint_active.append(status.constraint_active)
        self.log.slack.append(status.slack)


def build_closed_loop(model, reference: Reference, config: MpcConfig, plant_config: PlantConfig | None = None,
                      meshcat=None, *, robot: Robot, optimizer: TrajectoryOptimizer | None = None, noise_seed: int = 0,
                      push: JointPush | None = None):
    """Diagram: the robot's plant (discrete) <-> MpcController(model, optimizer); with the plant effects'
    torque noise, a `TorqueNoise` (seeded by `noise_seed`, one draw per control period over the
    reference) between them; with `push`, that push on the plant (`push.add_push`). Returns (diagram, plant,
    controller)."""
    plant_config = plant_config or PlantConfig()
    builder = DiagramBuilder()
    plant, scene_graph = make_plant(plant_config, builder=builder, robot=robot)
    controller = builder.AddSystem(MpcController(model, reference, config, plant_config.time_step, robot, optimizer))
    controller.set_name("mpc")
    builder.Connect(measured_state_output(builder, plant), controller.get_state_input_port())   # (delayed: the effects')
    effects = plant_config.effects
    if effects is not None and effects.has_torque_noise():
        period = model.sample_period
        noise = builder.AddSystem(TorqueNoise(effects.joint_values("torque_noise_std", robot.action_dim),
                                              controller.effort_limit, period, period - 0.5 * plant_config.time_step,
                                              len(reference.q), noise_seed))
        noise.set_name("torque_noise")
        builder.Connect(controller.get_torque_output_port(), noise.get_input_port())
        builder.Connect(noise.get_output_port(), actuation_input(builder, plant))
    else:
        builder.Connect(controller.get_torque_output_port(), actuation_input(builder, plant))
    if push is not None:
        add_push(builder, plant, robot, push)
    if meshcat is not None:
        from pydrake.geometry import MeshcatVisualizer
        MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat)
    return builder.Build(), plant, controller


def run_closed_loop(model, reference: Reference, config: MpcConfig, plant_config: PlantConfig | None = None,
                    duration: float | None = None, *, robot: Robot,
                    optimizer: TrajectoryOptimizer | None = None, noise_seed: int = 0,
                    push: JointPush | None = None) -> MpcLog:
    """Simulate plant + MPC from rest at the reference's start; returns the controller's log. noise_seed:
    the torque noise's draws, when the plant effects have it; push: a push on the arm (`build_closed_loop`)."""
    from pydrake.systems.analysis import Simulator
    diagram, plant, controller = build_closed_loop(model, reference, config, plant_config, robot=robot,
                                                   optimizer=optimizer, noise_seed=noise_seed, push=push)
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    x0 = np.concatenate([reference.q[0], np.zeros(len(reference.q[0]))])
    plant_context = plant.GetMyContextFromRoot(context)
    (plant_config or PlantConfig()).set_parameters(plant, plant_context)
    plant.SetPositionsAndVelocities(plant_context, x0)
    start_actuators(diagram, context, lambda: Dynamics(robot).gravity_torque(reference.q[0]))   # (at rest)
    period = model.sample_period
    duration = (len(reference.q) - 1) * period if duration is None else duration
    simulator.Initialize()
    with simulation_errors():
        simulator.AdvanceTo(duration - 0.25 * period)  # the last update (t = duration - h/2) included
    return controller.log
