"""Plant effects: what a real robot has and its description leaves out, simulated on top of the
nominal model (the robot file, which stays what a user has).

`PlantEffects` is the typed YAML a `--plant-effects FILE` names (per-joint lists, or a list of one value for all
joints): viscous friction (added to the description's joint damping, which Drake's discrete plant
integrates implicitly), Coulomb friction smoothed near zero velocity, -F_c tanh(v / v_s) (a
`effect_systems.JointFriction` system feeding the plant's applied generalized force, sampled every plant step),
reflected rotor inertia (Drake's JointActuator rotor inertia and gear ratio: G² I_r on the mass
matrix's diagonal), a payload rigidly attached to the tool frame, per-link mass scales (parameters in
the plant's Context), and white torque noise added to the held action each sample period (process
noise: not recorded, so a re-simulation from the recorded (x_k, a_k) is exact only without it).

Effects no rigid-body model has (issue 59), each a system of the plant's diagram between the command and the
joints: Stribeck friction (the breakaway friction F_s above Coulomb's near zero velocity, in `JointFriction`),
actuator lag (a first-order lag of each joint's torque behind its command, time constant T s) and a transport
delay (the command reaches the actuators whole plant steps later), in `effect_systems.ActuatorDynamics`; elastic
transmissions (a motor of inertia G² I_r behind a spring-damper k, d on each elastic joint, in
`effect_systems.ElasticTransmissions`: the motors are integrated exactly, the plant's own implicit PD actuator applies
the spring's torque); friction ripple (the Coulomb friction's magnitude varying with the joint's position,
F_c (1 + r sin(2 pi q / P))); and a measurement delay (the state a controller and the data see is the plant's of whole
plant steps earlier, a Drake `DiscreteTimeDelay`). The torque and the state the data record are the command and the
joints' (link-side, measured) state: a model of (q, v) sees these effects only through their consequences.
"""
import dataclasses

import numpy as np

from stdm_drake.config import check_joint_vector, load_yaml_config, one_line, require, file_keys
from stdm_drake.errors import InputError, bound_text
from stdm_drake.robots.nested_models import frame_by_name


MIN_MASS = 1e-6   # kg: a milligram, the smallest payload or link mass (1e-320 kg is no body, and breaks Drake's inertia)
MAX_MASS_RADIUS = 100.0   # m: the farthest a body's mass lies from its frame (centre of mass, radius of gyration)


@dataclasses.dataclass
class RigidInertia:
    """A rigid body's inertia: mass kg, centre of mass (3,) m in its frame, rotational inertia about the
    centre of mass [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] kg m² (zeros: a point mass)."""
    mass: float = 0.0
    center_of_mass: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    inertia: list[float] = dataclasses.field(default_factory=lambda: [0.0] * 6)

    def validate(self, what: str = "payload") -> None:
        require(np.isfinite(self.mass) and (self.mass == 0 or self.mass >= MIN_MASS),
                f"{what} mass must be {'0 (none) or ' if what == 'payload' else ''}at least {MIN_MASS:g} kg", self.mass)
        check_effect_bound(f"{what} mass", np.array([self.mass]), "mass")
        require(self.mass > 0 or not any(self.inertia), f"{what} inertia needs a mass > 0", self.inertia)
        require(len(self.center_of_mass) == 3 and np.hypot.reduce(np.abs(self.center_of_mass)) <= MAX_MASS_RADIUS,
                f"{what} center_of_mass must be 3 numbers within {MAX_MASS_RADIUS:g} m of its frame", self.center_of_mass)
        require(self.mass > 0 or not any(self.center_of_mass), f"{what} center_of_mass needs a mass > 0 (no body)",
                self.center_of_mass)
        require(len(self.inertia) == 6 and np.all(np.isfinite(self.inertia)),
                f"{what} inertia must be 6 finite numbers [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] (kg m²)", self.inertia)
        if self.mass > 0 and any(self.inertia):   # (a moment beyond m (100 m)²: mass farther out than any body reaches)
            largest = self.mass * MAX_MASS_RADIUS ** 2
            require(max(self.inertia[:3]) <= largest, f"{what} inertia must be at most mass x ({MAX_MASS_RADIUS:g} m)² = "
                    f"{largest:g} kg m² about each axis (its mass farther out than any robot's body)", self.inertia)
            from pydrake.multibody.tree import RotationalInertia
            if not RotationalInertia(*self.inertia).CouldBePhysicallyValid():
                raise InputError(f"{what} inertia {self.inertia} is not physically valid (positive moments that "
                                 "satisfy the triangle inequality)")
        if self.mass > 0:
            try:   # (Drake's own check: principal moments it cannot compute, of 1e-320 kg m², are an error there)
                self.spatial_inertia()
            except RuntimeError as error:
                raise InputError(f"{what} mass {self.mass:g} kg with inertia {self.inertia} is no rigid body Drake "
                                 f"can simulate ({one_line(error)[:120]})") from None

    def spatial_inertia(self):
        """Drake's SpatialInertia about the body frame's origin."""
        from pydrake.multibody.tree import RotationalInertia, SpatialInertia
        return SpatialInertia.MakeFromCentralInertia(self.mass, np.asarray(self.center_of_mass, dtype=float),
                                                     RotationalInertia(*self.inertia))


@dataclasses.dataclass
class Payload(RigidInertia):
    """A rigid payload welded to the robot's tool frame (its inertia in the tool frame)."""


# The largest magnitude each effect may have (module docstring's units): beyond any robot joint's by orders of
# magnitude (the largest industrial arms' joints hold about 1e4 N m, their gear ratios are at most a few hundred),
# and small enough that the simulation's arithmetic stays finite; a value beyond is a mistake, refused in one line
EFFECT_BOUNDS = dict(viscous_friction=1e6, coulomb_friction=1e6, torque_noise_std=1e6, joint_damping=1e6,
                     rotor_inertia=1e3, gear_ratio=1e5, mass_scale=1e6, mass=1e6, stribeck_friction=1e6,
                     actuator_time_constant=10.0, actuation_delay=1.0, transmission_stiffness=1e8,
                     transmission_damping=1e6, friction_ripple=1.0, friction_ripple_period=1e3, measurement_delay=1.0)
EFFECT_UNITS = dict(viscous_friction="N m s/rad", coulomb_friction="N m", torque_noise_std="N m",
                    joint_damping="N m s/rad", rotor_inertia="kg m²", gear_ratio="", mass_scale="", mass="kg",
                    stribeck_friction="N m", actuator_time_constant="s", actuation_delay="s",
                    transmission_stiffness="N m/rad", transmission_damping="N m s/rad", friction_ripple="",
                    friction_ripple_period="rad", measurement_delay="s")


def check_effect_bound(label: str, values: np.ndarray, kind: str | None = None) -> None:
    """InputError (one line) where a value of `label` (an effect of kind `kind`, default `label`) is beyond
    EFFECT_BOUNDS."""
    kind = kind or label
    if np.any(np.abs(values) > EFFECT_BOUNDS[kind]):
        unit = f" {EFFECT_UNITS[kind]}" if EFFECT_UNITS[kind] else ""
        raise InputError(f"{label} {float(np.max(np.abs(values))):g}{unit} is beyond any robot's (at most "
                         f"{EFFECT_BOUNDS[kind]:g}{unit} here)")


@dataclasses.dataclass
class PlantEffects:
    """Effects of the simulated plant beyond the robot's description (see the module docstring).

    source: where the magnitudes come from (a citation; recorded with the data).
    viscous_friction: N m s/rad per joint (or one value), added to the description's damping.
    coulomb_friction: N m per joint; coulomb_velocity_scale: v_s rad/s of the tanh smoothing (per joint
        or one value; 2/phi_2 for the sigmoid model phi_1 / (1 + exp(-phi_2 v)) of Gaz et al., whose
        amplitude is then F_c = phi_1 / 2).
    rotor_inertia: motor-side kg m² per joint, replacing the description's; gear_ratio: per joint (reflected inertia
        G² I_r). payload: a Payload on the tool frame.
    mass_scale: link name -> factor on that link's mass and rotational inertia (centre of mass kept).
    torque_noise_std: N m per joint, white noise on the held action, one draw per sample period.
    joint_damping: N m s/rad per joint (or one value): replaces the description's joint damping
        (viscous_friction is added to it); an identified robot's total viscous friction.
    link_inertia: link name -> RigidInertia (in the link's frame) replacing the description's (Context
        parameters, like the mass scales): an identified robot's links.
    stribeck_friction: F_s N m per joint, the breakaway friction at rest, at least coulomb_friction's F_c:
        -(F_c + (F_s - F_c) exp(-(v / v_st)²)) tanh(v / v_s); stribeck_velocity: v_st rad/s (per joint or one).
    actuator_time_constant: T s per joint (or one value): each joint's torque follows its command through a
        first-order lag, dτ/dt = (command - τ) / T (0: none).
    transmission_stiffness: k N m/rad per joint (or one value; 0: a rigid joint): an elastic transmission between the
        joint and its motor, whose inertia is the joint's G² I_r (rotor_inertia, gear_ratio: needed on each elastic
        joint, and then on the motor's side of the spring only); transmission_damping: d N m s/rad (per joint or one)
        in parallel with the spring. Link torque k (theta - q) + d (theta' - q'), motor J theta'' = u - that torque.
    friction_ripple: r per joint (or one), 0 <= r <= 1: the Coulomb (and Stribeck) friction's magnitude times
        1 + r sin(2 pi q / P); friction_ripple_period: P rad per joint (or one), link side.
    actuation_delay, measurement_delay: s, whole numbers of plant steps: a transport delay of the command, and the age
        of the state the controller and the data see.
    """
    source: str = ""
    viscous_friction: list[float] = dataclasses.field(default_factory=list)
    coulomb_friction: list[float] = dataclasses.field(default_factory=list)
    coulomb_velocity_scale: list[float] = dataclasses.field(default_factory=lambda: [0.05])
    rotor_inertia: list[float] = dataclasses.field(default_factory=list)
    gear_ratio: list[float] = dataclasses.field(default_factory=list)
    payload: Payload = dataclasses.field(default_factory=Payload)
    mass_scale: dict[str, float] = dataclasses.field(default_factory=dict)
    torque_noise_std: list[float] = dataclasses.field(default_factory=list)
    joint_damping: list[float] = dataclasses.field(default_factory=list)
    link_inertia: dict[str, RigidInertia] = dataclasses.field(default_factory=dict)
    stribeck_friction: list[float] = dataclasses.field(default_factory=list)
    stribeck_velocity: list[float] = dataclasses.field(default_factory=lambda: [0.1])
    actuator_time_constant: list[float] = dataclasses.field(default_factory=list)
    actuation_delay: float = 0.0
    transmission_stiffness: list[float] = dataclasses.field(default_factory=list)
    transmission_damping: list[float] = dataclasses.field(default_factory=list)
    friction_ripple: list[float] = dataclasses.field(default_factory=list)
    friction_ripple_period: list[float] = dataclasses.field(default_factory=list)
    measurement_delay: float = 0.0

    def validate(self) -> None:
        for name in ("viscous_friction", "coulomb_friction", "rotor_inertia", "torque_noise_std", "joint_damping"):
            if getattr(self, name):
                check_effect_bound(name, check_joint_vector(name, getattr(self, name), nonnegative=True))
        if self.gear_ratio:
            ratio = check_joint_vector("gear_ratio", self.gear_ratio)
            require(bool(np.all(ratio > 0)), "gear_ratio must be > 0 (1 for no gear)", self.gear_ratio)
            check_effect_bound("gear_ratio", ratio)
        require(bool(self.rotor_inertia) or not self.gear_ratio, "gear_ratio needs rotor_inertia", self.gear_ratio)
        scale = check_joint_vector("coulomb_velocity_scale", self.coulomb_velocity_scale)
        require(bool(np.all(scale > 0)), "coulomb_velocity_scale must be > 0 rad/s (0.05: none)", self.coulomb_velocity_scale)
        for link, factor in self.mass_scale.items():
            require(np.isfinite(factor) and factor > 0, f"mass_scale of {link} must be a finite number > 0", factor)
            check_effect_bound(f"mass_scale of {link}", np.array([factor]), "mass_scale")
        self.payload.validate()
        for link, inertia in self.link_inertia.items():
            inertia.validate(f"link_inertia of {link}:")
            require(inertia.mass > 0, f"link_inertia of {link}: mass must be > 0 kg", inertia.mass)
        both = sorted(set(self.link_inertia) & set(self.mass_scale))
        require(not both, "a link has either link_inertia or a mass_scale, not both", both)
        if self.stribeck_friction:
            check_effect_bound("stribeck_friction", check_joint_vector("stribeck_friction", self.stribeck_friction,
                                                                       nonnegative=True))
            require(self.is_on("coulomb_friction"), "stribeck_friction needs coulomb_friction (the friction it "
                    "breaks away to)", self.stribeck_friction)
            breakaway, coulomb = np.asarray(self.stribeck_friction, float), np.asarray(self.coulomb_friction, float)
            if len(breakaway) in (1, len(coulomb)) or len(coulomb) == 1:
                require(bool(np.all(breakaway >= coulomb)), f"stribeck_friction must be at least coulomb_friction "
                        f"{self.coulomb_friction} on every joint (the breakaway friction at rest)", self.stribeck_friction)
        velocity = check_joint_vector("stribeck_velocity", self.stribeck_velocity)
        require(bool(np.all(velocity > 0)), "stribeck_velocity must be > 0 rad/s (0.1: none)", self.stribeck_velocity)
        if self.actuator_time_constant:
            check_effect_bound("actuator_time_constant", check_joint_vector(
                "actuator_time_constant", self.actuator_time_constant, nonnegative=True))
        for name in ("actuation_delay", "measurement_delay"):
            require(np.isfinite(getattr(self, name)) and 0 <= getattr(self, name) <= EFFECT_BOUNDS[name],
                    f"{name} must be in [0, {EFFECT_BOUNDS[name]:g}] s", getattr(self, name))
        for name, needs in (("transmission_stiffness", "rotor_inertia"), ("transmission_damping", "transmission_stiffness"),
                            ("friction_ripple", "coulomb_friction"), ("friction_ripple_period", "friction_ripple")):
            if getattr(self, name):
                check_effect_bound(name, check_joint_vector(name, getattr(self, name), nonnegative=True))
                require(self.is_on(needs) or not self.is_on(name), f"{name} needs {needs} (without it there is "
                        "nothing it acts on, so it would be ignored)", getattr(self, name))
        require(not self.is_on("friction_ripple") or bool(self.friction_ripple_period), "friction_ripple needs "
                "friction_ripple_period (rad, the ripple's period in the joint's position)", self.friction_ripple)
        if self.friction_ripple_period:   # (0 on a joint without ripple: `effect_checks`)
            require(bool(np.all(np.asarray(self.friction_ripple_period, float) >= 0)), "friction_ripple_period must be "
                    ">= 0 rad", self.friction_ripple_period)

    def acting_later(self) -> list[str]:
        """The effects that are on and make the torque acting depend on earlier commands (lag, delay, the motors of
        elastic transmissions): no model of (x, u) holds them."""
        return [name for name in ("actuator_time_constant", "actuation_delay", "transmission_stiffness")
                if self.is_on(name)]

    def beyond_rigid_bodies(self) -> list[str]:
        """The effects that are on and that no rigid-body model (the RK4 plant model, identification) holds (the
        measurement delay is the loop's, not the plant's: a plant model holds the plant without it)."""
        return [name for name in ("stribeck_friction", "friction_ripple") if self.is_on(name)] + self.acting_later()

    def friction_at_rest(self, joints: int) -> np.ndarray:
        """The friction's largest magnitude at rest (joints,) N m: F_c, or F_s with Stribeck friction, times 1 + r
        with friction ripple (the smoothed friction's slope at zero velocity is this over v_s)."""
        stribeck = self.stribeck(joints)
        friction = self.joint_values("coulomb_friction", joints) if stribeck is None else stribeck[0]
        return friction * (1.0 + self.joint_values("friction_ripple", joints))

    def elastic(self, joints: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(k (joints,) N m/rad, d (joints,) N m s/rad, the motors' inertia G² I_r (joints,) kg m²) of the elastic
        transmissions (k = 0: a rigid joint), or None without any; InputError (one line) for an elastic joint without
        a motor inertia."""
        if not self.is_on("transmission_stiffness"):
            return None
        stiffness = self.joint_values("transmission_stiffness", joints)
        ratio = self.joint_values("gear_ratio", joints) if self.gear_ratio else np.ones(joints)
        motor = self.joint_values("rotor_inertia", joints) * ratio ** 2
        if np.any((stiffness > 0) & (motor <= 0)):
            joint = int(np.argmax((stiffness > 0) & (motor <= 0)))
            raise InputError(f"plant effects transmission_stiffness on joint {joint + 1} needs a rotor_inertia > 0 there "
                             "(the motor behind the spring)")
        return stiffness, self.joint_values("transmission_damping", joints), motor

    def ripple(self, joints: int) -> tuple[np.ndarray, np.ndarray] | None:
        """(r (joints,), P (joints,) rad) of the friction ripple, or None without it."""
        on = self.is_on("friction_ripple")
        return (self.joint_values("friction_ripple", joints), self.joint_values("friction_ripple_period", joints)) if on else None

    def stribeck(self, joints: int) -> tuple[np.ndarray, np.ndarray] | None:
        """(F_s (joints,) N m, v_st (joints,) rad/s), or None without Stribeck friction."""
        if not self.stribeck_friction:
            return None
        breakaway = self.joint_values("stribeck_friction", joints)
        coulomb = self.joint_values("coulomb_friction", joints)
        if np.any(breakaway < coulomb):
            raise InputError(f"plant effects stribeck_friction {breakaway.tolist()} must be at least coulomb_friction "
                             f"{coulomb.tolist()} on every joint (the breakaway friction at rest)")
        return breakaway, self.joint_values("stribeck_velocity", joints)

    def joint_values(self, name: str, joints: int) -> np.ndarray:
        """Field `name` as (joints,) values (zeros when empty; one value broadcast); InputError when a
        list has another length."""
        values = getattr(self, name)
        if not values:
            return np.zeros(joints)
        return check_joint_vector(name, values, count=joints, nonnegative=True)

    def is_on(self, name: str) -> bool:
        """Whether the field `name` (per joint, or one number) is non-zero (on some joint)."""
        values = getattr(self, name)
        return any(float(value) > 0 for value in (values if isinstance(values, list) else [values]))

    def coulomb(self, joints: int) -> tuple[np.ndarray, np.ndarray] | None:
        """(F_c (joints,) N m, v_s (joints,) rad/s) of the Coulomb friction, or None without it."""
        if not self.is_on("coulomb_friction"):
            return None
        return self.joint_values("coulomb_friction", joints), self.joint_values("coulomb_velocity_scale", joints)

    def has_torque_noise(self) -> bool:
        return self.is_on("torque_noise_std")

    def summary(self) -> str:
        """One line naming the effects that are on (and the source)."""
        parts = [name.replace("_", " ") for name in ("viscous_friction", "coulomb_friction", "stribeck_friction",
                                                     "friction_ripple", "rotor_inertia", "transmission_stiffness",
                                                     "torque_noise_std", "actuator_time_constant") if self.is_on(name)]
        for name in ("actuation_delay", "measurement_delay"):
            if getattr(self, name) > 0:
                parts.append(f"{name.replace('_', ' ')} {getattr(self, name):g} s")
        if self.payload.mass > 0:
            parts.append(f"payload {self.payload.mass:g} kg")
        if self.joint_damping:
            parts.append("joint damping")
        if self.link_inertia:
            parts.append(f"inertia of {len(self.link_inertia)} links")
        if self.mass_scale:
            parts.append("mass scale " + ", ".join(f"{link} x{factor:g}" for link, factor in self.mass_scale.items()))
        return (", ".join(parts) or "none") + (f"  ({self.source})" if self.source else "")

    def record(self) -> dict:
        """What a dataset or checkpoint records of the effects (every field; joint_damping and link_inertia
        only when given, so files of effects without them read as before)."""
        record = dataclasses.asdict(self)
        for name in ("joint_damping", "link_inertia", "stribeck_friction", "actuator_time_constant", "actuation_delay",
                     "transmission_stiffness", "transmission_damping", "friction_ripple", "friction_ripple_period",
                     "measurement_delay"):
            if not record[name]:
                del record[name]
        if not self.stribeck_friction:
            del record["stribeck_velocity"]
        return record

    @classmethod
    def from_record(cls, record: dict) -> "PlantEffects":
        fields = dict(record)
        fields["payload"] = Payload(**fields.get("payload", {}))
        fields["link_inertia"] = {link: RigidInertia(**values) for link, values in fields.get("link_inertia", {}).items()}
        return cls(**fields)


def load_plant_effects(path) -> PlantEffects:
    """The PlantEffects of a YAML file (InputError with one line for a missing or malformed one, or one that
    sets a key the plant would not use: the Coulomb smoothing scale without Coulomb friction)."""
    effects = load_yaml_config(path, PlantEffects, what="plant effects")
    if "coulomb_velocity_scale" in file_keys(path) and not effects.is_on("coulomb_friction"):
        raise InputError(f"{path}: coulomb_velocity_scale smooths coulomb_friction, which is zero or not given, so "
                         "it would be ignored")
    if "stribeck_velocity" in file_keys(path) and not effects.stribeck_friction:
        raise InputError(f"{path}: stribeck_velocity shapes stribeck_friction, which is not given, so it would be "
                         "ignored")
    return effects


def elastic_step(stiffness: float, damping: float, motor_inertia: float, step: float) -> tuple[np.ndarray, float]:
    """A motor behind an elastic transmission over a plant step h = `step` s (`effect_systems.ElasticTransmissions`):
    against a joint moving at constant velocity the deflection e obeys J e'' + d e' + k e = u (k `stiffness` N m/rad,
    d `damping` N m s/rad, J `motor_inertia` kg m², u held). Returns (S (3, 3): [e(h), e'(h), the integral of e over
    the step] = S [e(0), e'(0), u], exact; Kp N m/rad = beta / h, beta = (k S[2, 1] + d S[0, 1]) / h the slope of the
    spring's mean torque in e'(0), about k h / 2 + d, > 0 where sqrt(k / J) h < pi): the plant's PD actuator with Kp
    and Kd = 0 applies the spring's mean torque over the step whatever velocity the step finds."""
    from scipy.linalg import expm
    system = np.zeros((4, 4))   # d/dt [e, e', u, integral of e]
    system[0, 1], system[3, 0] = 1.0, 1.0
    system[1, :3] = -stiffness / motor_inertia, -damping / motor_inertia, 1.0 / motor_inertia
    exact = expm(system * step)[[0, 1, 3], :3]
    return exact, (stiffness * exact[2, 1] + damping * exact[0, 1]) / step ** 2


def add_effects_to_plant(plant, instance, robot, effects: PlantEffects) -> dict:
    """Before `plant.Finalize()`: the joint damping (replaced) and viscous friction (added) on the arm
    joints, rotor inertia and gear ratio on their actuators (on a rigid joint's: an elastic one's motor is behind its
    spring, `effect_systems.ElasticTransmissions`), on a discrete plant the elastic joints' springs as their
    actuators' PD gains (`elastic_step`'s; Drake's SAP applies them implicitly) with no effort limit (a spring may
    carry more than its motor gives, up to twice a step's torque: the motor's limit clips the command instead), the
    payload welded to the tool frame. Returns the elastic joints' effort limits N m by joint name (the motors'),
    empty without; InputError (one line) for a motor whose spring rings faster than the plant step resolves."""
    from pydrake.math import RigidTransform
    from pydrake.multibody.tree import PdControllerGains
    n = robot.num_joints
    elastic = effects.elastic(n)
    stiffness = elastic[0] if elastic is not None else np.zeros(n)
    damping = effects.joint_values("joint_damping", n) if effects.joint_damping else None
    viscous = effects.joint_values("viscous_friction", n)
    rotor = effects.joint_values("rotor_inertia", n)
    ratio = effects.joint_values("gear_ratio", n) if effects.gear_ratio else np.ones(n)
    actuators, motors = {}, {}   # (GetJointActuatorIndices(instance) lists none before Finalize)
    for index in plant.GetJointActuatorIndices():
        actuator = plant.get_joint_actuator(index)
        if actuator.model_instance() == instance:
            actuators[actuator.joint().name()] = actuator
    for i, name in enumerate(robot.joint_names):
        joint = plant.GetJointByName(name, instance)
        if damping is not None:
            joint.set_default_damping(damping[i])
        if viscous[i] > 0:
            joint.set_default_damping(joint.default_damping() + viscous[i])
        if effects.rotor_inertia:   # (replaces the description's, also by 0)
            actuators[name].set_default_rotor_inertia(0.0 if stiffness[i] > 0 else rotor[i])
            actuators[name].set_default_gear_ratio(ratio[i])
        if stiffness[i] > 0 and plant.time_step() > 0:   # (the spring's mean torque over a step: `elastic_step`)
            step, ringing = plant.time_step(), np.sqrt(stiffness[i] / elastic[2][i])
            if ringing * step >= np.pi:   # (there the spring's mean torque no longer depends on the link's motion)
                raise InputError(f"plant effects transmission_stiffness {stiffness[i]:g} N m/rad on {name} against its "
                                 f"motor's {elastic[2][i]:g} kg m² rings at {ringing / (2 * np.pi):.3g} Hz, which the "
                                 f"plant step {step:g} s cannot resolve (omega h = {ringing * step:.3g} >= pi); lower "
                                 f"--plant-time-step below {bound_text(np.pi / ringing, at_least=False)} s")
            actuators[name].set_controller_gains(PdControllerGains(
                p=elastic_step(stiffness[i], elastic[1][i], elastic[2][i], step)[1], d=0.0))
            motors[name] = actuators[name].effort_limit()
            actuators[name].set_effort_limit(np.inf)
    payload = effects.payload
    if payload.mass > 0:
        body = plant.AddRigidBody("payload", instance, payload.spatial_inertia())
        plant.WeldFrames(frame_by_name(plant, robot.tool_frame, instance), body.body_frame(), RigidTransform())
    return motors


def set_effect_parameters(plant, context, effects: PlantEffects) -> None:
    """The link inertias and per-link mass scales (mass and rotational inertia times the factor, centre
    of mass kept) as parameters of the plant's `context` (a double plant's for link inertias)."""
    for link, inertia in effects.link_inertia.items():
        plant.GetBodyByName(link).SetSpatialInertiaInBodyFrame(context, inertia.spatial_inertia())
    for link, factor in effects.mass_scale.items():
        body = plant.GetBodyByName(link)
        nominal = body.default_spatial_inertia()   # SpatialInertia of the plant's scalar type
        body.SetSpatialInertiaInBodyFrame(context, type(nominal)(nominal.get_mass() * factor, nominal.get_com(),
                                                                 nominal.get_unit_inertia()))


def coulomb_torque(velocity: np.ndarray, friction: np.ndarray, velocity_scale: np.ndarray,
                   stribeck: tuple[np.ndarray, np.ndarray] | None = None, ripple: tuple[np.ndarray, np.ndarray] | None = None,
                   position: np.ndarray | None = None) -> np.ndarray:
    """-F_c tanh(v / v_s) (n,) N m for joint velocities v (n,) rad/s, F_c (n,) N m, v_s (n,) rad/s; with
    `stribeck` (F_s (n,) N m, v_st (n,) rad/s) the friction's magnitude F_c + (F_s - F_c) exp(-(v / v_st)²); with
    `ripple` (r (n,), P (n,) rad) that magnitude times 1 + r sin(2 pi q / P) at the joint positions `position` q (n,)
    rad."""
    if stribeck is not None:
        breakaway, stribeck_velocity = stribeck
        friction = friction + (breakaway - friction) * np.exp(-(velocity / stribeck_velocity) ** 2)
    if ripple is not None:
        amplitude, period = ripple   # (a joint without ripple may have period 0: no ripple there)
        rippled = (amplitude > 0) & (period > 0)
        friction = friction * (1.0 + np.where(rippled, amplitude * np.sin(2 * np.pi * position / np.where(rippled, period, 1)), 0))
    return -friction * np.tanh(velocity / velocity_scale)
