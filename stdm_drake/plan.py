"""Trajectory planners for the tracked task-space data protocol (paper section V.B.1).

Four predefined initial end-effector poses, final poses sampled near each, and a plan of
`num_steps` samples from rest to rest between them. Three planners, chosen by
`PlannerConfig.kind`:

- "quintic": straight line in position and geodesic (axis-angle) in orientation, both timed by
  s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5, mapped to joint space by inverse kinematics (IK)
  seeded with the previous sample; q_dot = J^-1 V and q_ddot = J^-1 (A - J_dot v).
- "ruckig": jerk-limited, time-synchronized joint-space point-to-point motion to the IK
  solution of the goal pose.
- "toppra": the IK'd task-space straight line as a joint-space path, re-timed time-optimally
  under joint velocity and acceleration limits.

Frames: every pose is the pose of `tool0` in the world frame. base_link is welded at the world
origin, so world = base_link; note that base_link_inertia (DH frame 0) is base_link rotated by
pi about z, so the arm stretched at q = 0 points along world +x ("in front of the robot").
Spatial vectors are ordered [angular; linear], measured and expressed in the world frame, for
the origin of tool0.

Joint order: shoulder_pan, shoulder_lift, elbow, wrist_1, wrist_2, wrist_3.
"""
import dataclasses
import logging
import math
import os
from typing import Callable

import numpy as np

os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")

from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix  # noqa: E402
from pydrake.multibody.inverse_kinematics import InverseKinematics  # noqa: E402
from pydrake.multibody.plant import MultibodyPlant  # noqa: E402
from pydrake.multibody.tree import JacobianWrtVariable  # noqa: E402
from pydrake.solvers import Solve  # noqa: E402

from stdm_drake.config import load_yaml_config  # noqa: E402
from stdm_drake.errors import InputError, PlanningError  # noqa: E402
from stdm_drake.robot import (  # noqa: E402
    JOINT_NAMES, NUM_JOINTS, TOOL_FRAME, TRAJECTORIES_DIR, PlantConfig, joint_limits, make_plant)

logger = logging.getLogger(__name__)

PLANNER_KINDS = ("quintic", "ruckig", "toppra")
DEFAULT_TRACKING_SPEC = TRAJECTORIES_DIR / "tracking.yaml"

# Peak of ds/dtau and of d2s/dtau2 for s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5.
_QUINTIC_PEAK_VELOCITY = 15.0 / 8.0
_QUINTIC_PEAK_ACCELERATION = 10.0 / math.sqrt(3.0)


# --------------------------------------------------------------------------------------------
# Configuration
# --------------------------------------------------------------------------------------------

@dataclasses.dataclass
class PlannerConfig:
    """How one rest-to-rest plan is made and which limits it must respect.

    kind: "quintic", "ruckig" or "toppra".
    duration_fraction: quintic: motion time T = max(duration_fraction * horizon, shortest T
        under the task-space limits below); ruckig: ruckig's minimum_duration =
        duration_fraction * horizon (0 gives the time-optimal jerk-limited motion); toppra:
        ignored (the re-timing is time-optimal). horizon = num_steps * sample_period (s).
    velocity_scale: joint velocity limit as a fraction of the published limits (0, 1].
    acceleration_limits: (6,) joint acceleration limits, rad/s^2 (none are published).
    jerk_limits: (6,) joint jerk limits for ruckig, rad/s^3.
    max_linear_speed, max_linear_acceleration: quintic task-space limits on the tool0 origin,
        m/s and m/s^2.
    max_angular_speed, max_angular_acceleration: quintic task-space limits on the tool
        rotation, rad/s and rad/s^2.
    ik_tolerance: IK convergence on both the position (m) and rotation (rad) error.
    ik_max_iterations: Newton iterations per IK solve.
    ik_damping: damped-least-squares factor; the damping is ik_damping * min(1, |error|), so
        it vanishes near convergence (plain Newton steps, quadratic convergence).
    ik_continuity_tolerance: largest allowed distance (rad, any joint) between an IK solution
        and its first-order prediction from the previous sample (catches branch flips).
    max_jacobian_condition: largest allowed 2-norm condition number of the 6x6 tool Jacobian
        along quintic and toppra paths (singularity guard).
    path_waypoints: IK waypoints along the task-space line for the toppra path and for the
        continuation that finds the goal configuration for ruckig.
    toppra_gridpoints: number of toppra discretization points along the path.
    toppra_limit_margin: toppra plans under (1 - margin) times the limits, so that its
        interpolation error stays inside the limits that are checked afterwards.
    limit_tolerance: relative slack when checking sampled velocities and accelerations against
        their limits (floating-point round-off only).
    """
    kind: str = "quintic"
    duration_fraction: float = 1.0
    velocity_scale: float = 0.5
    acceleration_limits: list[float] = dataclasses.field(
        default_factory=lambda: [4.0, 4.0, 5.0, 5.0, 5.0, 5.0])
    jerk_limits: list[float] = dataclasses.field(
        default_factory=lambda: [30.0, 30.0, 40.0, 60.0, 60.0, 60.0])
    max_linear_speed: float = 0.6
    max_linear_acceleration: float = 2.0
    max_angular_speed: float = 1.0
    max_angular_acceleration: float = 3.0
    ik_tolerance: float = 1e-10
    ik_max_iterations: int = 50
    ik_damping: float = 1e-3
    ik_continuity_tolerance: float = 0.02
    max_jacobian_condition: float = 100.0
    path_waypoints: int = 51
    toppra_gridpoints: int = 201
    toppra_limit_margin: float = 0.02
    limit_tolerance: float = 1e-9

    def validate(self) -> None:
        """Raise InputError (one line) on a malformed configuration."""
        if self.kind not in PLANNER_KINDS:
            raise InputError(f"planner kind must be one of {', '.join(PLANNER_KINDS)}, got {self.kind!r}")
        _require(0.0 <= self.duration_fraction <= 1.0, "duration_fraction must be in [0, 1]",
                 self.duration_fraction)
        _require(0.0 < self.velocity_scale <= 1.0, "velocity_scale must be in (0, 1]", self.velocity_scale)
        for name in ("acceleration_limits", "jerk_limits"):
            values = getattr(self, name)
            _require(len(values) == NUM_JOINTS and all(math.isfinite(v) and v > 0 for v in values),
                     f"{name} must be {NUM_JOINTS} positive numbers", values)
        for name in ("max_linear_speed", "max_linear_acceleration", "max_angular_speed",
                     "max_angular_acceleration", "ik_tolerance", "ik_continuity_tolerance"):
            value = getattr(self, name)
            _require(math.isfinite(value) and value > 0, f"{name} must be positive", value)
        _require(self.ik_damping >= 0, "ik_damping must be >= 0", self.ik_damping)
        _require(self.ik_max_iterations >= 1, "ik_max_iterations must be >= 1", self.ik_max_iterations)
        _require(self.max_jacobian_condition > 1, "max_jacobian_condition must be > 1",
                 self.max_jacobian_condition)
        _require(self.path_waypoints >= 2, "path_waypoints must be >= 2", self.path_waypoints)
        _require(self.toppra_gridpoints >= 2, "toppra_gridpoints must be >= 2", self.toppra_gridpoints)
        _require(0.0 <= self.toppra_limit_margin < 1.0, "toppra_limit_margin must be in [0, 1)",
                 self.toppra_limit_margin)
        _require(0.0 <= self.limit_tolerance < 0.1, "limit_tolerance must be in [0, 0.1)",
                 self.limit_tolerance)


@dataclasses.dataclass
class InitialPose:
    """One predefined initial tool0 pose in the world frame.

    xyz: (3,) position, m. rpy: (3,) roll-pitch-yaw, rad (Drake's RollPitchYaw convention).
    q_seed: (6,) joint-space IK seed, rad; it fixes the arm's branch (elbow up, wrist side).
    """
    xyz: list[float] = dataclasses.field(default_factory=list)
    rpy: list[float] = dataclasses.field(default_factory=list)
    q_seed: list[float] = dataclasses.field(default_factory=list)

    def pose(self) -> RigidTransform:
        return RigidTransform(RollPitchYaw(np.asarray(self.rpy, float)), np.asarray(self.xyz, float))


@dataclasses.dataclass
class TaskSpaceSamplingConfig:
    """Where the plans start and how their final poses are sampled.

    initial_poses: the predefined initial poses (4 in the paper).
    position_offset: (3,) half-widths (m) of the box, centered on the initial position and
        aligned with the world axes, from which final positions are drawn uniformly.
    orientation_max_angle: final orientation = exp(angle * axis) * initial orientation (world
        frame) with axis uniform on the sphere and angle uniform in [0, this], rad.
    num_final_per_initial: final poses (plans) per initial pose (25 in the paper).
    num_steps: steps per plan N; a plan has N + 1 samples (100 in the paper).
    max_resample_attempts: a rejected final pose is redrawn at most this many times; then
        sample_task_plans raises PlanningError naming the initial pose.
    """
    initial_poses: list[InitialPose] = dataclasses.field(default_factory=list)
    position_offset: list[float] = dataclasses.field(default_factory=lambda: [0.15, 0.15, 0.15])
    orientation_max_angle: float = 0.3
    num_final_per_initial: int = 25
    num_steps: int = 100
    max_resample_attempts: int = 20

    def validate(self) -> None:
        """Raise InputError (one line) on a malformed configuration."""
        _require(len(self.initial_poses) >= 1, "initial_poses must list at least one pose",
                 len(self.initial_poses))
        for index, pose in enumerate(self.initial_poses):
            for name, size in (("xyz", 3), ("rpy", 3), ("q_seed", NUM_JOINTS)):
                values = getattr(pose, name)
                _require(len(values) == size and all(math.isfinite(v) for v in values),
                         f"initial_poses[{index}].{name} must be {size} finite numbers", values)
        _require(len(self.position_offset) == 3 and all(
            math.isfinite(v) and v >= 0 for v in self.position_offset),
            "position_offset must be 3 non-negative numbers (m)", self.position_offset)
        _require(0.0 <= self.orientation_max_angle <= math.pi,
                 "orientation_max_angle must be in [0, pi] rad", self.orientation_max_angle)
        _require(self.num_final_per_initial >= 1, "num_final_per_initial must be >= 1",
                 self.num_final_per_initial)
        _require(self.num_steps >= 1, "num_steps must be >= 1", self.num_steps)
        _require(self.max_resample_attempts >= 0, "max_resample_attempts must be >= 0",
                 self.max_resample_attempts)


@dataclasses.dataclass
class TrackingSpec:
    """Schema of trajectories/tracking*.yaml: the sampling protocol and the planner."""
    sampling: TaskSpaceSamplingConfig = dataclasses.field(default_factory=TaskSpaceSamplingConfig)
    planner: PlannerConfig = dataclasses.field(default_factory=PlannerConfig)


def _require(condition: bool, message: str, value) -> None:
    if not condition:
        raise InputError(f"{message}, got {value!r}")


def load_tracking_spec(path: str | os.PathLike = DEFAULT_TRACKING_SPEC, *,
                       planner_kind: str | None = None) -> tuple[TaskSpaceSamplingConfig, PlannerConfig]:
    """Load and validate a tracking spec YAML (top-level keys `sampling` and `planner`).

    planner_kind: if given, overrides `planner.kind` (same poses and limits, other planner).
    Raises InputError, naming the file, on a missing or malformed file, unknown keys, wrong
    types or invalid values.
    """
    spec = load_yaml_config(path, TrackingSpec, what="tracking spec")
    if planner_kind is not None:
        spec.planner = dataclasses.replace(spec.planner, kind=planner_kind)
    for section in ("planner", "sampling"):
        try:
            getattr(spec, section).validate()
        except InputError as error:
            raise InputError(f"{path}: {section}: {error}") from None
    return spec.sampling, spec.planner


# --------------------------------------------------------------------------------------------
# Kinematics
# --------------------------------------------------------------------------------------------

def _skew(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def rotation_exp(w: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of the rotation vector w (3,) rad (Rodrigues' formula)."""
    angle = float(np.linalg.norm(w))
    W = _skew(w)
    if angle < 1e-12:
        return np.eye(3) + W
    return np.eye(3) + (math.sin(angle) / angle) * W + ((1.0 - math.cos(angle)) / angle**2) * (W @ W)


def rotation_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) rad of the rotation matrix R (3, 3); angle in [0, pi]."""
    vee = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    sin = float(np.linalg.norm(vee))
    cos = max(-1.0, min(1.0, 0.5 * (float(np.trace(R)) - 1.0)))
    angle = math.atan2(sin, cos)
    if angle > math.pi - 1e-6:  # near pi the skew part vanishes: use Drake's robust conversion
        angle_axis = RotationMatrix(R).ToAngleAxis()
        return angle_axis.axis() * angle_axis.angle()
    if sin == 0.0:
        return np.zeros(3)
    return vee * (angle / sin)


def pose_text(X: RigidTransform) -> str:
    """Compact one-line description of a pose: xyz (m) and roll-pitch-yaw (rad)."""
    xyz = ", ".join(f"{v:.3f}" for v in X.translation())
    rpy = ", ".join(f"{v:.3f}" for v in RollPitchYaw(X.rotation()).vector())
    return f"xyz=({xyz}) m rpy=({rpy}) rad"


class RobotKinematics:
    """Forward/inverse kinematics of tool0 on a bare UR-10 plant (poses in the world frame).

    plant: a finalized MultibodyPlant holding the UR-10 (default: make_plant with
    time_step=0). The object owns one plant context, so it is not thread-safe.
    """

    def __init__(self, plant: MultibodyPlant | None = None):
        if plant is None:
            plant, _ = make_plant(PlantConfig(time_step=0.0))
        if plant.num_positions() != NUM_JOINTS or plant.num_velocities() != NUM_JOINTS:
            raise InputError(f"RobotKinematics needs the {NUM_JOINTS}-joint UR-10 plant, got "
                             f"{plant.num_positions()} positions")
        self.plant = plant
        self.context = plant.CreateDefaultContext()
        self.tool_frame = plant.GetFrameByName(TOOL_FRAME)
        self.world_frame = plant.world_frame()
        self.limits = joint_limits(plant)
        self._origin = np.zeros(3)
        # Reach bound: the distance between consecutive joint origins is constant, so tool0 is
        # never farther from the shoulder (on the pan axis) than the sum of those distances.
        self._set_state(np.zeros(NUM_JOINTS))
        points = [plant.GetJointByName(name).frame_on_child().CalcPoseInWorld(self.context).translation()
                  for name in JOINT_NAMES[1:]]
        points.append(self.tool_frame.CalcPoseInWorld(self.context).translation())
        self.shoulder = points[0].copy()
        self.reach = float(sum(np.linalg.norm(b - a) for a, b in zip(points[:-1], points[1:])))

    def check_reachable(self, X_goal: RigidTransform) -> None:
        """Raise PlanningError if the tool0 position of X_goal is beyond the arm's reach bound."""
        problem = self._reach_problem(X_goal)
        if problem:
            raise PlanningError(f"pose {pose_text(X_goal)} is {problem}")

    def _reach_problem(self, X_goal: RigidTransform) -> str:
        distance = float(np.linalg.norm(X_goal.translation() - self.shoulder))
        if distance <= self.reach:
            return ""
        return (f"out of reach: {distance:.3f} m from the shoulder, more than the arm's {self.reach:.3f} m "
                f"by {distance - self.reach:.3f} m")

    def _set_state(self, q: np.ndarray, v: np.ndarray | None = None) -> None:
        self.plant.SetPositions(self.context, q)
        if v is not None:
            self.plant.SetVelocities(self.context, v)

    def tool_pose(self, q: np.ndarray) -> RigidTransform:
        """Pose of tool0 in the world frame at joint positions q (6,) rad."""
        self._set_state(q)
        return self.plant.CalcRelativeTransform(self.context, self.world_frame, self.tool_frame)

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """Spatial velocity Jacobian (6, 6) of the tool0 origin: [omega; v] in world = J q_dot."""
        self._set_state(q)
        return self.plant.CalcJacobianSpatialVelocity(
            self.context, JacobianWrtVariable.kV, self.tool_frame, self._origin,
            self.world_frame, self.world_frame)

    def bias_acceleration(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Bias spatial acceleration (6,) J_dot v = [alpha; a] - J q_ddot of tool0, world frame."""
        self._set_state(q, v)
        bias = self.plant.CalcBiasSpatialAcceleration(
            self.context, JacobianWrtVariable.kV, self.tool_frame, self._origin,
            self.world_frame, self.world_frame)
        return np.concatenate([bias.rotational(), bias.translational()])

    def pose_error(self, X_goal: RigidTransform, q: np.ndarray) -> np.ndarray:
        """Error (6,) [rotation vector of R_goal R^T (rad); p_goal - p (m)] in the world frame."""
        X = self.tool_pose(q)
        rotation = rotation_log(X_goal.rotation().matrix() @ X.rotation().matrix().T)
        return np.concatenate([rotation, X_goal.translation() - X.translation()])

    def inverse_kinematics(self, X_goal: RigidTransform, q_seed: np.ndarray, *,
                           tolerance: float = 1e-10, max_iterations: int = 50,
                           damping: float = 1e-3, max_step: float = 0.5) -> np.ndarray:
        """Joint positions q (6,) rad with tool_pose(q) = X_goal, by damped Newton steps from q_seed.

        Converges when both the rotation error (rad) and the position error (m) are below
        `tolerance`; each step is J^T (J J^T + lambda^2 I)^-1 e with lambda = damping *
        min(1, |e|), scaled down to at most `max_step` rad on any joint. Raises PlanningError
        if it does not converge or the solution is outside the joint position limits.
        """
        q = np.array(q_seed, dtype=float).reshape(NUM_JOINTS)
        for _ in range(max_iterations + 1):
            error = self.pose_error(X_goal, q)
            rotation_error = float(np.linalg.norm(error[:3]))
            position_error = float(np.linalg.norm(error[3:]))
            if rotation_error <= tolerance and position_error <= tolerance:
                self.check_position_limits(q, what=f"IK solution for pose {pose_text(X_goal)}")
                return q
            J = self.jacobian(q)
            lam = damping * min(1.0, float(np.linalg.norm(error)))
            step = J.T @ np.linalg.solve(J @ J.T + lam**2 * np.eye(6), error)
            largest = float(np.max(np.abs(step)))
            if largest > max_step:
                step *= max_step / largest
            q = q + step
        distance = float(np.linalg.norm(X_goal.translation() - self.shoulder))
        raise PlanningError(
            f"inverse kinematics failed for pose {pose_text(X_goal)}: residual {position_error:.3g} m, "
            f"{rotation_error:.3g} rad after {max_iterations} iterations (target {distance:.3f} m "
            f"from the shoulder, reach {self.reach:.3f} m; unreachable or too far from the seed)")

    def inverse_kinematics_global(self, X_goal: RigidTransform, q_seed: np.ndarray, *,
                                  tolerance: float = 1e-10) -> np.ndarray:
        """IK (6,) rad by Drake's InverseKinematics + Solve from q_seed (cost |q - q_seed|^2),
        then polished by inverse_kinematics(). For poses whose seed is only roughly known.
        """
        q_seed = np.array(q_seed, dtype=float).reshape(NUM_JOINTS)
        ik = InverseKinematics(self.plant, with_joint_limits=True)
        position = X_goal.translation()
        slack = 1e-6
        ik.AddPositionConstraint(self.tool_frame, self._origin, self.world_frame,
                                 position - slack, position + slack)
        ik.AddOrientationConstraint(self.world_frame, X_goal.rotation(), self.tool_frame,
                                    RotationMatrix(), slack)
        ik.prog().AddQuadraticErrorCost(np.eye(NUM_JOINTS), q_seed, ik.q())
        ik.prog().SetInitialGuess(ik.q(), q_seed)
        result = Solve(ik.prog())
        if not result.is_success():
            raise PlanningError(f"inverse kinematics (Drake {result.get_solver_id().name()}) found no "
                                f"solution for pose {pose_text(X_goal)}: {result.get_solution_result()}")
        return self.inverse_kinematics(X_goal, result.GetSolution(ik.q()), tolerance=tolerance)

    def check_position_limits(self, q: np.ndarray, *, what: str) -> None:
        """Raise PlanningError naming the joint if q (6,) rad is outside the position limits."""
        lower, upper = self.limits.position_lower, self.limits.position_upper
        for j in range(NUM_JOINTS):
            if q[j] < lower[j] or q[j] > upper[j]:
                bound, excess = (lower[j], lower[j] - q[j]) if q[j] < lower[j] else (upper[j], q[j] - upper[j])
                raise PlanningError(f"{what}: {JOINT_NAMES[j]} at {q[j]:.4f} rad is outside its position "
                                    f"limit {bound:.4f} rad by {excess:.4f} rad")


# --------------------------------------------------------------------------------------------
# Planned trajectory
# --------------------------------------------------------------------------------------------

@dataclasses.dataclass(eq=False)
class PlannedTrajectory:
    """A rest-to-rest joint trajectory sampled at a fixed period.

    planner: "quintic", "ruckig" or "toppra".
    t: (N+1,) s, t[k] = k * sample_period. q: (N+1, 6) rad. qd: (N+1, 6) rad/s.
    qdd: (N+1, 6) rad/s^2 (the desired accelerations used as derivative targets).
    X_start, X_goal: tool0 poses in the world frame at q[0] and q[-1].
    q_goal: (6,) rad, the IK solution of X_goal where the plan ends (q[-1] == q_goal).
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
        """Exact (q, qd, qdd), each (6,), at time t (s); clamped to [0, N * sample_period]."""
        t = min(max(float(t), 0.0), float(self.t[-1]))
        if t >= self.duration:
            zero = np.zeros(NUM_JOINTS)
            return self.q_goal.copy(), zero, zero.copy()
        return self.evaluator(t)


# --------------------------------------------------------------------------------------------
# Planners
# --------------------------------------------------------------------------------------------

@dataclasses.dataclass
class _TaskLine:
    """Straight line in position and geodesic in orientation from X_start to X_goal (world)."""
    X_start: RigidTransform
    X_goal: RigidTransform

    def __post_init__(self):
        self.p0 = self.X_start.translation()
        self.R0 = self.X_start.rotation().matrix()
        self.dp = self.X_goal.translation() - self.p0
        self.w = rotation_log(self.X_goal.rotation().matrix() @ self.R0.T)
        self.tangent = np.concatenate([self.w, self.dp])  # d[omega; v]/ds, world frame

    def pose(self, s: float) -> RigidTransform:
        if s >= 1.0:
            return self.X_goal
        if s <= 0.0:
            return self.X_start
        return RigidTransform(RotationMatrix(rotation_exp(s * self.w) @ self.R0), self.p0 + s * self.dp)


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
    q0 = np.array(q0, dtype=float)
    if q0.shape != (NUM_JOINTS,) or not np.all(np.isfinite(q0)):
        raise InputError(f"start configuration must be {NUM_JOINTS} finite joint positions (rad), got {q0!r}")
    kinematics.check_position_limits(q0, what="start configuration")
    return q0


def _checked_jacobian(kinematics: RobotKinematics, q: np.ndarray, config: PlannerConfig,
                      label: str, where: str) -> np.ndarray:
    J = kinematics.jacobian(q)
    condition = float(np.linalg.cond(J))
    if not condition <= config.max_jacobian_condition:
        raise PlanningError(f"{label}: near a singularity {where}: Jacobian condition number "
                            f"{condition:.3g} > {config.max_jacobian_condition:.3g}")
    return J


def _ik_step(kinematics: RobotKinematics, X: RigidTransform, q_predicted: np.ndarray,
             config: PlannerConfig, label: str, where: str) -> np.ndarray:
    """IK seeded with a first-order prediction, with the continuity check."""
    try:
        q = kinematics.inverse_kinematics(X, q_predicted, tolerance=config.ik_tolerance,
                                          max_iterations=config.ik_max_iterations, damping=config.ik_damping)
    except PlanningError as error:
        raise PlanningError(f"{label}: {where}: {error}") from None
    jump = np.abs(q - q_predicted)
    j = int(np.argmax(jump))
    if jump[j] > config.ik_continuity_tolerance:
        raise PlanningError(f"{label}: IK discontinuity {where}: {JOINT_NAMES[j]} jumps {jump[j]:.4f} rad "
                            f"from its prediction (> {config.ik_continuity_tolerance} rad; branch switch)")
    return q


def _ik_along_line(kinematics: RobotKinematics, q0: np.ndarray, line: _TaskLine, ss: np.ndarray,
                   config: PlannerConfig, label: str) -> np.ndarray:
    """Joint waypoints (M, 6) rad along the task-space line at path parameters ss (M,), ss[0] = 0."""
    qs = np.empty((len(ss), NUM_JOINTS))
    qs[0] = q0
    for k in range(1, len(ss)):
        J = _checked_jacobian(kinematics, qs[k - 1], config, label, f"at path parameter s={ss[k - 1]:.3f}")
        q_predicted = qs[k - 1] + np.linalg.solve(J, line.tangent * (ss[k] - ss[k - 1]))
        qs[k] = _ik_step(kinematics, line.pose(ss[k]), q_predicted, config, label,
                         f"at path parameter s={ss[k]:.3f}")
    _checked_jacobian(kinematics, qs[-1], config, label, "at the goal")
    return qs


def _check_limits(kinematics: RobotKinematics, config: PlannerConfig, label: str, t: np.ndarray,
                  q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> None:
    """Raise PlanningError on the worst joint position/velocity/acceleration limit violation.

    t: (N+1,) s; q, qd, qdd: (N+1, 6). Velocity and acceleration get a relative slack of
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
            worst = (relative[k, j], f"{label}: {JOINT_NAMES[j]} {name} {values[k, j]:.4g} {unit} exceeds its "
                                     f"limit {limit[j]:.4g} {unit} by {excess[k, j]:.3g} {unit} at t={t[k]:.3f} s")
    if worst is not None:
        raise PlanningError(worst[1])


def _plan_label(kind: str, X_goal: RigidTransform) -> str:
    return f"{kind} plan to goal pose {pose_text(X_goal)}"


def _check_goal_reachable(kinematics: RobotKinematics, X_goal: RigidTransform, label: str) -> None:
    problem = kinematics._reach_problem(X_goal)
    if problem:
        raise PlanningError(f"{label}: {problem}")


def check_position_extrema(extrema, lower: np.ndarray, upper: np.ndarray, label: str) -> None:
    """Raise PlanningError if a ruckig trajectory's per-joint position extrema (its
    `position_extrema`: objects with .min/.max, rad) leave [lower, upper] (6,) rad."""
    for j, extremum in enumerate(extrema):
        for value, bound, excess in ((extremum.max, upper[j], extremum.max - upper[j]),
                                     (extremum.min, lower[j], lower[j] - extremum.min)):
            if excess > 0:
                raise PlanningError(f"{label}: {JOINT_NAMES[j]} reaches {value:.4f} rad, outside its position "
                                    f"limit {bound:.4f} rad by {excess:.4f} rad")


def _quintic_duration(line: _TaskLine, config: PlannerConfig, horizon: float, label: str) -> float:
    distance = float(np.linalg.norm(line.dp))
    angle = float(np.linalg.norm(line.w))
    shortest = max(
        _QUINTIC_PEAK_VELOCITY * distance / config.max_linear_speed,
        math.sqrt(_QUINTIC_PEAK_ACCELERATION * distance / config.max_linear_acceleration),
        _QUINTIC_PEAK_VELOCITY * angle / config.max_angular_speed,
        math.sqrt(_QUINTIC_PEAK_ACCELERATION * angle / config.max_angular_acceleration),
    )
    if shortest > horizon * (1.0 + 1e-12):
        raise PlanningError(f"{label}: the move ({distance:.3f} m, {angle:.3f} rad) needs at least {shortest:.3f} s "
                            f"under the task-space limits, longer than the {horizon:.3f} s horizon")
    return min(max(config.duration_fraction * horizon, shortest), horizon)


def plan_quintic(kinematics: RobotKinematics, q0, X_goal: RigidTransform, *, config: PlannerConfig,
                 num_steps: int = 100, sample_period: float = 0.01) -> PlannedTrajectory:
    """Quintic-timed task-space line (position) and geodesic (orientation), mapped by IK.

    q0: (6,) rad start at rest. Returns num_steps + 1 samples; q̇ = J^-1 V_d and
    q̈ = J^-1 (A_d - J̇ q̇) from the 6x6 tool Jacobian and bias acceleration.
    """
    config.validate()
    t = _horizon_times(num_steps, sample_period)
    q0 = _start_configuration(kinematics, q0)
    label = _plan_label("quintic", X_goal)
    _check_goal_reachable(kinematics, X_goal, label)
    X_start = kinematics.tool_pose(q0)
    line = _TaskLine(X_start, X_goal)
    _checked_jacobian(kinematics, q0, config, label, "at the start")
    T = _quintic_duration(line, config, float(t[-1]), label)

    def state(time: float, q_predicted: np.ndarray, where: str):
        tau = time / T if T > 0 else 1.0
        s, ds, dds = _quintic_scaling(tau)
        q = _ik_step(kinematics, line.pose(s if tau < 1.0 else 1.0), q_predicted, config, label, where)
        J = _checked_jacobian(kinematics, q, config, label, where)
        if tau >= 1.0:
            return q, np.zeros(NUM_JOINTS), np.zeros(NUM_JOINTS)
        qd = np.linalg.solve(J, line.tangent * (ds / T))
        qdd = np.linalg.solve(J, line.tangent * (dds / T**2) - kinematics.bias_acceleration(q, qd))
        return q, qd, qdd

    n = len(t)
    q, qd, qdd = np.empty((n, NUM_JOINTS)), np.zeros((n, NUM_JOINTS)), np.zeros((n, NUM_JOINTS))
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
        q_seed = np.array([np.interp(time, t, q[:, j]) for j in range(NUM_JOINTS)])
        return state(time, q_seed, f"at t={time:.4f} s")

    return PlannedTrajectory(planner="quintic", t=t, q=q, qd=qd, qdd=qdd, X_start=X_start, X_goal=X_goal,
                             q_goal=q_goal, duration=T, evaluator=evaluator)


def _goal_configuration(kinematics: RobotKinematics, q0: np.ndarray, X_goal: RigidTransform,
                        config: PlannerConfig, label: str) -> tuple[RigidTransform, _TaskLine, np.ndarray]:
    X_start = kinematics.tool_pose(q0)
    line = _TaskLine(X_start, X_goal)
    ss = np.linspace(0.0, 1.0, config.path_waypoints)
    return X_start, line, _ik_along_line(kinematics, q0, line, ss, config, label)


def plan_ruckig(kinematics: RobotKinematics, q0, X_goal: RigidTransform, *, config: PlannerConfig,
                num_steps: int = 100, sample_period: float = 0.01) -> PlannedTrajectory:
    """Jerk-limited joint-space point-to-point motion (ruckig) from q0 (6,) rad to IK(X_goal).

    The goal configuration is found by IK continuation along the task-space line, so all three
    planners end in the same configuration for the same goal. ruckig (community edition)
    ignores position limits, so the trajectory's position extrema are checked here.
    """
    import ruckig

    config.validate()
    t = _horizon_times(num_steps, sample_period)
    horizon = float(t[-1])
    q0 = _start_configuration(kinematics, q0)
    label = _plan_label("ruckig", X_goal)
    _check_goal_reachable(kinematics, X_goal, label)
    X_start, _, waypoints = _goal_configuration(kinematics, q0, X_goal, config, label)
    q_goal = waypoints[-1].copy()

    inp = ruckig.InputParameter(NUM_JOINTS)
    inp.current_position = q0.tolist()
    inp.current_velocity = [0.0] * NUM_JOINTS
    inp.current_acceleration = [0.0] * NUM_JOINTS
    inp.target_position = q_goal.tolist()
    inp.target_velocity = [0.0] * NUM_JOINTS
    inp.target_acceleration = [0.0] * NUM_JOINTS
    inp.max_velocity = (config.velocity_scale * kinematics.limits.velocity).tolist()
    inp.max_acceleration = list(config.acceleration_limits)
    inp.max_jerk = list(config.jerk_limits)
    if config.duration_fraction > 0:
        inp.minimum_duration = config.duration_fraction * horizon
    trajectory = ruckig.Trajectory(NUM_JOINTS)
    result = ruckig.Ruckig(NUM_JOINTS).calculate(inp, trajectory)
    if result not in (ruckig.Result.Working, ruckig.Result.Finished):
        raise PlanningError(f"{label}: ruckig failed with {result}")
    duration = float(trajectory.duration)
    if duration > horizon * (1.0 + 1e-12):
        raise PlanningError(f"{label}: the jerk-limited motion needs {duration:.3f} s, longer than the "
                            f"{horizon:.3f} s horizon")
    check_position_extrema(trajectory.position_extrema, kinematics.limits.position_lower,
                           kinematics.limits.position_upper, label)

    def evaluator(time: float):
        position, velocity, acceleration = trajectory.at_time(min(time, duration))
        return np.array(position), np.array(velocity), np.array(acceleration)

    n = len(t)
    q, qd, qdd = np.tile(q_goal, (n, 1)), np.zeros((n, NUM_JOINTS)), np.zeros((n, NUM_JOINTS))
    for k in range(n):
        if t[k] >= duration:
            break
        q[k], qd[k], qdd[k] = evaluator(float(t[k]))
    q[0], qd[0], qdd[0] = q0, 0.0, 0.0
    _check_limits(kinematics, config, label, t, q, qd, qdd)
    return PlannedTrajectory(planner="ruckig", t=t, q=q, qd=qd, qdd=qdd, X_start=X_start, X_goal=X_goal,
                             q_goal=q_goal, duration=duration, evaluator=evaluator)


def plan_toppra(kinematics: RobotKinematics, q0, X_goal: RigidTransform, *, config: PlannerConfig,
                num_steps: int = 100, sample_period: float = 0.01) -> PlannedTrajectory:
    """Time-optimal re-timing (toppra) of the IK'd task-space line under joint velocity and
    acceleration limits, from rest at q0 (6,) rad to rest at IK(X_goal).

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

    config.validate()
    t = _horizon_times(num_steps, sample_period)
    horizon = float(t[-1])
    q0 = _start_configuration(kinematics, q0)
    label = _plan_label("toppra", X_goal)
    _check_goal_reachable(kinematics, X_goal, label)
    X_start, _, waypoints = _goal_configuration(kinematics, q0, X_goal, config, label)
    q_goal = waypoints[-1].copy()
    n = len(t)
    if np.max(np.abs(q_goal - q0)) == 0.0:  # nothing to re-time
        zeros = np.zeros((n, NUM_JOINTS))
        return PlannedTrajectory(planner="toppra", t=t, q=np.tile(q0, (n, 1)), qd=zeros, qdd=zeros.copy(),
                                 X_start=X_start, X_goal=X_goal, q_goal=q_goal, duration=0.0,
                                 evaluator=lambda time: (q0.copy(), np.zeros(NUM_JOINTS), np.zeros(NUM_JOINTS)))

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
        raise PlanningError(f"{label}: toppra found no feasible time parameterization")
    duration = float(trajectory.duration)
    if duration > horizon * (1.0 + 1e-12):
        raise PlanningError(f"{label}: the time-optimal motion needs {duration:.3f} s, longer than the "
                            f"{horizon:.3f} s horizon")

    def evaluator(time: float):
        time = min(time, duration)
        return trajectory(time), trajectory(time, 1), trajectory(time, 2)

    q, qd, qdd = np.tile(q_goal, (n, 1)), np.zeros((n, NUM_JOINTS)), np.zeros((n, NUM_JOINTS))
    moving = t < duration
    q[moving] = trajectory(t[moving])
    qd[moving] = trajectory(t[moving], 1)
    qdd[moving] = trajectory(t[moving], 2)
    q[0], qd[0] = q0, 0.0
    _check_limits(kinematics, config, label, t, q, qd, qdd)
    return PlannedTrajectory(planner="toppra", t=t, q=q, qd=qd, qdd=qdd, X_start=X_start, X_goal=X_goal,
                             q_goal=q_goal, duration=duration, evaluator=evaluator)


_PLANNERS = {"quintic": plan_quintic, "ruckig": plan_ruckig, "toppra": plan_toppra}


def plan_trajectory(kinematics: RobotKinematics, q0, X_goal: RigidTransform, *, config: PlannerConfig,
                    num_steps: int = 100, sample_period: float = 0.01) -> PlannedTrajectory:
    """Plan from rest at q0 (6,) rad to rest at IK(X_goal) with the planner `config.kind`.

    Returns exactly num_steps + 1 samples at sample_period (s). Raises PlanningError (one line)
    when the goal is unreachable, near a singularity, or the plan violates a limit or cannot
    finish within num_steps * sample_period.
    """
    config.validate()
    return _PLANNERS[config.kind](kinematics, q0, X_goal, config=config, num_steps=num_steps,
                                  sample_period=sample_period)


# --------------------------------------------------------------------------------------------
# Sampling the data protocol
# --------------------------------------------------------------------------------------------

def initial_configuration(kinematics: RobotKinematics, pose: InitialPose, config: PlannerConfig) -> np.ndarray:
    """IK (6,) rad of an initial pose from its configured seed (Newton first, Drake IK as fallback)."""
    X = pose.pose()
    q_seed = np.asarray(pose.q_seed, dtype=float)
    try:
        return kinematics.inverse_kinematics(X, q_seed, tolerance=config.ik_tolerance,
                                             max_iterations=config.ik_max_iterations, damping=config.ik_damping)
    except PlanningError:
        return kinematics.inverse_kinematics_global(X, q_seed, tolerance=config.ik_tolerance)


def sample_final_pose(X_initial: RigidTransform, sampling_config: TaskSpaceSamplingConfig,
                      rng: np.random.Generator) -> RigidTransform:
    """A final pose near X_initial: uniform position offset in the box, rotation by an angle
    uniform in [0, orientation_max_angle] about a uniformly random world axis (7 draws)."""
    offset = rng.uniform(-1.0, 1.0, size=3) * np.asarray(sampling_config.position_offset, dtype=float)
    axis = rng.standard_normal(3)
    axis /= max(float(np.linalg.norm(axis)), 1e-12)
    angle = rng.uniform(0.0, sampling_config.orientation_max_angle)
    R = rotation_exp(angle * axis) @ X_initial.rotation().matrix()
    return RigidTransform(RotationMatrix(R), X_initial.translation() + offset)


def sample_task_plans(kinematics: RobotKinematics, sampling_config: TaskSpaceSamplingConfig,
                      planner_config: PlannerConfig, sample_period: float, rng: np.random.Generator, *,
                      is_collision_free: Callable[[np.ndarray], bool] | None = None,
                      on_reject: Callable[[str], None] | None = None) -> list[tuple[int, PlannedTrajectory]]:
    """Plans for every initial pose and num_final_per_initial final poses sampled near it.

    Returns [(initial_pose_index, PlannedTrajectory)] ordered by initial pose, each plan with
    num_steps + 1 samples at sample_period (s). Deterministic for a given rng state. A final pose
    whose plan raises PlanningError, or with a sample q (6,) rad for which is_collision_free(q)
    is False, is rejected: its one-line reason goes to on_reject (default: logged as a warning)
    and the pose is redrawn, up to max_resample_attempts times, after which PlanningError names
    the initial pose. An unreachable initial pose raises PlanningError at once.
    """
    sampling_config.validate()
    planner_config.validate()
    report = on_reject if on_reject is not None else logger.warning
    plans: list[tuple[int, PlannedTrajectory]] = []
    for index, initial in enumerate(sampling_config.initial_poses):
        X_initial = initial.pose()
        what = f"initial pose {index} ({pose_text(X_initial)})"
        try:
            q_initial = initial_configuration(kinematics, initial, planner_config)
        except PlanningError as error:
            raise PlanningError(f"{what} is unreachable: {error}") from None
        if is_collision_free is not None and not is_collision_free(q_initial):
            raise PlanningError(f"{what} is in self-collision at q={np.round(q_initial, 3).tolist()} rad")
        for plan_index in range(sampling_config.num_final_per_initial):
            reason = ""
            for attempt in range(sampling_config.max_resample_attempts + 1):
                X_goal = sample_final_pose(X_initial, sampling_config, rng)
                try:
                    plan = plan_trajectory(kinematics, q_initial, X_goal, config=planner_config,
                                           num_steps=sampling_config.num_steps, sample_period=sample_period)
                    if is_collision_free is not None:
                        for k, q in enumerate(plan.q):
                            if not is_collision_free(q):
                                raise PlanningError(f"{plan.planner} plan to goal pose {pose_text(X_goal)}: "
                                                    f"self-collision at t={plan.t[k]:.3f} s")
                except PlanningError as error:
                    reason = str(error)
                    report(f"{what}, plan {plan_index}, attempt {attempt + 1}: rejected, resampling: {reason}")
                    continue
                plans.append((index, plan))
                break
            else:
                raise PlanningError(f"{what}: no feasible final pose for plan {plan_index} after "
                                    f"{sampling_config.max_resample_attempts + 1} attempts; last: {reason}")
    return plans
