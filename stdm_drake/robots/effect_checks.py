"""Checks of the plant effects beyond rigid bodies against a robot and its plant step (`plant.check_plant_effects`
runs them before any work): settings that act on nothing, delays that are no whole number of plant steps, a
transmission too soft to carry its motor's torque, a friction ripple the plant step cannot resolve."""
import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.robots.effect_systems import plant_steps
from stdm_drake.robots.effects import PlantEffects


def check_beyond_rigid_bodies(effects: PlantEffects, robot, time_step: float, limits) -> None:
    """InputError (one line) where `effects` ask for what `robot`'s plant at `time_step` s (0: continuous) cannot do
    or would ignore; limits: the robot's `plant.JointLimits` (its velocity limits rad/s per arm joint, its effort limits
    N m per actuated joint, in the joints' order for a fully actuated arm)."""
    n = robot.num_joints
    stepped = effects.acting_later() + (["measurement_delay"] if effects.measurement_delay > 0 else [])
    if stepped and time_step <= 0:
        raise InputError(f"plant effects {' and '.join(stepped)} act every plant step: they need a discrete plant "
                         "(--plant-time-step > 0)")
    for name in ("actuation_delay", "measurement_delay"):
        if getattr(effects, name) > 0:
            plant_steps(effects, name, time_step)
    ripple, coulomb = effects.joint_values("friction_ripple", n), effects.joint_values("coulomb_friction", n)
    period = effects.joint_values("friction_ripple_period", n)
    for field, companion, values in (("friction_ripple", "coulomb_friction", coulomb),
                                     ("transmission_damping", "transmission_stiffness",
                                      effects.joint_values("transmission_stiffness", n)),
                                     ("friction_ripple_period", "friction_ripple", ripple * (coulomb > 0))):
        # (a per-joint list's value where its companion is 0; one value for all joints applies where it can)
        idle = (effects.joint_values(field, n) > 0) & (values <= 0) if len(getattr(effects, field)) > 1 else False
        if np.any(idle):
            joint = robot.joint_names[int(np.argmax(idle))]
            raise InputError(f"plant effects {field} on {joint}, whose {companion} is 0, acts on nothing there, so it "
                             "would be ignored; give it 0 on that joint")
    acting = (ripple > 0) & (coulomb > 0)
    if effects.friction_ripple_period and np.any(acting & (period <= 0)):
        joint = robot.joint_names[int(np.argmax(acting & (period <= 0)))]
        raise InputError(f"plant effects friction_ripple_period must be > 0 rad where friction_ripple is on ({joint})")
    elastic = effects.elastic(n)
    if elastic is not None and robot.fully_actuated:   # (a spring wound past half a turn at full torque: no transmission)
        windup = np.where(elastic[0] > 0, limits.effort / np.where(elastic[0] > 0, elastic[0], 1.0), 0.0)
        if np.any(windup > np.pi):
            joint = int(np.argmax(windup))
            raise InputError(f"plant effects transmission_stiffness {elastic[0][joint]:g} N m/rad on "
                             f"{robot.joint_names[joint]} winds up {windup[joint]:.3g} rad at its motor's effort limit "
                             f"{limits.effort[joint]:g} N m, more than half a turn: no transmission carries torque so; "
                             f"give at least {limits.effort[joint] / np.pi:.3g} N m/rad")
    rippled = effects.ripple(n)
    if rippled is not None and time_step > 0:   # (a period crossed within two plant steps at top speed aliases)
        finest = 2.0 * time_step * limits.velocity
        short = acting & (rippled[1] < finest)
        if np.any(short):
            joint = int(np.argmax(short))
            raise InputError(f"plant effects friction_ripple_period {rippled[1][joint]:g} rad on {robot.joint_names[joint]} "
                             f"passes in under two plant steps of {time_step:g} s at its velocity limit "
                             f"{limits.velocity[joint]:g} rad/s, so the plant cannot resolve it; give at least "
                             f"{finest[joint]:.3g} rad, or a finer plant step")
