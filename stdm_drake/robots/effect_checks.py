"""Checks of the plant effects beyond rigid bodies against a robot and its plant step (`plant.check_plant_effects`
runs them before any work): settings that act on nothing, delays that are no whole number of plant steps, a
transmission too soft to carry its motor's torque, a friction ripple the plant step cannot resolve, and values the
plant cannot show (a gear ratio that makes a motor vanish, a Coulomb or Stribeck width past the joint's speed range, a
Stribeck width so narrow that the friction never exceeds Coulomb's, a torque noise beyond the effort limit, a lag that
decays below double precision within one plant step)."""
import numpy as np

from stdm_drake.errors import InputError, bound_text
from stdm_drake.robots.effect_systems import plant_steps
from stdm_drake.robots.effects import MIN_MASS, PlantEffects

# kg m²: a milligram a millimetre from its axis, the smallest reflected rotor inertia G² I_r that is a motor (below,
# e.g. a gear ratio of 1e-300, it adds nothing to the joint)
MIN_REFLECTED_INERTIA = MIN_MASS * 1e-6
# h / T beyond which a first-order lag exp(-h / T) is below double precision (2^-53) within one plant step h
UNRESOLVED_LAG = 53 * np.log(2.0)

# the value of a field that must be > 0 that stands for none on a joint whose companion is 0 (PlantEffects' defaults)
NEUTRAL_VALUES = {"gear_ratio": 1.0, "coulomb_velocity_scale": PlantEffects().coulomb_velocity_scale[0],
                  "stribeck_velocity": PlantEffects().stribeck_velocity[0]}


def breakaway_shows(coulomb: np.ndarray, breakaway: np.ndarray, width: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Per joint (arrays of one length), whether the friction's magnitude (F_c + (F_s - F_c) exp(-(v / v_st)²))
    tanh(v / v_s) exceeds F_c at some velocity v > 0 (on a grid of 2001 velocities from 1e-6 to 1e3 times the larger
    of v_st and v_s): a Stribeck breakaway the plant shows."""
    velocity = np.logspace(-6, 3, 2001)[:, None] * np.maximum(width, scale)
    with np.errstate(over="ignore", under="ignore"):
        magnitude = (coulomb + (breakaway - coulomb) * np.exp(-(velocity / width) ** 2)) * np.tanh(velocity / scale)
    return np.any(magnitude > coulomb * (1 + 1e-9), axis=0)


def narrowest_breakaway(coulomb: float, breakaway: float, scale: float) -> float | None:
    """The narrowest Stribeck velocity (rad/s), on a grid from 0.01 to 1000 times the velocity scale `scale`, at which
    a breakaway `breakaway` N m over the Coulomb friction `coulomb` N m shows (`breakaway_shows`); None: at none."""
    widths = scale * np.logspace(-2, 3, 251)
    shows = breakaway_shows(np.full(len(widths), coulomb), np.full(len(widths), breakaway), widths,
                            np.full(len(widths), scale))
    return float(widths[int(np.argmax(shows))]) if np.any(shows) else None


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
    period, rotor = effects.joint_values("friction_ripple_period", n), effects.joint_values("rotor_inertia", n)
    stribeck = effects.stribeck(n)
    above_coulomb = stribeck[0] - coulomb if stribeck is not None else np.zeros(n)
    at_rest = effects.friction_at_rest(n)   # (the breakaway where Stribeck friction is on: tanh(v / v_s) shapes it too)
    for field, companion, values in (("friction_ripple", "coulomb_friction", coulomb),
                                     ("transmission_damping", "transmission_stiffness",
                                      effects.joint_values("transmission_stiffness", n)),
                                     ("friction_ripple_period", "friction_ripple", ripple * (coulomb > 0)),
                                     ("gear_ratio", "rotor_inertia", rotor),
                                     ("coulomb_velocity_scale", "friction at rest", at_rest),
                                     ("stribeck_velocity", "stribeck_friction above coulomb_friction", above_coulomb),
                                     ("stribeck_friction", "excess over coulomb_friction", above_coulomb)):
        # (a per-joint list's value where its companion is 0; one value for all joints applies where it can, and
        # acts on nothing where its companion is 0 on every joint: a gear ratio beside rotor inertias all 0, a
        # Stribeck friction equal to Coulomb's on every joint)
        if not getattr(effects, field):
            continue
        # (a field that must be > 0 stands for none with its neutral value: a gear ratio of 1, a velocity scale's
        # default; held-out run 34: "give it 0" was refused by the field's own rule, so no per-joint list could pass)
        none = NEUTRAL_VALUES.get(field, 0.0)
        idle = (effects.joint_values(field, n) > 0) & (values <= 0) & (effects.joint_values(field, n) != none)
        if len(getattr(effects, field)) > 1 and np.any(idle) and field != "stribeck_friction":   # (F_s = F_c: none)
            raise InputError(f"plant effects {field} on {robot.joint_names[int(np.argmax(idle))]}, whose {companion} is "
                             f"0, acts on nothing there, so it would be ignored; give it {none:g} on that joint"
                             + (" (the value that stands for none there)" if field in NEUTRAL_VALUES else ""))
        if field in ("gear_ratio", "stribeck_friction") and np.all(values <= 0):
            raise InputError(f"plant effects {field} acts on nothing: {companion} is 0 on every joint, so it would be "
                             "ignored; leave it out")
    # (a gear ratio that makes a motor's reflected inertia vanish; a rotor inertia itself below the floor, as a fit
    # leaves one that is 0 to its solver's tolerance, adds nothing and loads)
    reflected = effects.joint_values("gear_ratio", n) ** 2 * rotor if effects.gear_ratio else rotor
    faint = (rotor >= MIN_REFLECTED_INERTIA) & (reflected < MIN_REFLECTED_INERTIA)
    if np.any(faint):
        joint = int(np.argmax(faint))
        raise InputError(f"plant effects gear_ratio {effects.joint_values('gear_ratio', n)[joint]:g} on "
                         f"{robot.joint_names[joint]} reflects its rotor_inertia {rotor[joint]:g} kg m² as "
                         f"{reflected[joint]:g} kg m², less than {MIN_REFLECTED_INERTIA:g} kg m² (a milligram a "
                         "millimetre from its axis): no motor; give the gear ratio it has")
    for field, acting, what in (("coulomb_velocity_scale", at_rest > 0, "its torque would never reach coulomb_friction"),
                                ("stribeck_velocity", above_coulomb > 0, "the breakaway would reach past it")):
        width = effects.joint_values(field, n)
        wide = acting & (width > limits.velocity)
        if np.any(wide):
            joint = int(np.argmax(wide))
            raise InputError(f"plant effects {field} {width[joint]:g} rad/s on {robot.joint_names[joint]} is wider "
                             f"than the joint's whole speed range (velocity limit {limits.velocity[joint]:g} rad/s): "
                             f"{what}; give at most {limits.velocity[joint]:g} rad/s")
    if stribeck is not None and np.any(above_coulomb > 0):   # (a breakaway over before tanh(v / v_s) rises: none)
        hidden = above_coulomb > 0
        scale = effects.joint_values("coulomb_velocity_scale", n)
        hidden[hidden] = ~breakaway_shows(coulomb[hidden], stribeck[0][hidden], stribeck[1][hidden], scale[hidden])
        if np.any(hidden):   # (the advice: the narrowest width that shows, on a grid up to 1000 v_s; none: the excess)
            joint = int(np.argmax(hidden))
            narrowest = narrowest_breakaway(coulomb[joint], stribeck[0][joint], scale[joint])
            if narrowest is None:
                raise InputError(f"plant effects stribeck_friction {stribeck[0][joint]:g} N m on {robot.joint_names[joint]} "
                                 f"exceeds its coulomb_friction by {above_coulomb[joint]:.3g} N m, too little for the "
                                 "friction to rise above Coulomb's at any Stribeck velocity: give a larger breakaway, or "
                                 "none there")
            raise InputError(f"plant effects stribeck_velocity {stribeck[1][joint]:g} rad/s on {robot.joint_names[joint]} "
                             "ends the breakaway before the smoothed friction tanh(v / coulomb_velocity_scale) rises, so "
                             "the friction never exceeds coulomb_friction there and the plant shows no Stribeck effect; "
                             f"give at least {bound_text(narrowest, at_least=True)} rad/s there")
    m = robot.action_dim   # (a lag and a torque noise per actuated joint)
    noise = effects.joint_values("torque_noise_std", m) if effects.torque_noise_std else np.zeros(m)
    if robot.fully_actuated and np.any(noise > limits.effort):   # (beyond it every sample clips: saturation, no noise)
        joint = int(np.argmax(noise - limits.effort))
        raise InputError(f"plant effects torque_noise_std {noise[joint]:g} N m on "
                         f"{robot.joint_names[robot.actuated_indices[joint]]} is beyond its effort limit "
                         f"{limits.effort[joint]:g} N m: the held torque would clip at the limit every sample")
    lag = effects.joint_values("actuator_time_constant", m) if effects.actuator_time_constant else np.zeros(m)
    unresolved = (lag > 0) & (time_step > UNRESOLVED_LAG * lag)
    if np.any(unresolved):
        joint = int(np.argmax(unresolved))
        raise InputError(f"plant effects actuator_time_constant {lag[joint]:g} s on "
                         f"{robot.joint_names[robot.actuated_indices[joint]]} decays "
                         f"below double precision within one plant step of {time_step:g} s, so the plant shows no lag; "
                         f"give 0 for none, or at least {bound_text(time_step / UNRESOLVED_LAG, at_least=True)} s")
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
                             f"{robot.joint_names[joint]} winds up {windup[joint]:.5g} rad at its motor's effort limit "
                             f"{limits.effort[joint]:g} N m, more than half a turn: no transmission carries torque so; "
                             f"give at least {bound_text(limits.effort[joint] / np.pi, at_least=True)} N m/rad")
    rippled = effects.ripple(n)
    if rippled is not None and time_step > 0:   # (a period crossed within two plant steps at top speed aliases)
        finest = 2.0 * time_step * limits.velocity
        short = acting & (rippled[1] < finest)
        if np.any(short):
            joint = int(np.argmax(short))
            raise InputError(f"plant effects friction_ripple_period {rippled[1][joint]:g} rad on {robot.joint_names[joint]} "
                             f"passes in under two plant steps of {time_step:g} s at its velocity limit "
                             f"{limits.velocity[joint]:g} rad/s, so the plant cannot resolve it; give at least "
                             f"{bound_text(finest[joint], at_least=True)} rad, or a finer plant step")
