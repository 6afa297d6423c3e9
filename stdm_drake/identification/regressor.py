"""The inverse-dynamics regressor of a robot's description: joint torques linear in its parameters.

For a fully actuated robot of n joints with B moving rigid links ("links": each set of bodies welded
together and moved by a joint, its parameters those of its heaviest body, which absorbs whatever is
welded to it, e.g. a payload on the tool frame):

    tau = Y(q, v, v̇) pi + F_v v + F_c tanh(v / v_s) + I_a v̇ + tau_0(q, v, v̇)

pi (10 B): per link [m kg, m c (3) kg m, Ixx, Iyy, Izz, Ixy, Ixz, Iyz kg m²] (c the centre of mass and
I the rotational inertia about the link frame's origin, both in the link frame; Drake's
`SpatialInertia` about the body origin); F_v, F_c, I_a (n each): per joint viscous friction N m s/rad
(all of the joint's damping), Coulomb friction N m (smoothed by the velocity scale v_s rad/s) and
reflected rotor inertia kg m²; tau_0 the fixed part (bodies welded to a link other than its
parameter body keep their description's inertia). Parameters in this order: `names`.

Y comes from Drake: the description's plant converted to AutoDiff, each link's `SpatialInertia`
seeded with the derivatives of its 10 parameters, `CalcInverseDynamics` with gravity; since tau is
linear in pi, its gradient is Y exactly (at any parameter point) and tau_0 = tau − Y pi. About 0.3 ms
per sample for a 6-joint arm (tools/bench_regressor.py, BENCHMARKS.md).
"""
from __future__ import annotations

import numpy as np

from stdm_drake.errors import InputError

LINK_PARAMETERS = ("m", "mcx", "mcy", "mcz", "Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")
JOINT_PARAMETERS = ("viscous", "coulomb", "rotor_inertia")
# The parameter point the AutoDiff pass is evaluated at: a unit mass with a unit inertia about the origin
# (any point gives the same gradient; this one keeps c = h / m defined for links the description leaves
# massless).
_EVALUATION_POINT = np.array([1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0])


def link_parameters(spatial_inertia) -> np.ndarray:
    """The 10 parameters (m, m c, I about the origin) of a Drake `SpatialInertia` about a body's origin."""
    mass = spatial_inertia.get_mass()
    inertia = spatial_inertia.CalcRotationalInertia().CopyToFullMatrix3()
    return np.concatenate([[mass], mass * np.asarray(spatial_inertia.get_com()),
                           np.diag(inertia), [inertia[0, 1], inertia[0, 2], inertia[1, 2]]])


def pseudo_inertia(parameters) -> np.ndarray:
    """The 4x4 pseudo-inertia [[½ tr(I) 1 − I, h], [hᵀ, m]] of one link's 10 parameters (any scalar type:
    numbers or symbolic expressions); positive semidefinite exactly when the parameters are those of a
    physical mass distribution (Wensing, Kim, Slotine 2017)."""
    m, hx, hy, hz, ixx, iyy, izz, ixy, ixz, iyz = parameters
    half_trace = 0.5 * (ixx + iyy + izz)
    return np.array([[half_trace - ixx, 0.0 - ixy, 0.0 - ixz, hx],
                     [0.0 - ixy, half_trace - iyy, 0.0 - iyz, hy],
                     [0.0 - ixz, 0.0 - iyz, half_trace - izz, hz],
                     [hx, hy, hz, m]], dtype=object)


class InverseDynamicsRegressor:
    """Y(q, v, v̇) of `robot`'s description (see the module docstring); refuses a robot with unactuated
    joints (friction and torque per joint need an actuator on each)."""

    def __init__(self, robot):
        from pydrake.autodiffutils import AutoDiffXd, InitializeAutoDiff
        from pydrake.multibody.plant import MultibodyPlant
        from pydrake.multibody.tree import MultibodyForces_, SpatialInertia_, UnitInertia_
        robot.check_fully_actuated("identification")
        self.robot = robot
        plant = MultibodyPlant(0.0)
        instance = robot.add_to(plant)
        for index in plant.GetJointActuatorIndices():   # rotor inertia and damping are parameters here
            plant.get_joint_actuator(index).set_default_rotor_inertia(0.0)
        for index in plant.GetJointIndices(instance):
            joint = plant.get_joint(index)
            if joint.num_velocities():
                joint.set_default_damping_vector(np.zeros(joint.num_velocities()))
        plant.Finalize()
        self.plant = plant
        self.links = self._parameter_bodies(plant, instance)
        self.num_joints = n = robot.num_joints
        self._velocity_indices = np.array([plant.GetJointByName(name, instance).velocity_start()
                                           for name in robot.joint_names])
        if plant.num_velocities() != n:
            raise InputError(f"robot {robot.name}: identification needs a plant whose velocities are the arm "
                             f"joints ({n}), got {plant.num_velocities()}")
        self.names = tuple(f"{link}.{p}" for link in self.links for p in LINK_PARAMETERS) + tuple(
            f"{joint}.{p}" for p in JOINT_PARAMETERS for joint in robot.joint_names)
        self.num_link_parameters = 10 * len(self.links)
        self._autodiff = plant.ToAutoDiffXd()
        self._context = self._autodiff.CreateDefaultContext()
        self._point = np.tile(_EVALUATION_POINT, len(self.links))
        seeded = InitializeAutoDiff(self._point).ravel()
        for k, link in enumerate(self.links):
            p = seeded[10 * k:10 * k + 10]
            mass, com = p[0], p[1:4] / p[0]
            about_origin = np.array([[p[4], p[7], p[8]], [p[7], p[5], p[9]], [p[8], p[9], p[6]]]) / mass
            unit = UnitInertia_[AutoDiffXd](about_origin[0, 0], about_origin[1, 1], about_origin[2, 2],
                                            about_origin[0, 1], about_origin[0, 2], about_origin[1, 2])
            body = self._autodiff.GetBodyByName(link, instance)
            body.SetSpatialInertiaInBodyFrame(self._context, SpatialInertia_[AutoDiffXd](mass, com, unit, True))
        self._forces = MultibodyForces_[AutoDiffXd](self._autodiff)

    @staticmethod
    def _parameter_bodies(plant, instance) -> tuple:
        """One body per moving welded group of the robot (its heaviest, by the description): the links."""
        world = {body.index() for body in plant.GetBodiesWeldedTo(plant.world_body())}
        links, seen = [], set()
        for index in plant.GetBodyIndices(instance):
            if index in world or index in seen:
                continue
            group = plant.GetBodiesWeldedTo(plant.get_body(index))
            seen |= {body.index() for body in group}
            heaviest = max(group, key=lambda body: (body.default_mass(), -int(body.index())))
            links.append(heaviest.name())
        return tuple(links)

    def parameters(self, effects=None) -> np.ndarray:
        """pi (P,) of the description (effects None: the regression's prior) or of the plant `effects`
        describe (the truth of data simulated with them): each link's welded group's composite inertia
        about the link frame's origin (a payload included) less what the description's other bodies of the
        group hold fixed in tau_0; each joint's total damping (the description's, or the effects'
        joint_damping, plus viscous friction), Coulomb friction and reflected rotor inertia."""
        from pydrake.multibody.plant import MultibodyPlant
        from stdm_drake.robots.effects import add_effects_to_plant, set_effect_parameters   # lazy: pydrake

        def plant_of(plant_effects):
            plant = MultibodyPlant(0.0)
            instance = self.robot.add_to(plant)
            if plant_effects is not None:
                add_effects_to_plant(plant, instance, self.robot, plant_effects)
            plant.Finalize()
            context = plant.CreateDefaultContext()
            if plant_effects is not None:
                set_effect_parameters(plant, context, plant_effects)
            return plant, instance, context

        def composite(plant, instance, context, link, others_only):
            body = plant.GetBodyByName(link, instance)
            group = [other.index() for other in plant.GetBodiesWeldedTo(body)
                     if not (others_only and other.index() == body.index())]
            return link_parameters(plant.CalcSpatialInertia(context, body.body_frame(), group))

        description = plant_of(None)
        plant, instance, context = plant_of(effects) if effects is not None else description
        inertial = [composite(plant, instance, context, link, False) - composite(*description, link, True)
                    for link in self.links]
        actuators = {plant.get_joint_actuator(i).joint().name(): plant.get_joint_actuator(i)
                     for i in plant.GetJointActuatorIndices(instance)}
        damping = np.array([plant.GetJointByName(name, instance).default_damping() for name in self.robot.joint_names])
        rotor = np.array([actuators[name].default_reflected_inertia() if name in actuators else 0.0
                          for name in self.robot.joint_names])
        coulomb = (effects.joint_values("coulomb_friction", self.num_joints) if effects is not None
                   else np.zeros(self.num_joints))
        return np.concatenate(inertial + [damping, coulomb, rotor])

    def rigid_body_rows(self, q: np.ndarray, v: np.ndarray, vd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Y_rb (N, n, 10 B), tau_0 (N, n)) for q, v (N, n) rad, rad/s and v̇ (N, n) rad/s²."""
        from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, ExtractValue
        q, v, vd = (np.atleast_2d(np.asarray(values, dtype=np.float64)) for values in (q, v, vd))
        count, n = q.shape
        plant, context, forces = self._autodiff, self._context, self._forces
        order = self._velocity_indices
        rows = np.empty((count, n, self.num_link_parameters))
        fixed = np.empty((count, n))
        positions, velocities = np.empty(n, dtype=object), np.empty(n, dtype=object)
        accelerations = np.empty(n, dtype=object)
        for i in range(count):
            positions[order] = [AutoDiffXd(value) for value in q[i]]
            velocities[order] = [AutoDiffXd(value) for value in v[i]]
            accelerations[order] = [AutoDiffXd(value) for value in vd[i]]
            plant.SetPositions(context, positions)
            plant.SetVelocities(context, velocities)
            plant.CalcForceElementsContribution(context, forces)
            torque = plant.CalcInverseDynamics(context, accelerations, forces)[order]
            rows[i] = ExtractGradient(torque)
            fixed[i] = ExtractValue(torque).ravel() - rows[i] @ self._point
        return rows, fixed

    def joint_rows(self, v: np.ndarray, vd: np.ndarray, velocity_scale) -> np.ndarray:
        """The friction and rotor-inertia columns (N, n, 3 n): diag(v), diag(tanh(v / v_s)), diag(v̇)."""
        v, vd = np.atleast_2d(v), np.atleast_2d(vd)
        count, n = v.shape
        scale = np.broadcast_to(np.asarray(velocity_scale, dtype=float), (n,))
        rows = np.zeros((count, n, 3 * n))
        joints = np.arange(n)
        rows[:, joints, joints] = v
        rows[:, joints, n + joints] = np.tanh(v / scale)
        rows[:, joints, 2 * n + joints] = vd
        return rows
