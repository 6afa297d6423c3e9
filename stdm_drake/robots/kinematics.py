"""Kinematics of a robot's tool frame: SO(3) exponential and logarithm, forward kinematics, Jacobians,
inverse kinematics (damped Newton, with Drake's InverseKinematics as the global fallback), and the
task coordinates that make the tracking planners work for any arm of 6 or more joints.

Frames: every pose is the pose of the robot's tool frame (the UR-10's tool0) in the world frame.
Spatial vectors are ordered [angular; linear], measured and expressed in the world frame, for the
origin of the tool frame. Joint order: the robot's arm joints (the UR-10: shoulder_pan, shoulder_lift,
elbow, wrist_1, wrist_2, wrist_3).

Task coordinates. A tool pose fixes 6 coordinates; an arm of n > 6 joints has n - 6 more degrees of
freedom (the Panda's elbow can swing about the shoulder-wrist line with the tool still). The planners
make the motion unique, and its derivatives exact, by adding the positions of n - 6 "redundant" joints
to the task: y(q) = [tool pose; q_r], with the square task Jacobian [J; S] (S picks the redundant
joints). Which joints: those whose columns, removed from J at the home pose, leave the best-conditioned
6x6 Jacobian (`redundant_joints`). For the UR-10 (n = 6) the task is the tool pose alone.
"""
import itertools
import math

import numpy as np

from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.multibody.inverse_kinematics import InverseKinematics
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import JacobianWrtVariable
from pydrake.solvers import Solve

from stdm_drake.errors import InputError, PlanningError
from stdm_drake.robots.nested_models import frame_by_name
from stdm_drake.robots.plant import PlantConfig, joint_limits, make_plant
from stdm_drake.robots.robot import POSE_DIM, Robot


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
    """Forward/inverse kinematics of the robot's tool frame (poses in the world frame).

    robot: the Robot; plant: a finalized MultibodyPlant holding it
    (default: make_plant with time_step=0). The object owns one plant context, so it is not
    thread-safe.
    """

    def __init__(self, plant: MultibodyPlant | None = None, *, robot: Robot):
        if plant is None:
            plant, _ = make_plant(PlantConfig.continuous(), robot=robot)
        n = robot.num_joints
        if plant.num_positions() != n or plant.num_velocities() != n:
            raise InputError(f"RobotKinematics needs the {n}-joint plant of {robot.name}, got "
                             f"{plant.num_positions()} positions")
        self.robot = robot
        self.num_joints = n
        self.joint_names = robot.joint_names
        self.plant = plant
        self.context = plant.CreateDefaultContext()
        self.tool_frame = frame_by_name(plant, robot.tool_frame)
        self.world_frame = plant.world_frame()
        self.limits = joint_limits(plant)
        self._origin = np.zeros(3)
        # Reach bound: the distance between consecutive joint origins is constant, so the tool is
        # never farther from the first joint's origin (fixed in the world) than the sum of those distances.
        self._set_state(np.zeros(n))
        points = [plant.GetJointByName(name).frame_on_child().CalcPoseInWorld(self.context).translation()
                  for name in self.joint_names]
        points.append(self.tool_frame.CalcPoseInWorld(self.context).translation())
        self.shoulder = points[0].copy()
        self.reach = float(sum(np.linalg.norm(b - a) for a, b in zip(points[:-1], points[1:])))
        self.redundant_joints = redundant_joints(self.jacobian(robot.home)) if n > POSE_DIM else ()


    def check_reachable(self, X_goal: RigidTransform) -> None:
        """Raise PlanningError if the tool position of X_goal is beyond the arm's reach bound."""
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
        """Pose of the tool frame in the world frame at joint positions q (n,) rad."""
        self._set_state(q)
        return self.plant.CalcRelativeTransform(self.context, self.world_frame, self.tool_frame)

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """Spatial velocity Jacobian (6, n) of the tool frame's origin: [omega; v] in world = J q_dot."""
        self._set_state(q)
        return self.plant.CalcJacobianSpatialVelocity(
            self.context, JacobianWrtVariable.kV, self.tool_frame, self._origin,
            self.world_frame, self.world_frame)

    def bias_acceleration(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Bias spatial acceleration (6,) J_dot v = [alpha; a] - J q_ddot of the tool frame, world frame."""
        self._set_state(q, v)
        bias = self.plant.CalcBiasSpatialAcceleration(
            self.context, JacobianWrtVariable.kV, self.tool_frame, self._origin,
            self.world_frame, self.world_frame)
        return np.concatenate([bias.rotational(), bias.translational()])

    def task_jacobian(self, q: np.ndarray) -> np.ndarray:
        """Task Jacobian (n, n): the tool's spatial velocity Jacobian (6, n) with one unit row per
        redundant joint below it (the Jacobian itself for a 6-joint arm)."""
        J = self.jacobian(q)
        if not self.redundant_joints:
            return J
        return np.vstack([J, np.eye(self.num_joints)[list(self.redundant_joints)]])

    def task_bias(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Task bias acceleration (n,): bias_acceleration (6,), then zeros for the redundant joints."""
        bias = self.bias_acceleration(q, v)
        if not self.redundant_joints:
            return bias
        return np.concatenate([bias, np.zeros(len(self.redundant_joints))])

    def pose_error(self, X_goal: RigidTransform, q: np.ndarray) -> np.ndarray:
        """Error (6,) [rotation vector of R_goal R^T (rad); p_goal - p (m)] in the world frame."""
        X = self.tool_pose(q)
        rotation = rotation_log(X_goal.rotation().matrix() @ X.rotation().matrix().T)
        return np.concatenate([rotation, X_goal.translation() - X.translation()])

    def inverse_kinematics(self, X_goal: RigidTransform, q_seed: np.ndarray, *,
                           tolerance: float = 1e-10, max_iterations: int = 50,
                           damping: float = 1e-3, max_step: float = 0.5,
                           redundant_positions: np.ndarray | None = None) -> np.ndarray:
        """Joint positions q (n,) rad with tool_pose(q) = X_goal, by damped Newton steps from q_seed.

        Converges when both the rotation error (rad) and the position error (m) are below
        `tolerance`; each step is J^T (J J^T + lambda^2 I)^-1 e with lambda = damping *
        min(1, |e|), scaled down to at most `max_step` rad on any joint. For an arm of more than
        6 joints the steps are the smallest joint motions (the solution stays near the seed), or,
        with `redundant_positions` (one per redundant joint, rad), J and e are the task Jacobian
        and error, so the redundant joints end at those positions. Raises PlanningError if it
        does not converge or the solution is outside the joint position limits.
        """
        q = np.array(q_seed, dtype=float).reshape(self.num_joints)
        redundant = list(self.redundant_joints) if redundant_positions is not None else []
        for _ in range(max_iterations + 1):
            error = self.pose_error(X_goal, q)
            rotation_error = float(np.linalg.norm(error[:3]))
            position_error = float(np.linalg.norm(error[3:]))
            redundancy_error = np.asarray(redundant_positions, dtype=float) - q[redundant] if redundant else None
            if (rotation_error <= tolerance and position_error <= tolerance
                    and (not redundant or float(np.max(np.abs(redundancy_error))) <= tolerance)):
                self.check_position_limits(q, what=f"IK solution for pose {pose_text(X_goal)}")
                return q
            J = self.task_jacobian(q) if redundant else self.jacobian(q)
            if redundant:
                error = np.concatenate([error, redundancy_error])
            lam = damping * min(1.0, float(np.linalg.norm(error)))
            step = J.T @ np.linalg.solve(J @ J.T + lam**2 * np.eye(len(error)), error)
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
        """IK (n,) rad by Drake's InverseKinematics + Solve from q_seed (cost |q - q_seed|^2),
        then polished by inverse_kinematics(). For poses whose seed is only roughly known.
        """
        q_seed = np.array(q_seed, dtype=float).reshape(self.num_joints)
        ik = InverseKinematics(self.plant, with_joint_limits=True)
        position = X_goal.translation()
        slack = 1e-6
        ik.AddPositionConstraint(self.tool_frame, self._origin, self.world_frame,
                                 position - slack, position + slack)
        ik.AddOrientationConstraint(self.world_frame, X_goal.rotation(), self.tool_frame,
                                    RotationMatrix(), slack)
        ik.prog().AddQuadraticErrorCost(np.eye(self.num_joints), q_seed, ik.q())
        ik.prog().SetInitialGuess(ik.q(), q_seed)
        result = Solve(ik.prog())
        if not result.is_success():
            raise PlanningError(f"inverse kinematics (Drake {result.get_solver_id().name()}) found no "
                                f"solution for pose {pose_text(X_goal)}: {result.get_solution_result()}")
        return self.inverse_kinematics(X_goal, result.GetSolution(ik.q()), tolerance=tolerance)

    def check_position_limits(self, q: np.ndarray, *, what: str) -> None:
        """Raise PlanningError naming the joint if q (n,) rad is outside the position limits."""
        lower, upper = self.limits.position_lower, self.limits.position_upper
        for j in range(self.num_joints):
            if q[j] < lower[j] or q[j] > upper[j]:
                bound, excess = (lower[j], lower[j] - q[j]) if q[j] < lower[j] else (upper[j], q[j] - upper[j])
                raise PlanningError(f"{what}: {self.joint_names[j]} at {q[j]:.4f} rad is outside its position "
                                    f"limit {bound:.4f} rad by {excess:.4f} rad")


# Joints up to which every set of redundant joints is tried: C(12, 6) = 924 sets; C(31, 6) = 736,281 took a minute
# in `robot init`, and a 99-joint chain would take days. Beyond, the sets are built greedily.
EXHAUSTIVE_REDUNDANCY = 12


def redundant_joints(J: np.ndarray) -> tuple[int, ...]:
    """The n - 6 joints (indices, ascending) whose columns, removed from the tool Jacobian J (6, n),
    leave the 6x6 Jacobian with the smallest condition number; the first such set on ties. Above
    EXHAUSTIVE_REDUNDANCY joints, one joint at a time: the one whose removal leaves the best-conditioned rest,
    until 6 remain (the same rule, not guaranteed the best set)."""
    n = J.shape[1]
    if n <= EXHAUSTIVE_REDUNDANCY:
        return min(itertools.combinations(range(n), n - POSE_DIM),
                   key=lambda removed: float(np.linalg.cond(np.delete(J, removed, axis=1))))
    kept = list(range(n))
    while len(kept) > POSE_DIM:
        drop = min(kept, key=lambda joint: float(np.linalg.cond(J[:, [k for k in kept if k != joint]])))
        kept.remove(drop)
    return tuple(joint for joint in range(n) if joint not in kept)
