"""Joint-space tracking controllers and the joint sensor model, run as sampled-data systems.

A real robot's controller runs at its control rate and holds its torque in between (zero-order
hold). stdm-drake does the same: the control law is evaluated once per sample period on the
measured state, and the torque is held while the plant integrates at its finer step. The
control laws are Drake's own systems, evaluated in their own contexts:

- `Pid` (YAML `controller: !Pid`): Drake's `PidController` (kp, ki, kd) on the [q, v] error plus
  gravity feed-forward g(q_measured);
- `InverseDynamics` (`controller: !InverseDynamics`): Drake's `InverseDynamicsController` (computed
  torque with PID on the error and the planned acceleration as reference).

The integral of the position error is kept by the sampled loop (rectangle rule at the sample
period) and written into the Drake controller's context before each evaluation.
"""

import dataclasses
import typing

import numpy as np
from pydrake.systems.controllers import InverseDynamicsController, PidController

from stdm_drake.config import check_joint_vector, load_yaml_config
from stdm_drake.errors import InputError
from stdm_drake.robots.plant import Dynamics, joint_limits, robot_joint_limits
from stdm_drake.robots.robot import Robot

MAX_GAIN = 1e9   # a PID gain (N m/rad, N m/(rad s), N m s/rad): beyond any joint servo's by orders of magnitude
MAX_FILTER_TIME_CONSTANT = 10.0   # s: a velocity filter slower than this passes none of a tracked motion (a few seconds)

@dataclasses.dataclass
class JointGains:
    """What both tracking controllers share: gains per joint (in the robot's arm-joint order), or one
    value for every joint, the torque dither and the velocity filter.

    dither_std (N m): white torque dither added to each sample's torque (persistent excitation, as
    in system identification), held and recorded like the rest of the torque; zeros = off.
    velocity_filter_time_constant (s): the velocity the controller acts on (its D term, and C(q, v) v
    for inverse dynamics) is the measured one passed through a first-order low-pass filter,
    v_f,k = v_f,k-1 + beta (v_k - v_f,k-1) with beta = T / (T + time_constant) at the sample period T,
    started at the first measurement; 0 = the raw measurement.
    dither_acceleration (rad/s^2; instead of dither_std): dither_std = dither_acceleration x M_eff,
    M_eff,i = 1 / (M^-1)_ii, its smallest over home and 50 poses within +-0.5 rad of it.
    """
    kind: typing.ClassVar[str] = ""
    kp: typing.List[float] = dataclasses.field(default_factory=list)
    ki: typing.List[float] = dataclasses.field(default_factory=list)
    kd: typing.List[float] = dataclasses.field(default_factory=list)
    dither_std: typing.List[float] = dataclasses.field(default_factory=lambda: [0.0])
    velocity_filter_time_constant: float = 0.0
    dither_acceleration: typing.List[float] = dataclasses.field(default_factory=list)

    def sizing(self) -> list:
        """The sizing rule given instead of kp, ki, kd (none here)."""
        return []

    def validate(self) -> None:
        if not (0 <= self.velocity_filter_time_constant <= MAX_FILTER_TIME_CONSTANT):   # (NaN fails too)
            raise InputError(f"controller velocity_filter_time_constant must be in [0, {MAX_FILTER_TIME_CONSTANT:g}] s "
                             f"(a slower filter passes none of a tracked motion to the D term), got "
                             f"{self.velocity_filter_time_constant}")
        check_joint_vector("controller dither_std", self.dither_std, nonnegative=True)
        given = [name for name in ("kp", "ki", "kd") if getattr(self, name)]
        if self.sizing():
            check_joint_vector("controller bandwidth", self.sizing(), nonnegative=True)
            if given:
                raise InputError(f"controller: give kp, ki, kd or bandwidth, not both (got {', '.join(given)})")
        elif len(given) != 3:
            raise InputError("controller needs kp, ki and kd" + (" (or a bandwidth to size them from)"
                                                                 if self.kind == "pid" else ""))
        for name in given:
            check_joint_vector(f"controller gain {name}", getattr(self, name), nonnegative=True)
        if self.dither_acceleration:
            check_joint_vector("controller dither_acceleration", self.dither_acceleration, nonnegative=True)
            if any(float(value) > 0 for value in self.dither_std):   # (it replaces dither_std: held-out run 28)
                raise InputError("controller: give dither_std or dither_acceleration, not both (dither_acceleration "
                                 "sizes dither_std from the robot's inertia, so the dither_std given would be ignored)")

    def for_robot(self, robot: Robot, effects=None):
        """This config with kp, ki, kd and dither_std of the robot's length (one value broadcast, or
        sized from its inertia by a bandwidth and dither_acceleration, which are then left empty), as
        datasets record it; InputError when a list has another length. effects: the PlantEffects of the
        plant it will drive (sized gains use that plant's inertia, reflected rotor inertia and payload
        included, as a servo tuned on the real robot would)."""
        self.validate()
        n = robot.num_joints
        config = self
        if self.sizing() or self.dither_acceleration:
            inertia = smallest_effective_inertia(robot, effects)
            if self.sizing():
                w = check_joint_vector("controller bandwidth", self.sizing(), count=n)
                with np.errstate(over="ignore"):   # (a bandwidth whose gains overflow: refused below, naming it)
                    kp = inertia * w**2
                if not np.all(kp <= MAX_GAIN):
                    raise InputError(f"controller bandwidth {self.sizing()} rad/s sizes a kp of {float(np.max(kp)):g} "
                                     f"on the arm's inertia, beyond any joint's gain (at most {MAX_GAIN:g})")
                config = dataclasses.replace(config, kp=kp.tolist(), ki=(2.0 * kp).tolist(),
                                             kd=(2.0 * inertia * w).tolist(), bandwidth=[])
            if self.dither_acceleration:
                acceleration = check_joint_vector("controller dither_acceleration", self.dither_acceleration, count=n)
                config = dataclasses.replace(config, dither_std=(acceleration * inertia).tolist(), dither_acceleration=[])
        kp, ki, kd, dither_std = config.gains(n)
        for name, values in (("kp", kp), ("ki", ki), ("kd", kd)):
            if np.any(values > MAX_GAIN):   # (1e300 overflows the first control step; no servo's gain is near)
                raise InputError(f"controller gain {name} {float(values.max()):g} is beyond any joint's (at most {MAX_GAIN:g})")
        if np.any(dither_std > 0):   # (a dither beyond the motor's torque is saturation, not a dither)
            effort = robot_joint_limits(robot).effort   # (the plant effects leave the effort limits as they are)
            joint = int(np.argmax(dither_std - effort))
            if dither_std[joint] > effort[joint]:
                sized = " (dither_acceleration times the joint's inertia)" if self.dither_acceleration else ""
                raise InputError(f"controller dither_std {dither_std[joint]:g} N m{sized} on {robot.joint_names[joint]} is "
                                 f"beyond its effort limit {effort[joint]:g} N m")
        return dataclasses.replace(config, kp=kp.tolist(), ki=ki.tolist(), kd=kd.tolist(), dither_std=dither_std.tolist())

    def gains(self, joints: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(kp, ki, kd, dither_std), each (joints,); InputError when a list has another length."""
        return tuple(check_joint_vector(f"controller {name}", getattr(self, name), count=joints, nonnegative=True)
                     for name in ("kp", "ki", "kd", "dither_std"))

    def record(self) -> dict:
        """What a dataset records of this controller: its kind and its fields."""
        return dict(kind=self.kind, **dataclasses.asdict(self))


@dataclasses.dataclass
class Pid(JointGains):
    """Drake's `PidController` on the [q, v] error plus gravity feed-forward g(q_measured) (YAML tag
    `!Pid`): kp N m/rad, ki N m/(rad s), kd N m s/rad.

    bandwidth (rad/s; instead of kp, ki, kd): gains sized for any robot from each joint's effective
    inertia M_eff,i (its smallest near home: it decides stability at a held torque): kp = M_eff w^2,
    kd = 2 M_eff w (critically damped), ki = 2 kp, the rule behind controllers/pid.yaml's UR-10 gains.
    """
    kind: typing.ClassVar[str] = "pid"
    gravity_feedforward: bool = True
    bandwidth: typing.List[float] = dataclasses.field(default_factory=list)

    def sizing(self) -> list:
        return self.bandwidth


@dataclasses.dataclass
class InverseDynamics(JointGains):
    """Drake's `InverseDynamicsController` (YAML tag `!InverseDynamics`): computed torque with PID on
    the error and the planned acceleration as reference; kp 1/s^2, ki 1/s^3, kd 1/s (they scale the
    mass matrix, so one value suits every joint of any robot).

    damping_compensation: "planned" (default) compensates the description's joint damping D along the
    plan, D v_planned; "measured" keeps Drake's own, D v on the measured velocity, which makes a joint
    whose damping stops it within a sample period chatter (`SampledJointController`)."""
    kind: typing.ClassVar[str] = "inverse_dynamics"
    damping_compensation: str = "planned"

    def validate(self) -> None:
        super().validate()
        if self.damping_compensation not in DAMPING_COMPENSATIONS:
            raise InputError(f"controller damping_compensation must be one of {', '.join(DAMPING_COMPENSATIONS)}, "
                             f"got {self.damping_compensation!r}")


DAMPING_COMPENSATIONS = ("planned", "measured")
ControllerConfig = typing.Union[Pid, InverseDynamics]   # a tracking controller's settings, tagged in YAML
CONTROLLER_TYPES = {cls.kind: cls for cls in typing.get_args(ControllerConfig)}


@dataclasses.dataclass
class ControllerFile:
    """Schema of controllers/*.yaml: `controller: !Pid {...}` or `controller: !InverseDynamics {...}`."""
    controller: ControllerConfig = dataclasses.field(default_factory=InverseDynamics)

    def validate(self) -> None:
        self.controller.validate()


def friction_bound_joints(gains: "JointGains", robot: Robot, effects, error: float = 0.1) -> list[str]:
    """One line per joint the tracking controller cannot break loose from its Coulomb friction F_c with a
    tracking error below `error` rad: stiffness x error < F_c, the stiffness kp N m/rad for a PID and
    kp M_ii(home) for inverse dynamics (which scales by the description's mass matrix). Gains made for the
    description of a geared joint are far too small for the robot with its rotor and friction. Empty for
    a plant without Coulomb friction."""
    friction = None if effects is None else effects.coulomb(robot.num_joints)
    if friction is None:
        return []
    stiffness = np.asarray(gains.kp, dtype=float)   # (m,): one gain per actuated joint
    coulomb = friction[0]
    inertia = np.diag(Dynamics(robot).mass_matrix(robot.home))
    if not robot.fully_actuated:
        coulomb, inertia = coulomb[robot.actuated_indices], inertia[robot.actuated_indices]
    if isinstance(gains, InverseDynamics):
        stiffness = stiffness * inertia
    return [f"{name}: stiffness {k:.3g} N m/rad needs {c / k if k > 0 else float('inf'):.3g} rad of error to overcome "
            f"its {c:.3g} N m of Coulomb friction"
            for name, k, c in zip(robot.actuated_joint_names, stiffness, coulomb) if k * error < c]


def smallest_effective_inertia(robot: Robot, effects=None, box: float = 0.5, samples: int = 50) -> np.ndarray:
    """Per joint (n,) kg m^2, the smallest 1 / (M(q)^-1)_ii over home and `samples` poses drawn
    uniformly within +-box rad of it inside the position limits (numpy.random.default_rng(0)); of the
    plant with `effects` (PlantEffects; None: the description)."""
    dynamics = Dynamics(robot, effects)
    limits = joint_limits(dynamics.plant)
    poses = np.clip(robot.home + np.random.default_rng(0).uniform(-box, box, size=(samples, robot.num_joints)),
                    limits.position_lower, limits.position_upper)
    return np.min([dynamics.effective_inertia(q) for q in np.vstack([robot.home, poses])], axis=0)


def load_controller_config(path) -> ControllerConfig:
    """The tracking controller of a controller YAML (`ControllerFile`). A file in the layout before
    the tags (top-level `kind: pid` and the fields) still loads, with one warning line saying how to
    update it."""
    return load_yaml_config(path, ControllerFile, what="controller config",
                            old_layouts={"": (CONTROLLER_TYPES, "controller: !{}")}).controller


@dataclasses.dataclass
class SensorConfig:
    """Joint encoder model: white noise on q and v, then a causal moving average of v.

    position_noise_std rad; velocity_noise_std rad/s; velocity_filter_window samples (1 = off).
    """
    position_noise_std: float = 0.0
    velocity_noise_std: float = 0.0
    velocity_filter_window: int = 1

    # Beyond these a reading says nothing about the joint (a position noise of more than half a turn, a velocity
    # noise tens of times an arm's fastest joint) or smooths over more than a trajectory
    MAX_POSITION_NOISE_STD, MAX_VELOCITY_NOISE_STD, MAX_FILTER_WINDOW = np.pi, 100.0, 1000

    def validate(self) -> None:
        for name in ("position_noise_std", "velocity_noise_std"):
            if not getattr(self, name) >= 0:   # (a NaN too)
                raise InputError(f"sensor {name} must be a number >= 0, got {getattr(self, name)}")
        if not (self.position_noise_std <= self.MAX_POSITION_NOISE_STD
                and self.velocity_noise_std <= self.MAX_VELOCITY_NOISE_STD):
            raise InputError(f"sensor noise standard deviations must be at most pi rad (position) and "
                             f"{self.MAX_VELOCITY_NOISE_STD:g} rad/s (velocity), got {self.position_noise_std:g} and "
                             f"{self.velocity_noise_std:g}: beyond, a reading says nothing about the joint")
        if not 1 <= self.velocity_filter_window <= self.MAX_FILTER_WINDOW:
            raise InputError(f"velocity_filter_window must be in 1..{self.MAX_FILTER_WINDOW} samples, got "
                             f"{self.velocity_filter_window}")


class JointSensor:
    """Sampled joint measurements of one trajectory.

    `measure` returns the raw reading (q + n_q, v + n_v), which the servo controller uses, and
    the filtered velocity MA_w(v + n_v), which is what gets recorded (as on the real robot,
    where the average filter served the logged data, not the joint servo loop).
    """

    def __init__(self, config: SensorConfig, rng: np.random.Generator):
        config.validate()
        self.config = config
        self.rng = rng
        self._velocity_history: list[np.ndarray] = []

    def measure(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q, v: (n,) true state -> (q_measured, v_measured, v_filtered), each (n,)."""
        c = self.config
        q_measured = q + c.position_noise_std * self.rng.standard_normal(len(q)) if c.position_noise_std else q.copy()
        v_noisy = v + c.velocity_noise_std * self.rng.standard_normal(len(v)) if c.velocity_noise_std else v.copy()
        self._velocity_history.append(v_noisy)
        del self._velocity_history[:-c.velocity_filter_window]
        return q_measured, v_noisy, np.mean(self._velocity_history, axis=0)


class SampledJointController:
    """Drake's PID or inverse-dynamics controller evaluated once per sample period.

    `torque(q, v, q_d, v_d, qdd_d)` returns the torque (n,) N m to hold over the next sample
    period, clamped to the effort limits, and advances the error integral and the velocity filter
    by one period; `reset()` starts a new trajectory.

    Joint damping D (the description's <dynamics damping>): Drake's inverse dynamics cancels it on the
    measured velocity, D v; held over a sample period against a joint whose damping stops it faster
    than that (M_eff / D below the period) this cancellation feeds the delay back and the joint
    chatters. The computed torque here compensates the damping along the plan instead, D v_d: the
    torque the planned motion needs, while the plant's own damping acts on the tracking error.
    """

    def __init__(self, config: ControllerConfig, sample_period: float, robot: Robot):
        config.validate()
        self.config = config
        self.sample_period = sample_period
        self.dynamics = Dynamics(robot)
        self.effort_limit = joint_limits(self.dynamics.plant).effort
        joints = len(self.effort_limit)
        kp, ki, kd, self.dither_std = config.gains(joints)
        if isinstance(config, Pid):
            self._system = PidController(kp=kp, ki=ki, kd=kd)
        else:
            self._system = InverseDynamicsController(
                self.dynamics.plant, kp=kp, ki=ki, kd=kd, has_reference_acceleration=True)
        self._context = self._system.CreateDefaultContext()
        self._integral = np.zeros(joints)
        self._filter_gain = sample_period / (sample_period + config.velocity_filter_time_constant)
        self._filtered_velocity: np.ndarray | None = None

    def reset(self) -> None:
        self._integral[:] = 0.0
        self._filtered_velocity = None

    def torque(self, q, v, q_d, v_d, qdd_d) -> np.ndarray:
        system, context = self._system, self._context
        if self._filtered_velocity is None:
            self._filtered_velocity = np.array(v, dtype=float)
        else:
            self._filtered_velocity += self._filter_gain * (v - self._filtered_velocity)
        v = self._filtered_velocity
        context.SetContinuousState(self._integral)
        system.get_input_port_estimated_state().FixValue(context, np.concatenate([q, v]))
        system.get_input_port_desired_state().FixValue(context, np.concatenate([q_d, v_d]))
        if isinstance(self.config, InverseDynamics):
            system.get_input_port_desired_acceleration().FixValue(context, qdd_d)
        tau = np.array(system.get_output_port_control().Eval(context))
        if isinstance(self.config, InverseDynamics) and self.config.damping_compensation == "planned":
            tau += self.dynamics.damping * (np.asarray(v_d) - v)   # the description's damping along the plan
        if isinstance(self.config, Pid) and self.config.gravity_feedforward:
            tau += self.dynamics.gravity_torque(q)
        self._integral += (q_d - q) * self.sample_period
        return np.clip(tau, -self.effort_limit, self.effort_limit)
