"""The limits `robot init` derives where an arm's description states none, and the joints it locks as a tool or
gripper's mount (`stdm_drake.robots.starting_config`, whose docstring states the rules; docs/guides/robots.md).

Every derived limit is written to the robot config YAML and marked there as derived, to be replaced by the maker's
ratings: velocity pi/2 rad/s (0.5 m/s prismatic); a revolute range [0, 0] (URDF's default) as [-pi, pi]; effort
twice the largest |gravity torque| + 5 rad/s² x M_jj(q) over the home and 200 configurations drawn in the ranges,
at least a tenth of the largest joint's (a wrist carries a payload the description does not hold).
"""
from __future__ import annotations

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.robots.limit_checks import LIMIT_BOUNDS, MIN_LIMIT
from stdm_drake.robots.robot import POSE_DIM, Robot, RobotConfig
from stdm_drake.robots.plant import Dynamics, joint_limits

# the rule for limits an arm joint's file lacks (module docstring): velocity rad/s (revolute) or m/s
# (prismatic), the revolute range (rad), the reference acceleration (rad/s² or m/s²), the margin, the floor as
# a share of the largest joint's effort, and the configurations drawn
DERIVED_LIMITS = dict(velocity=(np.pi / 2, 0.5), position=(-np.pi, np.pi), acceleration=5.0, margin=2.0,
                      floor=0.1, configurations=200)
# N m: a joint without a usable effort limit while its derived one is computed (the largest a robot config may give,
# limit_checks.LIMIT_BOUNDS)
PROVISIONAL_EFFORT = 1e6
# what the notes of derived limits say of the file's
NONE_GIVEN = "the file gives none, 0 or one beyond an arm joint's; in SDFormat, below 0 is none"


def mount_joints(arm_joints: list, joints: dict) -> list:
    """The chain's last movable joints that mount a tool or gripper, not arm joints: those after POSE_DIM or more
    joints whose file states an effort limit, the file stating none for them (a gripper's turning mount on a
    7-joint arm, pybullet's KUKA iiwa world). None where the arm itself lacks effort limits (they are derived).
    joints: the description's, by name."""
    rated = [usable(joints[name].effort) for name in arm_joints]
    last = max((index for index, value in enumerate(rated) if value), default=-1)
    if last + 1 < POSE_DIM or not all(rated[:last + 1]):
        return []
    return list(arm_joints[last + 1:])


def usable(value) -> bool:
    """Whether a limit the file states can be one (finite, > 0)."""
    return value is not None and np.isfinite(value) and value > 0


def within_bounds(value, key: str) -> bool:
    """Whether a limit the file states (`key`: "velocity" or "effort") is one an arm joint can have: usable and in
    [MIN_LIMIT, LIMIT_BOUNDS[key]] (limit_checks: rad/s or m/s, N m or N)."""
    return usable(value) and MIN_LIMIT <= value <= LIMIT_BOUNDS[key]


def derive_kinematic_limits(config: RobotConfig, joints: dict) -> list[str]:
    """Into `config`, per arm joint (`joints`: the description's, by name), the velocity limit and revolute
    position range its file lacks and `config` does not give (`DERIVED_LIMITS`), and PROVISIONAL_EFFORT where it
    lacks an effort limit (`derive_effort_limits` replaces it once the robot loads); the notes saying so. A velocity
    or effort limit beyond an arm joint's bounds (2e6 N m, 1e-320: `within_bounds`) is derived the same way, a note
    naming it. A negative or non-finite one is no missing one: InputError (one line) unless `config` replaces it."""
    notes, velocity, ranges, beyond = [], [], [], []
    for name in config.arm_joints:
        joint = joints[name]
        for key, value in (("velocity", joint.velocity), ("effort", joint.effort)):
            replaced = name in (config.velocity_limits if key == "velocity" else config.effort_limits)
            if value is not None and (value < 0 or not np.isfinite(value)) and not replaced:
                raise InputError(f"joint {name!r} states {key} limit {value:g}; a limit is > 0 ({key} limits the file "
                                 "lacks, or gives as 0, are derived): correct it in the file")
            if usable(value) and not within_bounds(value, key) and not replaced:
                beyond.append(f"{key} limit {value:g} of {name}")
        if not within_bounds(joint.velocity, "velocity") and name not in config.velocity_limits:
            config.velocity_limits[name] = DERIVED_LIMITS["velocity"][joint.kind == "prismatic"]
            velocity.append(name)
        if joint.kind == "revolute" and joint.lower == joint.upper == 0 and name not in config.position_limits:
            config.position_limits[name] = list(DERIVED_LIMITS["position"])
            ranges.append(name)
        if not within_bounds(joint.effort, "effort") and name not in config.effort_limits:
            config.effort_limits[name] = PROVISIONAL_EFFORT
    if beyond:
        notes.append(f"the file's {', '.join(beyond)} {'are' if len(beyond) > 1 else 'is'} beyond an arm joint's "
                     f"([{MIN_LIMIT:g}, {LIMIT_BOUNDS['velocity']:g}] rad/s or m/s, [{MIN_LIMIT:g}, "
                     f"{LIMIT_BOUNDS['effort']:g}] N m or N): derived as if the file gave none")
    if velocity:
        notes.append(f"velocity_limits of {', '.join(velocity)} derived ({NONE_GIVEN}): pi/2 rad/s, 0.5 m/s "
                     "prismatic; replace them with the maker's ratings")
    if ranges:
        notes.append(f"position_limits of {', '.join(ranges)} derived (the file's range is [0, 0]): [-pi, pi]; replace "
                     "them with the maker's ranges")
    return notes


def derive_effort_limits(robot: Robot, config: RobotConfig) -> list[str]:
    """Into `config`, in place of each PROVISIONAL_EFFORT, the derived effort limit (N m or N; `DERIVED_LIMITS`,
    3 significant digits) of `robot` (built from `config`); the note saying so."""
    derived = [name for name, value in config.effort_limits.items() if value == PROVISIONAL_EFFORT]
    if not derived:
        return []
    dynamics = Dynamics(robot)
    limits = joint_limits(dynamics.plant)
    lower = np.where(np.isfinite(limits.position_lower), limits.position_lower, -np.pi)
    upper = np.where(np.isfinite(limits.position_upper), limits.position_upper, np.pi)
    rng = np.random.default_rng(0)
    rule = DERIVED_LIMITS
    needed = np.zeros(robot.num_joints)
    for q in [robot.home] + [rng.uniform(lower, upper) for _ in range(rule["configurations"])]:
        torque = np.abs(dynamics.gravity_torque(q)) + rule["acceleration"] * np.diag(dynamics.mass_matrix(q))
        needed = np.maximum(needed, rule["margin"] * torque)
    needed = np.maximum(needed, rule["floor"] * needed.max())
    for j, name in enumerate(robot.joint_names):
        if name in derived:
            config.effort_limits[name] = float(f"{needed[j]:.3g}")
    return [f"effort_limits of {', '.join(derived)} derived ({NONE_GIVEN}): twice the largest |gravity "
            "torque| + 5 rad/s² x M_jj over 200 configurations, at least a tenth of the largest; replace them with "
            "the maker's ratings"]
