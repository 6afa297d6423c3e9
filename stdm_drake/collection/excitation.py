"""The excitation protocol (paper V.A.2, eq. 10): per-joint random sine torques A sin(f t + phi) + B
added to gravity compensation, drawn until a trajectory stays inside the robot's limits.
`Excitation` is the schema of trajectories/excitation*.yaml."""
import dataclasses
import typing

import numpy as np

from stdm_drake.config import check_joint_vector
from stdm_drake.errors import InputError, bound_text
from stdm_drake.robots.control import JointSensor
from stdm_drake.robots.plant import Dynamics, joint_limits, robot_joint_limits
from stdm_drake.robots.robot import Robot
from stdm_drake.robots.station import Station


@dataclasses.dataclass
class Excitation:
    """Random sine torques (paper eq. 10) on top of gravity compensation, per actuated joint (amplitude,
    offset; the start positions: per arm joint). An unactuated joint gets no torque and no compensation.

    tau_i(t) = g_i(q_k) + A_i sin(f_i t + phi_i) + B_i with A_i ~ U[0, amplitude_max_i] N m,
    f_i ~ U[frequency_range] rad/s, B_i ~ U[-offset_max_i, offset_max_i] N m,
    phi_i ~ U[phase_range] rad; t is the time since the trajectory's start.
    q0 ~ U[initial_position_lower, initial_position_upper] rad, v0 = 0.
    A trajectory is resampled when it comes within position_margin (rad) of a joint limit,
    exceeds velocity_fraction of a velocity limit, or (check_self_collision) makes two
    non-adjacent links touch; after max_attempts failed attempts collection stops with an error.
    """
    kind: typing.ClassVar[str] = "excitation"
    num_steps: int = 50
    amplitude_max: list[float] = dataclasses.field(default_factory=lambda: [6.0, 6.0, 2.0, 0.015, 0.002, 0.00015])
    offset_max: list[float] = dataclasses.field(default_factory=lambda: [6.0, 6.0, 2.0, 0.015, 0.002, 0.00015])
    frequency_range: list[float] = dataclasses.field(default_factory=lambda: [1.0, 10.0])
    phase_range: list[float] = dataclasses.field(default_factory=lambda: [-1.0, 1.0])
    gravity_compensation: bool = True
    initial_position_lower: list[float] = dataclasses.field(
        default_factory=lambda: [-3.1, -2.6, -2.6, -3.1, -3.1, -3.1])
    initial_position_upper: list[float] = dataclasses.field(
        default_factory=lambda: [3.1, -0.5, 2.6, 3.1, 3.1, 3.1])
    position_margin: float = 0.05
    velocity_fraction: float = 1.0
    check_self_collision: bool = True
    max_attempts: int = 200

    def validate(self) -> None:
        for name in ("amplitude_max", "offset_max", "initial_position_lower", "initial_position_upper"):
            check_joint_vector(f"excitation {name}", getattr(self, name))
        for name in ("frequency_range", "phase_range"):
            low_high = getattr(self, name)
            if len(low_high) != 2 or not low_high[0] <= low_high[1]:
                raise InputError(f"excitation {name} must be [low, high] with low <= high, got {low_high}")
        if np.any(np.asarray(self.amplitude_max) < 0) or np.any(np.asarray(self.offset_max) < 0):
            raise InputError("excitation amplitude_max and offset_max must be >= 0")
        if np.any(np.asarray(self.initial_position_lower) > np.asarray(self.initial_position_upper)):
            raise InputError("excitation initial_position_lower must be <= initial_position_upper")
        if self.num_steps < 2 or self.max_attempts < 1:
            raise InputError("excitation num_steps must be >= 2 and max_attempts >= 1")
        if not (np.isfinite(self.position_margin) and self.position_margin >= 0):   # (a NaN makes every check pass)
            raise InputError(f"excitation position_margin must be a finite number >= 0 rad, got {self.position_margin}")
        if not 0 < self.velocity_fraction <= 1:   # (beyond 1: past the robot's limits; a NaN too)
            raise InputError(f"excitation velocity_fraction must be in (0, 1] (of each velocity limit), got "
                             f"{self.velocity_fraction}")
        if not all(np.isfinite(self.frequency_range)) or self.frequency_range[0] < 0:
            raise InputError(f"excitation frequency_range must be finite numbers >= 0 rad/s, got {self.frequency_range}")
        if not all(abs(value) <= 1e9 for value in self.phase_range):   # (a NaN too)
            raise InputError(f"excitation phase_range must be numbers within +-1e9 rad (beyond, a double holds no "
                             f"fraction of a turn), got {self.phase_range}")

    def check_sampled(self, sample_period: float) -> None:
        """InputError (one line) where a sine of frequency_range (rad/s) is beyond what the held torque samples at
        `sample_period` s carry (the Nyquist frequency pi / period: beyond it the torque aliases to another sine)."""
        if self.frequency_range[1] > np.pi / sample_period:
            raise InputError(f"excitation frequency_range {self.frequency_range} rad/s reaches beyond "
                             f"{bound_text(np.pi / sample_period, at_least=False, digits=4)} rad/s, the Nyquist "
                             f"frequency of the {sample_period:g} s sample period (the held torque would alias); keep "
                             "its upper end at most that")

    @classmethod
    def derived_for(cls, robot: Robot, acceleration: float = 0.5, box: float = 0.5) -> "Excitation":
        """Default ranges for a robot without an excitation file, by the rule behind the UR-10's:
        amplitude and offset limits `acceleration` (rad/s^2) times each joint's effective inertia
        M_ii at the home pose (N m), start poses in a box of +-`box` rad around home, kept 0.05 rad
        inside the position limits (box=math.pi: the whole range, as trajectories/excitation.yaml's
        nearly whole-range UR-10 start poses)."""
        dynamics = Dynamics(robot)
        torque = acceleration * np.diag(dynamics.mass_matrix(robot.home))[robot.actuated_indices]
        limits = joint_limits(dynamics.plant)
        lower = np.maximum(robot.home - box, limits.position_lower + 0.05)
        upper = np.minimum(robot.home + box, limits.position_upper - 0.05)
        return cls(amplitude_max=torque.tolist(), offset_max=torque.tolist(), initial_position_lower=lower.tolist(),
                   initial_position_upper=upper.tolist())

    def check_start_poses(self, robot: Robot) -> None:
        """InputError naming the joint if the start-pose box is not `position_margin` inside its limits (every start
        would be rejected, after the simulation, as a limit violation), or an amplitude or offset is beyond its
        effort limit."""
        limits = robot_joint_limits(robot)
        for name, values in (("amplitude_max", self.amplitude_max), ("offset_max", self.offset_max)):
            beyond = np.asarray(values, dtype=float) > limits.effort   # (a sine past the motor's torque is clipped flat)
            if np.any(beyond):
                j = int(np.argmax(beyond))
                raise InputError(f"excitation {name} {values[j]:g} N m on {robot.joint_names[robot.actuated_indices[j]]} "
                                 f"is beyond its effort limit {limits.effort[j]:g} N m")
        lower, upper = np.asarray(self.initial_position_lower), np.asarray(self.initial_position_upper)
        for j, name in enumerate(robot.joint_names):
            low, high = limits.position_lower[j] + self.position_margin, limits.position_upper[j] - self.position_margin
            if lower[j] < low or upper[j] > high:
                raise InputError(f"excitation start poses of {name} [{lower[j]:.4g}, {upper[j]:.4g}] rad leave its "
                                 f"limits less the {self.position_margin} rad margin [{low:.4g}, {high:.4g}] rad")

    def for_robot(self, robot: Robot) -> "Excitation":
        """This config with every per-joint list of the robot's length (one value broadcast): torques per
        actuated joint, start positions per arm joint; InputError when a list has another length."""
        counts = dict(amplitude_max=robot.action_dim, offset_max=robot.action_dim,
                      initial_position_lower=robot.num_joints, initial_position_upper=robot.num_joints)
        return dataclasses.replace(self, **{
            name: check_joint_vector(f"excitation {name}", getattr(self, name), count=count).tolist()
            for name, count in counts.items()})


def excitation_trajectory(rig: Station, config: Excitation, rng: np.random.Generator) -> dict:
    """Sample eq. (10) parameters and q0 until a trajectory stays inside the limits."""
    lower, upper = np.asarray(config.initial_position_lower), np.asarray(config.initial_position_upper)
    reasons: dict[str, int] = {}
    starts = []   # the start poses simulated (`Station.gravity_beyond`)
    sensor_config = rig.settings.sensor
    for _ in range(config.max_attempts):
        amplitude = rng.uniform(0.0, config.amplitude_max)
        frequency = rng.uniform(*config.frequency_range, size=rig.robot.action_dim)
        offset = rng.uniform(-np.asarray(config.offset_max), config.offset_max)
        phase = rng.uniform(*config.phase_range, size=rig.robot.action_dim)
        q0 = rng.uniform(lower, upper)
        if config.check_self_collision and not rig.collision_checker.is_collision_free(q0):
            reasons["initial self-collision"] = reasons.get("initial self-collision", 0) + 1
            continue

        starts.append(q0)

        def control(k, t, q, v):
            tau = amplitude * np.sin(frequency * t + phase) + offset
            return tau + rig.dynamics.actuated_gravity_torque(q) if config.gravity_compensation else tau

        try:
            traj = rig.run(q0, config.num_steps, control, JointSensor(sensor_config, rng), rng)
        except RuntimeError as error:  # Drake refuses a state gone non-finite: the draw diverged, draw again
            if "non-finite" not in str(error):
                raise
            reasons["simulation diverged"] = reasons.get("simulation diverged", 0) + 1
            continue
        reason = rig.limit_violation(traj, config.position_margin, config.velocity_fraction,
                                     config.check_self_collision)
        if reason is None:
            traj["excitation"] = np.concatenate([amplitude, frequency, offset, phase])
            return traj
        key = reason.split(" at step")[0]
        reasons[key] = reasons.get(key, 0) + 1
    summary = ", ".join(f"{name} x{count}" for name, count in sorted(reasons.items(), key=lambda item: -item[1]))
    hint = "lower the torque ranges"
    if config.velocity_fraction < 1 and any("velocity limit" in name for name in reasons):
        hint += f" or raise velocity_fraction ({config.velocity_fraction:g} of each velocity limit)"
    unholdable, cause = rig.gravity_beyond(starts, np.asarray(config.amplitude_max) + np.asarray(config.offset_max)
                                           if config.gravity_compensation else np.full(rig.robot.action_dim, np.inf))
    if cause:   # (unheld beyond the excitation's torques: the ranges cannot help)
        hint = cause if unholdable else (
            f"{cause}, beyond its excitation torques, so it drifts whatever the ranges; collect these data with "
            "--protocol tracking and a controller sized for the plant (stdm-drake:controllers/pid_dither_sized.yaml)")
    raise InputError(f"excitation: no trajectory within limits after {config.max_attempts} attempts ({summary}); {hint}")
