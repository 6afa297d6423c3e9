"""The joint limits a description states and a robot config gives: their checks before Drake reads them (Drake's
parser asserts on some, and others no robot has) and the config's overrides. Used by `robots.description`, whose
`Joint` and `Description` these read, and `robots.robot`."""
from __future__ import annotations

import math

from stdm_drake.errors import InputError


def limit_overrides(position: dict, velocity: dict, effort: dict) -> dict:
    """Per joint, the limits a robot config gives in place of the file's (its position_limits [lower, upper],
    velocity_limits, effort_limits): {"lower", "upper", "velocity", "effort"}, the keys it gives."""
    overrides = {joint: dict(lower=float(low), upper=float(high)) for joint, (low, high) in position.items()}
    for key, limits in (("velocity", velocity), ("effort", effort)):
        for joint, value in limits.items():
            overrides.setdefault(joint, {})[key] = float(value)
    return overrides


def limits_drake_refuses(description) -> set[str]:
    """The joints of a `description.Description` whose file limits Drake's parser cannot take (lower position limit above upper, a negative
    velocity limit: assertions that end the process)."""
    return {joint.name for joint in description.joints
            if (joint.lower is not None and joint.upper is not None and joint.lower > joint.upper)
            or (joint.velocity is not None and joint.velocity < 0)}


LIMIT_KEYS = {"lower": "position_limits", "upper": "position_limits", "velocity": "velocity_limits",
              "effort": "effort_limits"}
# The largest velocity (rad/s or m/s) and effort (N m or N) limit an arm joint may have, and the smallest position
# range (rad or m) it may move in: beyond any robot's joint by orders of magnitude (the 1,119 files of the robot corpus
# state at most 1,000 and 10,000; the largest industrial arms' joints hold about 1e4 N m) and what the plans and the
# MPC can work with (a limit of 1e300 is none, and overflows their arithmetic; a range of 1e-320 rad is none)
LIMIT_BOUNDS = {"velocity": 1e4, "effort": 1e6}
MIN_POSITION_RANGE = 1e-6
MAX_POSITION_LIMIT = 1e6   # ... and the largest position limit's magnitude (the corpus states at most 1e3)
# ... and the smallest velocity and effort limit (rad/s or m/s, N m or N): a limit of 1e-320 is 0 in all but name
MAX_GYRATION_RADIUS = 100.0   # m: a link's principal moments at most mass x (this)² (the plant effects' bound too)
MIN_LIMIT = 1e-6


def check_config_limit(field: str, joint: str, value, arm_joints) -> None:
    """InputError unless `joint` is one of `arm_joints` and a robot config's `velocity_limits` or `effort_limits`
    (`field`) value for it lies in [MIN_LIMIT, LIMIT_BOUNDS] (rad/s or m/s, N m or N), as a file's limits of an arm
    joint must."""
    if joint not in arm_joints:
        raise InputError(f"robot config {field}: {joint!r} is not an arm joint")
    bound = LIMIT_BOUNDS[field.split("_")[0]]
    if not MIN_LIMIT <= value <= bound:   # (NaN too)
        raise InputError(f"robot config {field}[{joint!r}] must be in [{MIN_LIMIT:g}, {bound:g}], got {value!r}")


def check_limits(joint, where: str, arm: bool, locked: bool = False) -> None:
    """InputError for a `description.Joint` whose lower position limit > upper or a negative velocity limit; for an
    `arm` joint also a non-finite limit, a zero velocity limit or an empty position range (it could not move). Each
    message names the robot config key that replaces the file's value where there is one (arm joints; a
    locked joint's position_limits), else says to edit the file."""
    given = {key: getattr(joint, key) for key in ("lower", "upper", "velocity") if getattr(joint, key) is not None}

    def override(key: str) -> str:
        if arm or (locked and LIMIT_KEYS[key] == "position_limits"):
            return f"; give {LIMIT_KEYS[key]}[{joint.name!r}] in the robot config to replace it"
        return "; correct it in the file (the robot config replaces limits of arm joints only)"

    if arm:
        for key, value in given.items():
            if not math.isfinite(value):
                raise InputError(f"{where} has a non-finite {key} limit ({value}){override(key)}")
            if key in ("lower", "upper") and abs(value) > MAX_POSITION_LIMIT:
                raise InputError(f"{where} has the {key} position limit {value:g}, beyond {MAX_POSITION_LIMIT:g} rad or m "
                                 f"(a limit of 1e300 is none){override(key)}")
    if joint.lower is not None and joint.upper is not None and joint.lower > joint.upper:
        raise InputError(f"{where} has its lower position limit {joint.lower:g} above its upper limit "
                         f"{joint.upper:g}{override('lower')}")
    if arm and joint.lower is not None and joint.upper is not None and joint.upper - joint.lower < MIN_POSITION_RANGE:
        raise InputError(f"{where} has the position range [{joint.lower:g}, {joint.upper:g}], so it cannot move"
                         f"{override('lower')}")
    if joint.velocity is not None and (joint.velocity < 0 or (arm and joint.velocity == 0)):
        raise InputError(f"{where} has velocity limit {joint.velocity:g}; a velocity limit is > 0 (rad/s or m/s)"
                         f"{override('velocity')}")
    for key, bound in LIMIT_BOUNDS.items():
        value = getattr(joint, key)
        if arm and value is not None and math.isfinite(value) and (value > bound or 0 < value < MIN_LIMIT):
            raise InputError(f"{where} has {key} limit {value:g}; an arm joint's is in [{MIN_LIMIT:g}, {bound:g}] "
                             f"({'rad/s or m/s' if key == 'velocity' else 'N m or N'}){override(key)}")
