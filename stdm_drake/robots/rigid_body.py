"""Continuous-time rigid-body dynamics of a robot with analytic derivatives, in microseconds.

`RigidBodyDynamics` is built from the Drake plant the toolbox already loads (one source of truth:
the same bodies, inertias with their context's parameters, joint frames and axes, gravity, reflected
rotor inertia, joint damping and actuation matrix), as a Pinocchio model. Pinocchio is the tool made
for exactly this: its articulated-body algorithm (ABA) and the analytic derivatives of ABA
(Carpentier & Mansard, RSS 2018) cost a few microseconds per call for a 6-joint arm, against about a
millisecond for Drake's AutoDiffXd forward dynamics with 18 derivatives. What Pinocchio's ABA leaves
out, the joint damping -D v and the smoothed Coulomb friction -F_c tanh(v / v_s) of the plant
effects, is added exactly on top as a generalized force, with its own derivative.

For n joints (all of the plant's degrees of freedom, revolute or prismatic) and m actuators:

    q̈ = M(q)⁻¹ (B τ + τ_g(q) − C(q, v) v − D v + τ_c(v))

with M including the reflected rotor inertia (Drake's G² I_r on the diagonal, Pinocchio's armature).
Drake stays the simulator; this is the model side (the MPC's and the learned models' physics).
"""
from __future__ import annotations

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.robots.effects import coulomb_torque
from stdm_drake.robots.plant import PlantConfig, make_plant


def _rotation_to_axis(axis: np.ndarray) -> np.ndarray:
    """A rotation R (3, 3) whose third column is the unit `axis`: the frame in which a joint about or
    along `axis` is Pinocchio's RZ / PZ joint."""
    z = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


class RigidBodyDynamics:
    """The forward dynamics of a finalized Drake `plant` (continuous or discrete: only its bodies,
    joints and actuators are read) with the parameters of `context` (mass scales, link inertias),
    and, optionally, Coulomb friction (F_c (n,) N m, v_s (n,) rad/s) on the joints in velocity order.

    acceleration(q, v, tau)                q̈ (N, n) rad/s² for q (N, n) rad, v (N, n) rad/s, τ (N, m) N m
    acceleration_and_jacobians(q, v, tau)  (q̈ (N, n), d q̈ / d(q, v, τ) (N, n, 2n + m))

    Rows are evaluated one Pinocchio call each (a few µs); every other operation is batched.
    """

    def __init__(self, plant, context=None, coulomb: tuple[np.ndarray, np.ndarray] | None = None):
        import pinocchio as pin
        from pydrake.multibody.tree import BodyIndex, PrismaticJoint, RevoluteJoint
        context = context if context is not None else plant.CreateDefaultContext()
        n, m = plant.num_velocities(), plant.num_actuators()
        if plant.num_positions() != n:
            raise InputError(f"rigid-body dynamics needs one position per velocity, the plant has "
                             f"{plant.num_positions()} and {n} (a floating or ball joint)")
        self.num_joints, self.action_dim = n, m
        zero = plant.CreateDefaultContext()
        zero.SetTimeStateAndParametersFrom(context)
        plant.SetPositionsAndVelocities(zero, np.zeros(2 * n))
        world = plant.world_body().index()
        joint_of_child = {}
        for index in plant.GetJointIndices():
            joint = plant.get_joint(index)
            joint_of_child[joint.child_body().index()] = joint
        moving = [joint for joint in joint_of_child.values() if joint.num_velocities() > 0]
        for joint in moving:
            if not isinstance(joint, (RevoluteJoint, PrismaticJoint)):
                raise InputError(f"rigid-body dynamics: joint {joint.name()!r} is {joint.type_name()}; "
                                 "only revolute and prismatic joints are supported")

        def owner(body_index):
            """The moving joint a body is rigidly attached to (None: welded to the world)."""
            while body_index != world:
                joint = joint_of_child.get(body_index)
                if joint is None:     # a body with no inboard joint is a free body: the plant refused it already
                    raise InputError(f"rigid-body dynamics: body {plant.get_body(body_index).name()!r} has no joint")
                if joint.num_velocities() > 0:
                    return joint
                body_index = joint.parent_body().index()
            return None

        def ancestry(joint):
            """The velocity starts of the moving joints from the root down to `joint`: sorted, they put every
            joint after its parent and each subtree's joints together (depth first, as Pinocchio numbers them)."""
            chain, parent = [joint.velocity_start()], owner(joint.parent_body().index())
            while parent is not None:
                chain.append(parent.velocity_start())
                parent = owner(parent.parent_body().index())
            return tuple(reversed(chain))

        model = pin.Model()
        model.gravity = pin.Motion(np.asarray(plant.gravity_field().gravity_vector(), dtype=float), np.zeros(3))
        frames, ids = {}, {}   # Drake joint index -> X_WJ at q = 0 (pin.SE3), Pinocchio joint id
        order = sorted(moving, key=ancestry)
        for joint in order:
            X_WF = joint.frame_on_parent().CalcPoseInWorld(zero)
            if isinstance(joint, RevoluteJoint):
                axis, kind = joint.revolute_axis(), pin.JointModelRZ()
            else:
                axis, kind = joint.translation_axis(), pin.JointModelPZ()
            X_WJ = pin.SE3(X_WF.rotation().matrix() @ _rotation_to_axis(axis), X_WF.translation())
            parent = owner(joint.parent_body().index())
            parent_id = 0 if parent is None else ids[parent.index()]
            placement = X_WJ if parent is None else frames[parent.index()].actInv(X_WJ)
            ids[joint.index()] = model.addJoint(parent_id, kind, placement, joint.name())
            frames[joint.index()] = X_WJ
        for number in range(1, plant.num_bodies()):   # (body 0 is the world)
            body = plant.get_body(BodyIndex(number))
            joint = owner(body.index())
            if joint is None:
                continue
            inertia = body.CalcSpatialInertiaInBodyFrame(zero)
            mass = inertia.get_mass()
            if mass == 0:
                continue
            # from the dynamic parameters about the body origin, as Drake holds them (no shift to the centre of
            # mass, whose rounding makes a valid point mass's or thin rod's inertia a hair non-positive there)
            first = mass * np.asarray(inertia.get_com(), dtype=float)
            about_origin = inertia.CalcRotationalInertia().CopyToFullMatrix3()
            parameters = np.array([mass, *first, about_origin[0, 0], about_origin[0, 1], about_origin[1, 1],
                                   about_origin[0, 2], about_origin[1, 2], about_origin[2, 2]])
            X_WB = body.body_frame().CalcPoseInWorld(zero)
            X_JB = frames[joint.index()].actInv(pin.SE3(X_WB.rotation().matrix(), X_WB.translation()))
            model.appendBodyToJoint(ids[joint.index()], X_JB.act(pin.Inertia.FromDynamicParameters(parameters)),
                                    pin.SE3.Identity())
        # Drake's velocity index of each Pinocchio velocity (Pinocchio orders its joints depth first)
        drake_index = np.empty(n, dtype=int)
        damping = np.zeros(n)
        for joint in order:
            pin_index = model.joints[ids[joint.index()]].idx_v
            drake_index[pin_index] = joint.velocity_start()
            damping[joint.velocity_start()] = joint.GetDampingVector(context)[0]
        armature = np.zeros(n)
        for index in plant.GetJointActuatorIndices():
            actuator = plant.get_joint_actuator(index)
            armature[actuator.joint().velocity_start()] += actuator.calc_reflected_inertia(context)
        model.armature = armature[drake_index]
        self.model, self.data = model, model.createData()
        self._pin = pin
        self._to_pin = drake_index                      # q_pin = q_drake[_to_pin]
        self._from_pin = np.argsort(drake_index)        # q_drake = q_pin[_from_pin]
        self.damping = damping                          # D (n,) N m s/rad, Drake order
        self.actuation = np.asarray(plant.MakeActuationMatrix(), dtype=float)    # B (n, m)
        self.coulomb = None if coulomb is None else tuple(np.asarray(c, dtype=float) for c in coulomb)
        # fast paths: Pinocchio's joint order is Drake's, the action is the joint torque, no extra forces
        self._same_order = bool(np.array_equal(drake_index, np.arange(n)))
        self._torque_is_force = m == n and bool(np.array_equal(self.actuation, np.eye(n)))
        self._extra_forces = bool(damping.any()) or self.coulomb is not None

    # -- forces beyond Pinocchio's ABA -----------------------------------------------------------------

    def _generalized_force(self, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """B τ − D v + τ_c(v) (N, n) for rows (N, ·), or (n,) for one row: Drake order."""
        force = tau if self._torque_is_force else tau @ self.actuation.T
        if not self._extra_forces:
            return force
        force = force - self.damping * v
        if self.coulomb is not None:
            force += coulomb_torque(v, *self.coulomb)
        return force

    def _force_velocity_slope(self, v: np.ndarray) -> np.ndarray:
        """d(−D v + τ_c(v)) / dv, diagonal (N, n)."""
        slope = np.broadcast_to(-self.damping, v.shape).copy()
        if self.coulomb is not None:
            friction, scale = self.coulomb
            slope -= friction / scale / np.cosh(v / scale) ** 2
        return slope

    def _rows(self, q, v, tau):
        q, v, tau = np.atleast_2d(q), np.atleast_2d(v), np.atleast_2d(tau)
        n = self.num_joints
        if q.dtype != np.float64 or v.dtype != np.float64 or tau.dtype != np.float64:
            q, v, tau = q.astype(np.float64), v.astype(np.float64), tau.astype(np.float64)
        if q.shape[1] != n or v.shape != q.shape or tau.shape != (len(q), self.action_dim):
            raise InputError(f"rigid-body dynamics needs q, v (N, {n}) and tau (N, {self.action_dim}), got "
                             f"{q.shape}, {v.shape}, {tau.shape}")
        return q, v, tau

    def inverse_mass_matrix(self, q) -> np.ndarray:
        """M(q)⁻¹ (n, n) at q (n,) rad, reflected rotor inertia included (Drake order)."""
        q = np.asarray(q, dtype=np.float64)
        inverse = self._pin.computeMinverse(self.model, self.data, q[self._to_pin])   # (both triangles filled)
        back = self._from_pin
        return inverse[back][:, back]

    def acceleration(self, q, v, tau) -> np.ndarray:
        """q̈ (N, n) rad/s² at q (N, n) rad, v (N, n) rad/s under τ (N, m) N m."""
        q, v, tau = self._rows(q, v, tau)
        force = self._generalized_force(v, tau)
        if not self._same_order:
            to = self._to_pin
            q, v, force = q[:, to], v[:, to], force[:, to]
        out = np.empty_like(q)
        aba, model, data = self._pin.aba, self.model, self.data
        for i in range(len(q)):
            out[i] = aba(model, data, q[i], v[i], force[i])
        return out if self._same_order else out[:, self._from_pin]

    def acceleration_row(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """q̈ (n,) for one row q, v (n,) float64, τ (m,), unchecked: the hot path of sequential rollouts."""
        force = self._generalized_force(v, tau)
        if self._same_order:
            return self._pin.aba(self.model, self.data, q, v, force)
        to = self._to_pin
        return self._pin.aba(self.model, self.data, q[to], v[to], force[to])[self._from_pin]

    def acceleration_and_jacobians(self, q, v, tau) -> tuple[np.ndarray, np.ndarray]:
        """(q̈ (N, n), d q̈ / d(q, v, τ) (N, n, 2n + m)), analytic (Pinocchio's ABA derivatives and the
        extra forces' own slopes by the chain rule)."""
        q, v, tau = self._rows(q, v, tau)
        n, count = self.num_joints, len(q)
        force = self._generalized_force(v, tau)
        qp, vp = (q, v) if self._same_order else (q[:, self._to_pin], v[:, self._to_pin])
        fp = force if self._same_order else force[:, self._to_pin]
        acceleration = np.empty((count, n))
        d_q, d_v, inverse = np.empty((count, n, n)), np.empty((count, n, n)), np.empty((count, n, n))
        derivatives, model, data = self._pin.computeABADerivatives, self.model, self.data
        for i in range(count):
            d_q[i], d_v[i], inverse[i] = derivatives(model, data, qp[i], vp[i], fp[i])
            acceleration[i] = data.ddq
        if not self._same_order:    # Pinocchio order -> Drake order on both axes
            back = self._from_pin
            acceleration = acceleration[:, back]
            d_q, d_v, inverse = (array[:, back][:, :, back] for array in (d_q, d_v, inverse))
        if self._extra_forces:
            d_v += inverse * self._force_velocity_slope(v)[:, None, :]
        jacobian = np.empty((count, n, 2 * n + self.action_dim))
        jacobian[:, :, :n], jacobian[:, :, n:2 * n] = d_q, d_v
        jacobian[:, :, 2 * n:] = inverse if self._torque_is_force else inverse @ self.actuation
        return acceleration, jacobian


def robot_dynamics(robot, effects=None) -> RigidBodyDynamics:
    """The `RigidBodyDynamics` of `robot`'s description (effects None: the nominal model a user has) or of
    the affected plant with `effects` (`robots.effects.PlantEffects`: friction, rotor inertia, payload,
    link inertias and mass scales, as the simulator applies them), built from the plant `make_plant` makes."""
    beyond = effects.beyond_rigid_bodies() if effects is not None else []
    if beyond:
        raise InputError(f"the rigid-body model of the affected plant does not hold its {', '.join(beyond)} (effects "
                         "beyond rigid bodies, between the command and the joints): use the description's plant")
    config = PlantConfig.continuous()
    config.effects = effects
    plant, _ = make_plant(config, robot=robot)
    context = plant.CreateDefaultContext()
    config.set_parameters(plant, context)
    coulomb = effects.coulomb(robot.num_joints) if effects is not None else None
    return RigidBodyDynamics(plant, context, coulomb)
