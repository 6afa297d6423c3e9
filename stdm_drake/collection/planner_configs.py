"""Planner settings, one type per planner, tagged in YAML (`planner: !Quintic`, `!Ruckig`, `!Toppra`):
the limits and IK settings every planner shares (`PlannerLimits`) and each planner's own."""
import dataclasses
import math
import typing

from stdm_drake.config import require, check_joint_vector
from stdm_drake.errors import InputError
from stdm_drake.robots.robot import Robot

# the smallest velocity scale and joint or task-space limit: one of 1e-320 (0 in all but name) lets no plan move;
# the largest joint or task-space limit (rad/s², rad/s³, m/s, m/s², rad/s, rad/s²): beyond any arm's by orders of magnitude
MIN_LIMIT, MAX_LIMIT = 1e-6, 1e6


@dataclasses.dataclass
class PlannerLimits:
    """What every planner shares: the limits a plan must respect and the IK that maps it to joint space.

    velocity_scale: joint velocity limit as a fraction of the published limits (0, 1].
    acceleration_limits: (n,) joint acceleration limits, rad/s^2 (none are published), or one for all.
    ik_tolerance: IK convergence on both the position (m) and rotation (rad) error.
    ik_max_iterations: Newton iterations per IK solve.
    ik_damping: damped-least-squares factor; the damping is ik_damping * min(1, |error|), so
        it vanishes near convergence (plain Newton steps, quadratic convergence).
    ik_continuity_tolerance: largest allowed distance (rad, any joint) between an IK solution
        and its first-order prediction from the previous sample (catches branch flips).
    max_jacobian_condition: largest allowed 2-norm condition number of the task Jacobian (the 6x6
        tool Jacobian of a 6-joint arm) along the paths (singularity guard).
    limit_tolerance: relative slack when checking sampled velocities and accelerations against
        their limits (floating-point round-off only).
    """
    kind: typing.ClassVar[str] = ""
    velocity_scale: float = 0.5
    acceleration_limits: typing.List[float] = dataclasses.field(
        default_factory=lambda: [4.0, 4.0, 5.0, 5.0, 5.0, 5.0])
    ik_tolerance: float = 1e-10
    ik_max_iterations: int = 50
    ik_damping: float = 1e-3
    ik_continuity_tolerance: float = 0.02
    max_jacobian_condition: float = 100.0
    limit_tolerance: float = 1e-9

    def joint_lists(self) -> tuple[str, ...]:
        """The per-joint fields (one value per arm joint, or one for all)."""
        return ("acceleration_limits",)

    def for_robot(self, robot: Robot):
        """This config with the per-joint limits of the robot's length (one value broadcast)."""
        return dataclasses.replace(self, **{
            name: check_joint_vector(f"planner {name}", getattr(self, name), count=robot.num_joints).tolist()
            for name in self.joint_lists()})

    def as_kind(self, kind: str) -> "PlannerConfig":
        """A planner of `kind` with this one's shared limits (and the settings both kinds have), its own
        other settings at their defaults, except jerk limits a Ruckig gets from a planner without them:
        ten times the acceleration limits (the UR-10 file's are 7.5-12 times), per joint as those are."""
        if kind not in PLANNER_TYPES:
            raise InputError(f"planner kind must be one of {', '.join(PLANNER_TYPES)}, got {kind!r}")
        target = PLANNER_TYPES[kind]
        names = {field.name for field in dataclasses.fields(target)}
        values = {field.name: getattr(self, field.name) for field in dataclasses.fields(self) if field.name in names}
        if "jerk_limits" in names and "jerk_limits" not in values:
            values["jerk_limits"] = [10.0 * limit for limit in self.acceleration_limits]
        return target(**values)

    def record(self) -> dict:
        """What a dataset records of this planner: its kind and its fields."""
        return dict(kind=self.kind, **dataclasses.asdict(self))

    def validate(self) -> None:
        """Raise InputError (one line) on a malformed configuration."""
        require(MIN_LIMIT <= self.velocity_scale <= 1.0, f"velocity_scale must be in [{MIN_LIMIT:g}, 1]",
                self.velocity_scale)
        for name in self.joint_lists():
            values = getattr(self, name)
            require(len(values) >= 1 and all(MIN_LIMIT <= v <= MAX_LIMIT for v in values),
                    f"{name} must be numbers in [{MIN_LIMIT:g}, {MAX_LIMIT:g}] (one per joint, or one for all)", values)
        # (beyond these bounds a plan is not the plan: an IK a centimetre off, a jump of more than half a turn between
        # samples, a damping that stops the IK's steps, joint speeds a million times the tool's near a singularity)
        # (and below 1e-12 m or rad double precision at an arm's scale, which no IK meets; a continuity tolerance finer
        # than the IK's own flags every sample)
        require(1e-12 <= self.ik_tolerance <= 1e-2, "ik_tolerance must be in [1e-12, 1e-2] (m and rad; finer is "
                "below double precision at an arm's scale)", self.ik_tolerance)
        require(self.ik_tolerance <= self.ik_continuity_tolerance <= math.pi, f"ik_continuity_tolerance must be in "
                f"[ik_tolerance ({self.ik_tolerance:g}), pi] rad", self.ik_continuity_tolerance)
        require(0 <= self.ik_damping <= 1.0, "ik_damping must be in [0, 1]", self.ik_damping)
        require(self.ik_max_iterations >= 1, "ik_max_iterations must be >= 1", self.ik_max_iterations)
        require(1 < self.max_jacobian_condition <= 1e6, "max_jacobian_condition must be in (1, 1e6]",
                self.max_jacobian_condition)
        require(0.0 <= self.limit_tolerance < 0.1, "limit_tolerance must be in [0, 0.1)",
                self.limit_tolerance)


@dataclasses.dataclass
class Quintic(PlannerLimits):
    """A straight task-space line timed by a quintic (YAML `planner: !Quintic`).

    duration_fraction: motion time T = max(duration_fraction * horizon, shortest T under the task-space
        limits), horizon = num_steps * sample_period (s).
    max_linear_speed, max_linear_acceleration: task-space limits on the tool frame's origin, m/s and
        m/s^2; max_angular_speed, max_angular_acceleration: on the tool's rotation, rad/s and rad/s^2.
    """
    kind: typing.ClassVar[str] = "quintic"
    duration_fraction: float = 1.0
    max_linear_speed: float = 0.6
    max_linear_acceleration: float = 2.0
    max_angular_speed: float = 1.0
    max_angular_acceleration: float = 3.0

    def validate(self) -> None:
        super().validate()
        require(0.0 <= self.duration_fraction <= 1.0, "duration_fraction must be in [0, 1]", self.duration_fraction)
        for name in ("max_linear_speed", "max_linear_acceleration", "max_angular_speed", "max_angular_acceleration"):
            value = getattr(self, name)
            require(MIN_LIMIT <= value <= MAX_LIMIT, f"{name} must be in [{MIN_LIMIT:g}, {MAX_LIMIT:g}]", value)


@dataclasses.dataclass
class Ruckig(PlannerLimits):
    """Jerk-limited joint-space motion to the goal's IK solution (YAML `planner: !Ruckig`).

    duration_fraction: ruckig's minimum_duration = duration_fraction * horizon (0: the time-optimal motion).
    jerk_limits: (n,) joint jerk limits, rad/s^3, or one for all.
    path_waypoints: IK waypoints of the continuation along the task-space line that finds the goal
        configuration (the same one the other planners reach).
    """
    kind: typing.ClassVar[str] = "ruckig"
    duration_fraction: float = 1.0
    jerk_limits: typing.List[float] = dataclasses.field(default_factory=lambda: [30.0, 30.0, 40.0, 60.0, 60.0, 60.0])
    path_waypoints: int = 51

    def joint_lists(self) -> tuple[str, ...]:
        return ("acceleration_limits", "jerk_limits")

    def validate(self) -> None:
        super().validate()
        require(0.0 <= self.duration_fraction <= 1.0, "duration_fraction must be in [0, 1]", self.duration_fraction)
        require(self.path_waypoints >= 2, "path_waypoints must be >= 2", self.path_waypoints)


@dataclasses.dataclass
class Toppra(PlannerLimits):
    """The IK'd task-space line as a joint path, re-timed time-optimally (YAML `planner: !Toppra`).

    path_waypoints: IK waypoints along the line (the path); toppra_gridpoints: discretization points
    along it; toppra_limit_margin: plan under (1 - margin) times the limits, so that the interpolation
    error stays inside the limits checked afterwards.
    """
    kind: typing.ClassVar[str] = "toppra"
    path_waypoints: int = 51
    toppra_gridpoints: int = 201
    toppra_limit_margin: float = 0.02

    def validate(self) -> None:
        super().validate()
        require(self.path_waypoints >= 2, "path_waypoints must be >= 2", self.path_waypoints)
        require(self.toppra_gridpoints >= 2, "toppra_gridpoints must be >= 2", self.toppra_gridpoints)
        require(0.0 <= self.toppra_limit_margin < 1.0, "toppra_limit_margin must be in [0, 1)",
                self.toppra_limit_margin)


PlannerConfig = typing.Union[Quintic, Ruckig, Toppra]   # one rest-to-rest planner's settings, tagged in YAML


PLANNER_TYPES = {cls.kind: cls for cls in typing.get_args(PlannerConfig)}


PLANNER_KINDS = tuple(PLANNER_TYPES)
