"""Plan specifications of the tracked data protocol (paper section V.B.1): initial tool poses, final
poses sampled near each (`TaskSpaceSamplingConfig`), the planner settings (`Tracking`, from
trajectories/*.yaml), and the sampling of plans for every initial pose."""
import dataclasses
import logging
import math
import typing
from typing import Callable

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix

from stdm_drake.robots.kinematics import RobotKinematics, pose_text, rotation_exp
from stdm_drake.collection.planner_configs import PlannerConfig, Quintic
from stdm_drake.collection.planners import PlannedTrajectory, plan_trajectory, quintic_shortest_times
from stdm_drake.config import require
from stdm_drake.errors import InputError, PlanningError
from stdm_drake.robots.plant import robot_joint_limits, Dynamics, SelfCollisionChecker, joint_limits
from stdm_drake.robots.robot import Robot
from stdm_drake.robots.starting_config import check_holds_home

logger = logging.getLogger(__name__)

# One plan's steps: a plan is seconds of motion (100 steps in the paper); 100,000 steps are 1,000 s at the default
# 10 ms, and a plan of 1e7 steps (28 hours) planned and simulated for minutes without a line. More data is more plans.
MAX_PLAN_STEPS = 100_000
MAX_REACH = 1000.0   # m: a pose or an offset beyond a kilometre (no arm reaches it)
MAX_ANGLE = 1e9      # rad: beyond, a double holds no fraction of a turn (as the excitation's phases)
# Redraws of a rejected goal pose: a goal box from which 1,000 draws are all unreachable or in collision is one to
# move, not to draw from again (1e9 redraws of an unreachable box went on for minutes, a line per draw)
MAX_RESAMPLE_ATTEMPTS = 1_000
# Rejections `report` names one by one per plan once the plan is found (the rest counted); where every attempt fails,
# the refusal alone (one line) names the last
REPORTED_REJECTIONS = 3


@dataclasses.dataclass
class InitialPose:
    """One predefined initial tool0 pose in the world frame.

    xyz: (3,) position, m. rpy: (3,) roll-pitch-yaw, rad (Drake's RollPitchYaw convention).
    q_seed: (n,) joint-space IK seed, rad; it fixes the arm's branch (elbow up, wrist side).
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

    def for_robot(self, robot: Robot) -> "TaskSpaceSamplingConfig":
        """This config after checking each IK seed has one position per arm joint of `robot`."""
        limits = robot_joint_limits(robot)
        for index, pose in enumerate(self.initial_poses):
            require(len(pose.q_seed) == robot.num_joints,
                    f"initial_poses[{index}].q_seed must have {robot.num_joints} positions (robot {robot.name})",
                    pose.q_seed)
            outside = (np.asarray(pose.q_seed) < limits.position_lower) | (np.asarray(pose.q_seed) > limits.position_upper)
            if np.any(outside):   # (the IK starts from a pose the arm cannot take)
                joint = int(np.argmax(outside))
                raise InputError(f"initial_poses[{index}].q_seed[{joint}] {pose.q_seed[joint]:g} rad is outside "
                                 f"{robot.joint_names[joint]}'s position limits [{limits.position_lower[joint]:g}, "
                                 f"{limits.position_upper[joint]:g}] rad: no pose the IK can start from")
        return self

    def validate(self) -> None:
        """Raise InputError (one line) on a malformed configuration."""
        require(len(self.initial_poses) >= 1, "initial_poses must list at least one pose",
                 len(self.initial_poses))
        # (bounds past which a number means nothing here: no arm reaches a kilometre, and beyond 1e9 rad a double
        # holds no fraction of a turn)
        for index, pose in enumerate(self.initial_poses):
            for name, size, bound, unit in (("xyz", 3, MAX_REACH, "m"), ("rpy", 3, MAX_ANGLE, "rad"),
                                            ("q_seed", None, MAX_ANGLE, "rad")):
                values = getattr(pose, name)
                require(len(values) == (size or len(values)) and len(values) and all(abs(v) <= bound for v in values),
                        f"initial_poses[{index}].{name} must be {size or 'joint-count'} numbers within +-{bound:g} "
                        f"{unit}", values)
        require(len(self.position_offset) == 3 and all(0 <= v <= MAX_REACH for v in self.position_offset),
                f"position_offset must be 3 numbers in [0, {MAX_REACH:g}] m (no arm reaches farther)",
                self.position_offset)
        require(0.0 <= self.orientation_max_angle <= math.pi,
                 "orientation_max_angle must be in [0, pi] rad", self.orientation_max_angle)
        require(self.num_final_per_initial >= 1, "num_final_per_initial must be >= 1",
                 self.num_final_per_initial)
        require(1 <= self.num_steps <= MAX_PLAN_STEPS, f"num_steps must be in [1, {MAX_PLAN_STEPS:,}] (longer: more "
                "plans)", self.num_steps)
        require(0 <= self.max_resample_attempts <= MAX_RESAMPLE_ATTEMPTS,
                f"max_resample_attempts must be in [0, {MAX_RESAMPLE_ATTEMPTS:,}]", self.max_resample_attempts)


@dataclasses.dataclass
class Tracking:
    """The tracking protocol (YAML `protocol: !Tracking`, trajectories/tracking*.yaml): the sampling of
    initial and final poses and the planner (`planner: !Quintic`, `!Ruckig` or `!Toppra`)."""
    kind: typing.ClassVar[str] = "tracking"
    sampling: TaskSpaceSamplingConfig = dataclasses.field(default_factory=TaskSpaceSamplingConfig)
    planner: PlannerConfig = dataclasses.field(default_factory=Quintic)


def derived_tracking_spec(robot: Robot, *, num_initial_poses: int = 4, box: float = 0.3, seed: int = 0,
                          sample_period: float = 0.01) -> Tracking:
    """A tracking spec for a robot without a tracking file, by the rules behind the UR-10's:

    - initial poses: the tool pose at home, then at configurations drawn uniformly in home +- `box`
      rad (numpy.random.default_rng(seed)), kept when 0.1 rad inside the position limits, free of
      self-collision and with a task Jacobian condition number at most half the planner's limit;
      each pose's IK seed is its configuration, so every initial pose is reachable on that branch.
    - final poses: a box of +-0.1 x the arm's reach bound around each (the UR-10's 0.15 m is 0.106 of
      its 1.415 m), rotations up to 0.3 rad, 25 per initial pose, 100 steps (the paper's protocol);
      box and angle shrink together for a slow arm by `speed_fitted_scale` (plans of 100 steps at
      `sample_period` s must stay within the planner's share of the joint velocity limits, and within
      its task-space limits).
    - planner: quintic with the UR-10 file's task-space limits; joint acceleration limits of
      5 rad/s^2, or a tenth of what a joint's actuator gives beyond gravity at home (effort - |g_i|)
      / M_ii when that is less (the UR-10's 4-5 rad/s^2 are 0.06-0.15 of it on the arm joints).

    Raises PlanningError when fewer than `num_initial_poses` usable configurations are found.
    """

    robot.check_can_track()
    dynamics = Dynamics(robot)
    kinematics = RobotKinematics(dynamics.plant, robot=robot)
    checker = SelfCollisionChecker(robot)
    limits = joint_limits(dynamics.plant)
    check_holds_home(robot, dynamics, limits)   # (else a joint has no acceleration to plan with)
    inertia = np.diag(dynamics.mass_matrix(robot.home))
    capability = (limits.effort - np.abs(dynamics.gravity_torque(robot.home))) / inertia
    acceleration = np.minimum(5.0, 0.1 * np.maximum(capability, 0.0))
    planner = Quintic(acceleration_limits=np.round(acceleration, 3).tolist())
    rng = np.random.default_rng(seed)
    configurations, attempts = [], 0
    candidate = robot.home.copy()
    while len(configurations) < num_initial_poses:
        inside = np.all(candidate >= limits.position_lower + 0.1) and np.all(candidate <= limits.position_upper - 0.1)
        if (inside and checker.is_collision_free(candidate)
                and np.linalg.cond(kinematics.task_jacobian(candidate)) <= planner.max_jacobian_condition / 2):
            configurations.append(candidate)
        attempts += 1
        if attempts > 1000:
            raise PlanningError(f"robot {robot.name}: found only {len(configurations)} of {num_initial_poses} initial "
                                f"configurations within +-{box} rad of home that are inside the limits, collision "
                                "free and away from singularities; give a tracking spec with --config")
        candidate = robot.home + rng.uniform(-box, box, size=robot.num_joints)
    poses = []
    for q in configurations:
        X = kinematics.tool_pose(q)
        poses.append(InitialPose(xyz=X.translation().tolist(), rpy=RollPitchYaw(X.rotation()).vector().tolist(),
                                 q_seed=q.tolist()))
    sampling = TaskSpaceSamplingConfig(initial_poses=poses, position_offset=[0.1 * kinematics.reach] * 3)
    scale = speed_fitted_scale(kinematics, configurations, sampling, planner,
                               np.abs(limits.velocity), sampling.num_steps * sample_period, seed)
    sampling.position_offset = [round(scale * 0.1 * kinematics.reach, 3)] * 3
    sampling.orientation_max_angle = round(scale * sampling.orientation_max_angle, 3)
    sampling.validate()
    planner.validate()
    return Tracking(sampling=sampling, planner=planner)


def speed_fitted_scale(kinematics: RobotKinematics, configurations: list, sampling: TaskSpaceSamplingConfig,
                       planner: PlannerConfig, velocity_limits: np.ndarray, horizon: float, seed: int,
                       draws: int = 200, target: float = 0.8) -> float:
    """Factor in (0, 1] for the final-pose box and angle: 1 unless the arm is too slow for them. At each
    initial configuration q, `draws` displacements dx drawn as `sample_final_pose` draws them become
    joint motions dq = J_task(q)^-1 dx (redundant joints held); a quintic over `horizon` s peaks at
    1.875 |dq| / horizon. The factor brings the 90th percentile of the largest ratio of that peak to
    velocity_scale x the joint's limit down to `target` (the UR-10 and the Panda need 0.50 and 0.71 with
    their boxes: factor 1), so that most plans pass the planner's velocity check at the first draw. A quintic
    planner's task-space limits count too: its shortest time for the move (velocity terms shrink with the
    factor, acceleration terms with its square root) must be within `target` x horizon (rtb-data's IRB 140 file,
    4.3 m of reach and a box of 0.43 m under the UR-10 file's task-space limits: factor 0.39)."""
    rng = np.random.default_rng(seed + 1)
    allowed = planner.velocity_scale * np.asarray(velocity_limits, dtype=float)
    factors = []   # per draw: the largest factor that keeps its plan within the limits at `target`
    for q in configurations:
        jacobian = kinematics.task_jacobian(q)
        for _ in range(draws):
            displacement = np.zeros(len(q))
            axis = rng.standard_normal(3)
            displacement[:3] = rng.uniform(0.0, sampling.orientation_max_angle) * axis / np.linalg.norm(axis)
            displacement[3:6] = rng.uniform(-1.0, 1.0, 3) * np.asarray(sampling.position_offset)
            motion = np.linalg.lstsq(jacobian, displacement, rcond=None)[0]
            factor = target / np.max(1.875 * np.abs(motion) / horizon / allowed)
            if isinstance(planner, Quintic):
                speed, acceleration = quintic_shortest_times(np.linalg.norm(displacement[3:6]),
                                                             np.linalg.norm(displacement[:3]), planner)
                factor = min(factor, target * horizon / max(speed, 1e-12),
                             (target * horizon / max(acceleration, 1e-12)) ** 2)
            factors.append(factor)
    scale = float(min(1.0, np.quantile(factors, 0.1)))
    if not (np.isfinite(scale) and scale >= 0.05):
        raise PlanningError(f"robot {kinematics.robot.name}: derived plans of {horizon:g} s would need a final-pose box "
                            f"{scale:.3g} of the usual to stay within the velocity limits; give a tracking spec with "
                            "--config")
    return scale


def initial_configuration(kinematics: RobotKinematics, pose: InitialPose, config: PlannerConfig) -> np.ndarray:
    """IK (n,) rad of an initial pose from its configured seed (Newton first, Drake IK as fallback)."""
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
                      on_reject: Callable[[str], None] | None = None,
                      first_index: int = 0) -> list[tuple[int, PlannedTrajectory]]:
    """Plans for every initial pose and num_final_per_initial final poses sampled near it.

    Returns [(initial_pose_index, PlannedTrajectory)] ordered by initial pose, each plan with
    num_steps + 1 samples at sample_period (s). Deterministic for a given rng state. A final pose
    whose plan raises PlanningError, or with a sample q (n,) rad for which is_collision_free(q)
    is False, is rejected: its one-line reason goes to on_reject (default: logged as a warning)
    and the pose is redrawn, up to max_resample_attempts times, after which PlanningError names
    the initial pose. An unreachable initial pose raises PlanningError at once. Messages number the
    initial poses from `first_index` (the pose's index in the full spec when planning one pose).
    """
    sampling_config.validate()
    planner_config.validate()
    report = on_reject if on_reject is not None else logger.warning
    plans: list[tuple[int, PlannedTrajectory]] = []
    for index, initial in enumerate(sampling_config.initial_poses):
        X_initial = initial.pose()
        what = f"initial pose {index + first_index} ({pose_text(X_initial)})"
        try:
            q_initial = initial_configuration(kinematics, initial, planner_config)
        except PlanningError as error:
            raise PlanningError(f"{what} is unreachable: {error}") from None
        if is_collision_free is not None and not is_collision_free(q_initial):
            raise PlanningError(f"{what} is in self-collision at q={np.round(q_initial, 3).tolist()} rad")
        for plan_index in range(sampling_config.num_final_per_initial):
            rejected = []   # (each rejected draw's reason)
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
                    rejected.append(str(error))
                    continue
                # the rejections named once the plan is found, so that a refusal stays its one line
                for number, why in enumerate(rejected[:REPORTED_REJECTIONS], 1):
                    more = (f" (and {len(rejected) - number} more)" if number == REPORTED_REJECTIONS
                            and len(rejected) > number else "")
                    report(f"{what}, plan {plan_index}, attempt {number}: rejected, resampled{more}: {why}")
                plans.append((index, plan))
                break
            else:
                raise PlanningError(f"{what}: no feasible final pose for plan {plan_index} after "
                                    f"{sampling_config.max_resample_attempts + 1} attempts; last: {rejected[-1]}")
    return plans
