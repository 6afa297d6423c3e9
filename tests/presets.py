"""Robots the tests use by name: the library takes the robot as an argument everywhere below the
commands, so tests load the shipped presets here once per process."""
from stdm_drake.robots.robot import UR10_CONFIG, load_robot

UR10 = load_robot(UR10_CONFIG)


def free_limits(effort, joints: int = 6):
    """JointLimits with effort limits `effort` (one value, or one per joint) N m and no position or velocity limit:
    for `MpcConfig.solver` on models whose states have no robot's limits."""
    import numpy as np

    from stdm_drake.robots.plant import JointLimits
    return JointLimits(position_lower=np.full(joints, -np.inf), position_upper=np.full(joints, np.inf),
                       velocity=np.full(joints, np.inf), effort=np.broadcast_to(np.asarray(effort, dtype=float), (joints,)).copy())
