"""Trajectory planners for the tracked task-space data protocol (paper section V.B.1): a plan of
`num_steps` samples from rest to rest between two tool poses. Three planners, one config type each
(`planner_configs.PlannerConfig`, tagged in YAML):

- `Quintic`: straight line in position and geodesic (axis-angle) in orientation, both timed by
  s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5, mapped to joint space by inverse kinematics (IK)
  seeded with the previous sample; q_dot = J^-1 V and q_ddot = J^-1 (A - J_dot v).
- `Ruckig`: jerk-limited, time-synchronized joint-space point-to-point motion to the IK
  solution of the goal pose.
- `Toppra`: the IK'd task-space straight line as a joint-space path, re-timed time-optimally
  under joint velocity and acceleration limits.

Frames: every pose is the pose of the robot's tool frame in the world frame (the UR-10: tool0;
base_link is welded at the world origin, and base_link_inertia (DH frame 0) is base_link rotated by
pi about z, so the arm stretched at q = 0 points along world +x, "in front of the robot").
Spatial vectors are ordered [angular; linear], measured and expressed in the world frame, for
the origin of the tool frame. Joint order: the robot's arm joints. An arm of more than 6 joints
also moves its redundant joints linearly along the path (task coordinates: see
stdm_drake.robots.kinematics); an arm of fewer than 6 cannot follow a task-space plan.

The three planners share the IK continuation along the task-space line, the horizon and the
joint-limit checks, so that the same goal gives the same end configuration whichever planner is chosen.
"""
import dataclasses
import math
from typing import Callable

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix

from stdm_drake.collection.planner_configs import PlannerConfig
from stdm_drake.robots.kinematics import RobotKinematics, pose_text, rotation_exp, rotation_log
from stdm_drake.errors import InputError, PlanningError

# Peak of ds/dtau and of d2s/dtau2 for s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5.
_QUINTIC_PEAK_VELOCITY = 15.0 / 8.0
_QUINTIC_PEAK_ACCELERATION = 10.0 / math.sqrt(3.0)


@dataclasses.dataclass(eq=False)
class PlannedTrajectory:
    """A rest-to-rest joint trajectory sampled at a fixed period.

    planner: "quintic", "ruckig" or "toppra".
    t: (N+1,) s, t[k] = k * sample_period. q: (N+1, n) rad. qd: (N+1, n) rad/s.
    qdd: (N+1, n) rad/s^2 (the desired accelerations used as derivative targets).
    X_start, X_goal: tool0 poses in the world frame at q[0] and q[-1].
    q_goal: (n,) rad, the IK solution of X_goal where the plan ends (q[-1] == q_goal).
    duration: motion time (s) <= N * sample_period; the plan holds q_goal after it.
    """
    planner: str
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    X_start: RigidTransform
    X_goal: RigidTransform
    q_goal: np.ndarray
    duration: float
    evaluator: Callable[[float], tuple[np.ndarray, np.ndarray, np.ndarray]] = dataclasses.field(repr=False)

    @property
    def num_steps(self) -> int:
        return len(self.t) - 1

    @property
    def sample_period(self) -> float:
        return float(self.t[1] - self.t[0])

    def evaluate(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Exact (q, qd, qdd), each (n,), at time t (s); clamped to [0, N * sample_period]."""
        t = min(max(float(t), 0.0), float(self.t[-1]))
        if t >= self.duration:
            zero = np.zeros_like(self.q_goal)
            return self.q_goal.copy(), zero, zero.copy()
        return self.evaluator(t)


@dataclasses.dataclass
class _TaskLine:
    """Straight line in position and geodesic in orientation from X_start to X_goal (world); for an
    arm of more than 6 joints, the redundant joints (kinematics.redundant_joints) move linearly in
    the path parameter from redundant_start to redundant_goal (rad)."""
    X_start: RigidTransform
    X_goal: RigidTransform
    redundant_start: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    redundant_goal: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))

    def __post_init__(self):
        self.p0 = self.X_start.translation()
        self.R0 = self.X_start.rotation().matrix()
        self.dp = self.X_goal.translation() - self.p0
        self.w = rotation_log(self.X_goal.rotation().matrix() @ self.R0.T)
        self.dr = np.asarray(self.redundant_goal, float) - np.asarray(self.redundant_start, float)
        # d(task coordinates)/ds: [omega; v] (world frame), then the redundant joints' rates
        self.tangent = np.concatenate([self.w, self.dp, self.dr]) if len(self.dr) else np.concatenate([self.w, self.dp])

    def pose(self, s: float) -> RigidTransform:
        if s >= 1.0:
            return self.X_goal
        if s <= 0.0:
            return self.X_start
        return RigidTransform(RotationMatrix(rotation_exp(s * self.w) @ self.R0), self.p0 + s * self.dp)

    def redundant(self, s: float) -> np.ndarray | None:
        """Positions (rad) of the redundant joints at path parameter s, or None for a 6-joint arm."""
        if not len(self.dr):
            return None
        return np.asarray(self.redundant_start, float) + min(max(s, 0.0), 1.0) * self.dr


def _task_line(kinematics: RobotKinematics, q0: np.ndarray, X_goal: RigidTransform, config: PlannerConfig,
               label: str) -> _TaskLine:
    """The task-space line from the tool pose at q0 to X_goal. For an arm of more than 6 joints the
    redundant joints go to where the smallest-motion IK from q0 puts them at X_goal."""
    X_start = kinematics.tool_pose(q0)
    redundant = list(kinematics.redundant_joints)
    if not redundant:
        return _TaskLine(X_start, X_goal)
    try:
        q_goal = kinematics.inverse_kinematics(X_goal, q0, tolerance=config.ik_tolerance,
                                               max_iterations=config.ik_max_iterations, damping=config.ik_damping)
    except PlanningError as error:
        raise PlanningError(f"{label}: at the goal: {error}") from None
    return _TaskLine(X_start, X_goal, q0[redundant], q_goal[redundant])


def _quintic_scaling(tau: float) -> tuple[float, float, float]:
    """s, ds/dtau, d2s/dtau2 of the rest-to-rest quintic at tau in [0, 1]."""
    tau = min(max(tau, 0.0), 1.0)
    s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
    ds = 30.0 * tau**2 * (1.0 - tau) ** 2
    dds = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau)
    return s, ds, dds


def _horizon_times(num_steps: int, sample_period: float) -> np.ndarray:
    if int(num_steps) != num_steps or num_steps < 1:
        raise InputError(f"num_steps must be a positive integer, got {num_steps!r}")
    if not (math.isfinite(sample_period) and sample_period > 0):
        raise InputError(f"sample_period must be positive (s), got {sample_period!r}")
    return np.arange(int(num_steps) + 1) * float(sample_period)


def _start_configuration(kinematics: RobotKinematics, q0) -> np.ndarray:
    kinematics.robot.check_can_track()
    q0 = np.array(q0, dtype=float)
    if q0.shape != (kinematics.num_joints,) or not np.all(np.isfinite(q0)):
        raise InputError(f"start configuration must be {kinematics.num_joints} finite joint positions (rad), "
                         f"got {q0!r}")
    kinematics.check_position_limits(q0, what="start configuration")
    return q0


def _checked_jacobian(kinematics: RobotKinematics, q: np.ndarray, config: PlannerConfig,
                      label: str, where: str) -> np.ndarray:
    J = kinematics.task_jacobian(q)
    condition = float(np.linalg.cond(J))
    if not condition <= config.max_jacobian_condition:
        raise PlanningError(f"{label}: near a singularity {where}: Jacobian condition number "
                            f"{condition:.3g} > {config.max_jacobian_condition:.3g}")
    return J


def _ik_step(kinematics: RobotKinematics, line: _TaskLine, s: float, q_predicted: np.ndarray,
             config: PlannerConfig, label: str, where: str) -> np.ndarray:
    """IK of the line's task coordinates at path parameter s, seeded with a first-order prediction, continuity checked."""
    try:
        q = kinematics.inverse_kinematics(line.pose(s), q_predicted, tolerance=config.ik_tolerance,
                                          max_iterations=config.ik_max_iterations, damping=config.ik_damping,
                                          redundant_positions=line.redundant(s))
    except PlanningError as error:
        raise PlanningError(f"{label}: {where}: {error}") from None
    jump = np.abs(q - q_predicted)
    j = int(np.argmax(jump))
    if jump[j] > config.ik_continuity_tolerance:
        raise PlanningError(f"{label}: IK discontinuity {where}: {kinematics.joint_names[j]} jumps {jump[j]:.3g} rad from "
                            f"its prediction (> ik_continuity_tolerance {config.ik_continuity_tolerance:g} rad: a branch "
                            "switch, or a tolerance finer than the first-order prediction's own error along the path)")
    return q


def _ik_along_line(kinematics: RobotKinematics, q0: np.ndarray, line: _TaskLine, ss: np.ndarray,
                   config: PlannerConfig, label: str) -> np.ndarray:
    """Joint waypoints (M, n) rad along the task-space line at path parameters ss (M,), ss[0] = 0."""
    qs = np.empty((len(ss), kinematics.num_joints))
    qs[0] = q0
    for k in range(1, len(ss)):
        J = _checked_jacobian(kinematics, qs[k - 1], config, label, f"at path parameter s={ss[k - 1]:.3f}")
        q_predicted = qs[k - 1] + np.linalg.solve(J, line.tangent * (ss[k] - ss[k - 1]))
        qs[k] = _ik_step(kinematics, line, float(ss[k]), q_predicted, config, label,
                         f"at path parameter s={ss[k]:.3f}")
    _checked_jacobian(kinematics, qs[-1], config, label, "at the goal")
    return qs


def _check_limits(kinematics: RobotKinematics, config: PlannerConfig, label: str, t: np.ndarray,
                  q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> None:
    """Raise PlanningError on the worst joint position/velocity/acceleration limit violation.

    t: (N+1,) s; q, qd, qdd: (N+1, n). Velocity and acceleration get a relative slack of
    config.limit_tolerance; the violation reported is the largest relative to its limit.
    """
    limits = kinematics.limits
    velocity_limit = config.velocity_scale * limits.velocity
    acceleration_limit = np.asarray(config.acceleration_limits, dtype=float)
    tolerance = config.limit_tolerance
    span = limits.position_upper - limits.position_lower
    checks = (  # (name, unit, values, limit, excess over the limit, allowed excess, relative scale)
        ("position", "rad", q, limits.position_upper, q - limits.position_upper, 0.0, span),
        ("position", "rad", q, limits.position_lower, limits.position_lower - q, 0.0, span),
        ("velocity", "rad/s", qd, velocity_limit, np.abs(qd) - velocity_limit, tolerance * velocity_limit,
         velocity_limit),
        ("acceleration", "rad/s^2", qdd, acceleration_limit, np.abs(qdd) - acceleration_limit,
         tolerance * acceleration_limit, acceleration_limit),
    )
    worst = None  # (relative excess, message)
    for name, unit, values, limit, excess, allowed, scale in checks:
        relative = (excess - allowed) / scale
        k, j = np.unravel_index(int(np.argmax(relative)), relative.shape)
        if relative[k, j] > 0 and (worst is None or relative[k, j] > worst[0]):
            worst = (relative[k, j], f"{label}: {kinematics.joint_names[j]} {name} {values[k, j]:.4g} {unit} exceeds its "
                                     f"limit {limit[j]:.4g} {unit} by {excess[k, j]:.3g} {unit} at t={t[k]:.3f} s")
    if worst is not None:
        raise PlanningError(worst[1])


def _plan_label(kind: str, X_goal: RigidTransform) -> str:
    return f"{kind} plan to goal pose {pose_text(X_goal)}"


def _check_goal_reachable(kinematics: RobotKinematics, X_goal: RigidTransform, label: str) -> None:
    problem = kinematics._reach_problem(X_goal)
    if problem:
        raise PlanningError(f"{label}: {problem}")


def check_position_extrema(extrema, lower: np.ndarray, upper: np.ndarray, label: str, joint_names=None) -> None:
    """Raise PlanningError if a ruckig trajectory's per-joint position extrema (its
    `position_extrema`: objects with .min/.max, rad) leave [lower, upper] (n,) rad."""
    names = joint_names or [f"joint {j}" for j in range(len(lower))]
    for j, extremum in enumerate(extrema):
        for value, bound, excess in ((extremum.max, upper[j], extremum.max - upper[j]),
                                     (extremum.min, lower[j], lower[j] - extremum.min)):
            if excess > 0:
                raise PlanningError(f"{label}: {names[j]} reaches {value:.4f} rad, outside its position "
                                    f"limit {bound:.4f} rad by {excess:.4f} rad")


def quintic_shortest_times(distance: float, angle: float, config) -> tuple[float, float]:
    """(the shortest time s a quintic moves `distance` m and turns `angle` rad within a Quintic config's task-space
    speed limits, and within its acceleration limits)."""
    return (max(_QUINTIC_PEAK_VELOCITY * distance / config.max_linear_speed,
                _QUINTIC_PEAK_VELOCITY * angle / config.max_angular_speed),
            max(math.sqrt(_QUINTIC_PEAK_ACCELERATION * distance / config.max_linear_acceleration),
                math.sqrt(_QUINTIC_PEAK_ACCELERATION * angle / config.max_angular_acceleration)))


def _quintic_duration(line: _TaskLine, config: PlannerConfig, horizon: float, label: str) -> float:
    distance = float(np.linalg.norm(line.dp))
    angle = float(np.linalg.norm(line.w))
    shortest = max(quintic_shortest_times(distance, angle, config))
    if shortest > horizon * (1.0 + 1e-12):
        raise PlanningError(f"{label}: the move ({distance:.3f} m, {angle:.3f} rad) needs at least {shortest:.3f} s "
                            f"under the task-space limits, longer than the {horizon:.3f} s horizon")
    return min(max(config.duration_fraction * horizon, shortest), horizon)


def plan_quintic(kinematics: RobotKinematics, q0, X_goal: RigidTransform, *, config: PlannerConfig,
                 num_steps: int = 100, sample_period: float = 0.01) -> PlannedTrajectory:
    """Quintic-timed task-space line (position) and geodesic (orientation), mapped by IK.

    q0: (n,) rad start at rest. Returns num_steps + 1 samples; q̇ = J^-1 V_d and
    q̈ = J^-1 (A_d - J̇ q̇) from the square task Jacobian and bias acceleration (the 6x6 tool
    Jacobian of a 6-joint arm; see stdm_drake.robots.kinematics for more joints).
    """
    config.validate()
    t = _horizon_times(num_steps, sample_period)
    q0 = _start_configuration(kinematics, q0)
    label = _plan_label("quintic", X_goal)
    _check_goal_reachable(kinematics, X_goal, label)
    _checked_jacobian(kinematics, q0, config, label, "at the start")
    line = _task_line(kinematics, q0, X_goal, config, label)
    X_start = line.X_start
    T = _quintic_duration(line, config, float(t[-1]), label)

    def state(time: float, q_predicted: np.ndarray, where: str):
        tau = time / T if T > 0 else 1.0
        s, ds, dds = _quintic_scaling(tau)
        q = _ik_step(kinematics, line, s if tau < 1.0 else 1.0, q_predicted, config, label, where)
        J = _checked_jacobian(kinematics, q, config, label, where)
        if tau >= 1.0:
            return q, np.zeros(kinematics.num_joints), np.zeros(kinematics.num_joints)
        qd = np.linalg.solve(J, line.tangent * (ds / T))
        qdd = np.linalg.solve(J, line.tangent * (dds / T**2) - kinematics.task_bias(q, qd))
        return q, qd, qdd

    n = len(t)
    q, qd, qdd = np.empty((n, kinematics.num_joints)), np.zeros((n, kinematics.num_joints)), np.zeros((n, kinematics.num_joints))
    q[0] = q0
    k = 1
    while k < n:
        q_predicted = q[k - 1] + sample_period * qd[k - 1] + 0.5 * sample_period**2 * qdd[k - 1]
        q[k], qd[k], qdd[k] = state(float(t[k]), q_predicted, f"at t={t[k]:.3f} s")
        if t[k] >= T:  # at the goal: hold
            q[k + 1:] = q[k]
            break
        k += 1
    q_goal = q[-1].copy()
    _check_limits(kinematics, config, label, t, q, qd, qdd)

    def evaluator(time: float):
        q_seed = np.array([np.interp(time, t, q[:, j]) for j in range(kinematics.num_joints)])
        return state(time, q_seed, f"at t={time:.4f} s")

    return PlannedTrajectory(planner="quintic", t=t, q=q, qd=qd, qdd=qdd, X_start=X_start, X_goal=X_goal,
                             q_goal=q_goal, duration=T, evaluator=evaluator)


def _goal_configuration(kinematics: RobotKinematics, q0: np.ndarray, X_goal: RigidTransform,
                        config: PlannerConfig, label: str) -> tuple[RigidTransform, _TaskLine, np.ndarray]:
    line = _task_line(kinematics, q0, X_goal, config, label)
    ss = np.linspace(0.0, 1.0, config.path_waypoints)
    return line.X_start, line, _ik_along_line(kinematics, q0, line, ss, config, label)


@dataclasses.dataclass
class _JointSpaceGoal:
    """What the joint-space planners (ruckig, toppra) share: sample times t (n,) s and the horizon
    t[-1] s; the start q0 and the goal q_goal (n,) rad; the IK waypoints along the task-space line
    (W, n) rad, whose last is q_goal; the start pose X_start; the label for error messages."""
    t: np.ndarray
    horizon: float
    q0: np.ndarray
    q_goal: np.ndarray
    waypoints: np.ndarray
    X_start: RigidTransform
    X_goal: RigidTransform
    label: str

    def check_duration(self, duration: float, what: str) -> None:
        """PlanningError if a `what` ("jerk-limited", ...) motion of `duration` s overruns the horizon."""
        if duration > self.horizon * (1.0 + 1e-12):
            raise PlanningError(f"{self.label}: the {what} motion needs {duration:.3f} s, longer than the "
                                f"{self.horizon:.3f} s horizon")

    def trajectory(self, kind: str, kinematics: "RobotKinematics", config: "PlannerConfig", q, qd, qdd,
                   duration: float, evaluator) -> "PlannedTrajectory":
        """The sampled plan (q, qd, qdd: (N+1, n)) after the joint-limit checks."""
        _check_limits(kinematics, config, self.label, self.t, q, qd, qdd)
        return PlannedTrajectory(planner=kind, t=self.t, q=q, qd=qd, qdd=qdd, X_start=self.X_start,
                                 X_goal=self.X_goal, q_goal=self.q_goal, duration=duration, evaluator=evaluator)


def _joint_space_goal(kind: str, kinematics: "RobotKinematics", q0, X_goal: RigidTransform, config: "PlannerConfig",
                      num_steps: int, sample_period: float) -> _JointSpaceGoal:
    """Validate, check the goal is reachable, and IK the task-space line from q0 to X_goal."""
    config.validate()
    t = _horizon_times(num_steps, sample_period)
    q0 = _start_configuration(kinematics, q0)
    label = _plan_label(kind, X_goal)
    _check_goal_reachable(kinematics, X_goal, label)
    X_start, _, waypoints = _goal_configuration(kinematics, q0, X_goal, config, label)
    return _JointSpaceGoal(t=t, horizon=float(t[-1]), q0=q0, q_goal=waypoints[-1].copy(), waypoints=waypoints,
                           X_start=X_start, X_goal=X_goal, label=label)


def plan_ruckig(kinematics: RobotKinematics, q0, X_goal: RigidTransform, *, config: PlannerConfig,
                num_steps: int = 100, sample_period: float = 0.01) -> PlannedTrajectory:
    """Jerk-limited joint-space point-to-point motion (ruckig) from q0 (n,) rad to IK(X_goal).

    The goal configuration is found by IK continuation along the task-space line, so all three
    planners end in the same configuration for the same goal. ruckig (community edition)
    ignores position limits, so the trajectory's position extrema are checked here.
    """
    import ruckig

    goal = _joint_space_goal("ruckig", kinematics, q0, X_goal, config, num_steps, sample_period)
    t, q0, q_goal = goal.t, goal.q0, goal.q_goal
    inp = ruckig.InputParameter(kinematics.num_joints)
    inp.current_position = q0.tolist()
    inp.current_velocity = [0.0] * kinematics.num_joints
    inp.current_acceleration = [0.0] * kinematics.num_joints
    inp.target_position = q_goal.tolist()
    inp.target_velocity = [0.0] * kinematics.num_joints
    inp.target_acceleration = [0.0] * kinematics.num_joints
    inp.max_velocity = (config.velocity_scale * kinematics.limits.velocity).tolist()
    inp.max_acceleration = list(config.acceleration_limits)
    inp.max_jerk = list(config.jerk_limits)
    if config.duration_fraction > 0:
        inp.minimum_duration = config.duration_fraction * goal.horizon
    trajectory = ruckig.Trajectory(kinematics.num_joints)
    result = ruckig.Ruckig(kinematics.num_joints).calculate(inp, trajectory)
    if result not in (ruckig.Result.Working, ruckig.Result.Finished):
        raise PlanningError(f"{goal.label}: ruckig failed with {result}")
    duration = float(trajectory.duration)
    goal.check_duration(duration, "jerk-limited")
    check_position_extrema(trajectory.position_extrema, kinematics.limits.position_lower,
                           kinematics.limits.position_upper, goal.label, kinematics.joint_names)

    def evaluator(time: float):
        position, velocity, acceleration = trajectory.at_time(min(time, duration))
        return np.array(position), np.array(velocity), np.array(acceleration)

    n = len(t)
    q, qd, qdd = np.tile(q_goal, (n, 1)), np.zeros((n, kinematics.num_joints)), np.zeros((n, kinematics.num_joints))
    for k in range(n):
        if t[k] >= duration:
            break
        q[k], qd[k], qdd[k] = evaluator(float(t[k]))
    q[0], qd[0], qdd[0] = q0, 0.0, 0.0
    return goal.trajectory("ruckig", kinematics, config, q, qd, qdd, duration, evaluator)


def plan_toppra(kinematics: RobotKinematics, q0, X_goal: RigidTransform, *, config: PlannerConfig,
                num_steps: int = 100, sample_period: float = 0.01) -> PlannedTrajectory:
    """Time-optimal re-timing (toppra) of the IK'd task-space line under joint velocity and
    acceleration limits, from rest at q0 (n,) rad to rest at IK(X_goal).

    The path is a cubic spline through `path_waypoints` IK solutions along the same line the
    quintic planner follows, so the tool deviates from the exact line between waypoints only
    by the spline's interpolation error. We use the toppra package rather than Drake's
    multibody.optimization.Toppra because toppra returns the re-timed joint trajectory with
    its first and second time derivatives directly, while Drake's returns only s(t), to be
    composed with the path by hand.
    """
    import toppra
    import toppra.algorithm
    import toppra.constraint

    goal = _joint_space_goal("toppra", kinematics, q0, X_goal, config, num_steps, sample_period)
    t, q0, q_goal, waypoints = goal.t, goal.q0, goal.q_goal, goal.waypoints
    n = len(t)
    if np.max(np.abs(q_goal - q0)) == 0.0:  # nothing to re-time
        zeros = np.zeros((n, kinematics.num_joints))
        return PlannedTrajectory(planner="toppra", t=t, q=np.tile(q0, (n, 1)), qd=zeros, qdd=zeros.copy(),
                                 X_start=goal.X_start, X_goal=X_goal, q_goal=q_goal, duration=0.0,
                                 evaluator=lambda time: (q0.copy(), np.zeros(len(q0)), np.zeros(len(q0))))

    scale = 1.0 - config.toppra_limit_margin
    velocity = scale * config.velocity_scale * kinematics.limits.velocity
    acceleration = scale * np.asarray(config.acceleration_limits)
    path = toppra.SplineInterpolator(np.linspace(0.0, 1.0, len(waypoints)), waypoints)
    instance = toppra.algorithm.TOPPRA(
        [toppra.constraint.JointVelocityConstraint(np.column_stack([-velocity, velocity])),
         toppra.constraint.JointAccelerationConstraint(np.column_stack([-acceleration, acceleration]))],
        path, gridpoints=np.linspace(0.0, 1.0, config.toppra_gridpoints), parametrizer="ParametrizeConstAccel")
    trajectory = instance.compute_trajectory(0.0, 0.0)
    if trajectory is None:
        raise PlanningError(f"{goal.label}: toppra found no feasible time parameterization")
    duration = float(trajectory.duration)
    goal.check_duration(duration, "time-optimal")

    def evaluator(time: float):
        time = min(time, duration)
        return trajectory(time), trajectory(time, 1), trajectory(time, 2)

    q, qd, qdd = np.tile(q_goal, (n, 1)), np.zeros((n, kinematics.num_joints)), np.zeros((n, kinematics.num_joints))
    moving = t < duration
    q[moving] = trajectory(t[moving])
    qd[moving] = trajectory(t[moving], 1)
    qdd[moving] = trajectory(t[moving], 2)
    q[0], qd[0] = q0, 0.0
    return goal.trajectory("toppra", kinematics, config, q, qd, qdd, duration, evaluator)


_PLANNERS = {"quintic": plan_quintic, "ruckig": plan_ruckig, "toppra": plan_toppra}


def plan_trajectory(kinematics: RobotKinematics, q0, X_goal: RigidTransform, *, config: PlannerConfig,
                    num_steps: int = 100, sample_period: float = 0.01) -> PlannedTrajectory:
    """Plan from rest at q0 (n,) rad to rest at IK(X_goal) with the planner `config.kind`.

    Returns exactly num_steps + 1 samples at sample_period (s). Raises PlanningError (one line)
    when the goal is unreachable, near a singularity, or the plan violates a limit or cannot
    finish within num_steps * sample_period.
    """
    config.validate()
    return _PLANNERS[config.kind](kinematics, q0, X_goal, config=config, num_steps=num_steps,
                                  sample_period=sample_period)
