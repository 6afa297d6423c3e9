"""The plant effects' systems in a plant's diagram (`plant.make_plant` adds them): the joint friction driving the
plant's applied generalized force, the actuators between a torque command and the plant's actuation, the motors of
elastic transmissions between the actuators and the plant, the measurement delay on the plant's state, and the
torque noise between a controller and the actuators (`effects.PlantEffects` holds what each is; its module docstring
the models)."""
import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem
from pydrake.systems.primitives import DiscreteTimeDelay

from stdm_drake.errors import InputError
from stdm_drake.robots.effects import PlantEffects, coulomb_torque, elastic_step


class JointFriction(LeafSystem):
    """Coulomb (and Stribeck) joint friction of the arm joints as a generalized force: input "state" (the plant's
    [q, v]), output "generalized_force" (the plant's velocities), `coulomb_torque` of each arm joint's velocity, 0
    elsewhere. Direct feedthrough: a discrete plant samples it every step."""

    def __init__(self, plant, joint_velocity_indices, friction: np.ndarray, velocity_scale: np.ndarray,
                 stribeck: tuple[np.ndarray, np.ndarray] | None = None, ripple=None, joint_position_indices=None):
        super().__init__()
        self._indices = np.asarray(joint_velocity_indices, dtype=int)
        self._positions = None if joint_position_indices is None else np.asarray(joint_position_indices, dtype=int)
        self._friction = np.asarray(friction, dtype=float)
        self._scale = np.asarray(velocity_scale, dtype=float)
        self._stribeck, self._ripple = stribeck, ripple
        self._nq, self._nv = plant.num_positions(), plant.num_velocities()
        self._state = self.DeclareVectorInputPort("state", self._nq + self._nv)
        self.DeclareVectorOutputPort("generalized_force", BasicVector(self._nv), self._output)

    def _output(self, context, output) -> None:
        state = self._state.Eval(context)
        v = state[self._nq:]
        position = None if self._positions is None else state[self._positions]
        force = np.zeros(self._nv)
        force[self._indices] = coulomb_torque(v[self._indices], self._friction, self._scale, self._stribeck,
                                              self._ripple, position)
        output.SetFromVector(force)


class ActuatorDynamics(LeafSystem):
    """The actuators between a torque command and the joints: input "command" (m,) N m, output "torque" (m,) N m,
    updated every plant step h. The command reaches the lag `delay_steps` steps later (a shift register of the
    commands, w_k = command_(k - d)); joint j's torque follows w through a first-order lag of time constant T_j,
    discretized exactly for a command held over each step: τ_(k+1) = τ_k + (1 - exp(-h / T_j)) (w_k - τ_k), the
    output τ_k (a joint with T_j = 0: w_k). A step of the command from rest reaches u (1 - exp(-(t - d h) / T))
    at t = k h, k >= d: the lag's continuous response, sampled at the start of each plant step, where the discrete
    plant samples its input (so a lagged joint, however small T, answers a change of command from the next plant
    step on; a joint with T = 0 at once). `start` sets every state to one torque, as if it had been held before (the
    robot at rest holding it)."""

    def __init__(self, time_constant: np.ndarray, delay_steps: int, step: float):
        super().__init__()
        self._lagged = np.asarray(time_constant, dtype=float) > 0
        self._keep = np.where(self._lagged, np.exp(-step / np.where(self._lagged, time_constant, 1.0)), 0.0)
        self._delay, self._m = int(delay_steps), len(self._lagged)
        self._command = self.DeclareVectorInputPort("command", self._m)
        # state: [τ (m), the delayed commands oldest first (d m)]
        self._state = self.DeclareDiscreteState((1 + self._delay) * self._m)
        self.DeclarePeriodicDiscreteUpdateEvent(step, 0.0, self._update)
        self.DeclareVectorOutputPort("torque", BasicVector(self._m), self._output,
                                     prerequisites_of_calc={self.xd_ticket()} if self._delay else
                                     {self.xd_ticket(), self._command.ticket()})

    def _lag_input(self, context) -> np.ndarray:
        if self._delay:
            return context.get_discrete_state(self._state).get_value()[self._m:2 * self._m]
        return self._command.Eval(context)

    def _update(self, context, discrete_state) -> None:
        state = context.get_discrete_state(self._state).get_value()
        held, torque = self._lag_input(context), state[:self._m]
        new = np.empty_like(state)
        new[:self._m] = held + self._keep * (torque - held)
        if self._delay:
            new[self._m:-self._m] = state[2 * self._m:]
            new[-self._m:] = self._command.Eval(context)
        discrete_state.get_mutable_vector(self._state).SetFromVector(new)

    def _output(self, context, output) -> None:
        torque = context.get_discrete_state(self._state).get_value()[:self._m]
        output.SetFromVector(np.where(self._lagged, torque, self._lag_input(context)))

    def start(self, context, torque: np.ndarray) -> None:
        """Every state variable of this system's `context` at `torque` (m,) N m, held before."""
        context.SetDiscreteState(self._state, np.tile(np.asarray(torque, dtype=float), 1 + self._delay))


class ElasticTransmissions(LeafSystem):
    """The motors of elastic transmissions: input "command" (m,) N m (the actuators' torque), input "state" (the
    plant's [q, v]); outputs "desired_state" (2 m,) (what the plant's PD-actuated elastic joints are pulled toward),
    "feedforward" (m,) N m (the command on the rigid joints, 0 on the elastic ones: the plant's actuation input) and
    "link_torque" (m,) N m (what the joints get now: k (theta - q) + d (theta' - q') on an elastic joint, unclipped:
    the plant's elastic actuators have no effort limit, the motors' clips the command; the command on a rigid one).
    Actuator order throughout (the order of the plant's actuation input).

    Motor j: J theta'' = u - k (theta - q) - d (theta' - q'). Over a plant step of h the discrete plant moves each
    joint along a line, q(s) = q_k + w s with w = v_(k+1) its velocity after the step, so the deflection
    e = theta - q(s) obeys J e'' + d e' + k e = u from e(0) = theta_k - q_k, e'(0) = theta'_k - w, integrated exactly
    (`effects.elastic_step`). The spring's mean torque over the step is then c + beta (theta'_k - w), linear in the
    unknown w; the plant's implicit PD actuator, with the stiffness `effects.elastic_step` gives (Kp = beta / h,
    Kd = 0) and the desired position q_k + h theta'_k + c / Kp, applies exactly that torque for whatever w its step
    finds. So the link gets the impulse the motor gives (the pair's momentum holds to rounding), and the spring is
    implicit on both sides: stable at any stiffness on the lightest link, where the plant step resolves the motor
    (sqrt(k / J) h < pi, else refused). The price is Drake's first-order step of the link (end-of-step velocity): the spring loses energy at about h k / (2 I) per second (I the
    link's inertia about the joint), a numerical damping ratio below 0.25 omega h at the pair's frequency omega (tested);
    choose the plant step so that omega h is small. (Drake's discrete plant steps before this system's update, which
    sees the joints after the step: (q_k, w) = (q_(k+1) - h v_(k+1), v_(k+1)).)"""

    def __init__(self, plant, actuator_joints, stiffness, damping, motor_inertia, effort, step: float):
        super().__init__()
        self._q = np.array([joint.position_start() for joint in actuator_joints])
        self._v = np.array([plant.num_positions() + joint.velocity_start() for joint in actuator_joints])
        self._k, self._d = np.asarray(stiffness, float), np.asarray(damping, float)
        self._elastic, self._effort, self._h = self._k > 0, np.asarray(effort, float), step   # (effort: the motors')
        m = len(self._k)
        self._step, self._gain = np.zeros((m, 3, 3)), np.ones(m)   # (rigid joints: unused, kept finite)
        for j in np.flatnonzero(self._elastic):
            self._step[j], self._gain[j] = elastic_step(self._k[j], self._d[j], motor_inertia[j], step)
        self._command = self.DeclareVectorInputPort("command", m)
        self._state = self.DeclareVectorInputPort("state", plant.num_positions() + plant.num_velocities())
        self._motor = self.DeclareDiscreteState(2 * m)   # [theta (m), theta' (m)]
        self.DeclarePeriodicDiscreteUpdateEvent(step, 0.0, self._update)
        self.DeclareVectorOutputPort("desired_state", BasicVector(2 * m), self._desired)
        self.DeclareVectorOutputPort("feedforward", BasicVector(m), self._feedforward,
                                     prerequisites_of_calc={self._command.ticket()})
        self.DeclareVectorOutputPort("link_torque", BasicVector(m), self._link_torque)

    def _joints(self, context) -> tuple[np.ndarray, np.ndarray]:
        state = self._state.Eval(context)
        return state[self._q], state[self._v]

    def _motors(self, context) -> tuple[np.ndarray, np.ndarray]:
        motor = context.get_discrete_state(self._motor).get_value()
        return motor[:len(self._k)], motor[len(self._k):]

    def _update(self, context, discrete_state) -> None:
        theta, rate = self._motors(context)
        q_after, w = self._joints(context)   # (after the plant's step)
        start = np.stack([theta - (q_after - self._h * w), rate - w, self._motor_torque(context)], axis=1)
        end = np.einsum("jab,jb->ja", self._step[:, :2], start)   # [e(h), e'(h)] (m, 2)
        new = np.concatenate([q_after + end[:, 0], w + end[:, 1]])
        discrete_state.get_mutable_vector(self._motor).SetFromVector(np.where(np.tile(self._elastic, 2), new, 0.0))

    def _desired(self, context, output) -> None:
        theta, rate = self._motors(context)
        q, _ = self._joints(context)   # (before the plant's step: it asks now)
        step, k, d, h = self._step, self._k, self._d, self._h
        e0, u = theta - q, self._motor_torque(context)
        # c: the spring's mean torque over the step at e'(0) = 0, (k integral of e + d (e(h) - e(0))) / h
        mean = (k * (step[:, 2, 0] * e0 + step[:, 2, 2] * u) + d * ((step[:, 0, 0] - 1.0) * e0 + step[:, 0, 2] * u)) / h
        output.SetFromVector(np.concatenate([q + h * rate + mean / self._gain, rate]))   # (rate: Kd = 0, unused)

    def _motor_torque(self, context) -> np.ndarray:
        """The command (m,) N m clipped to the motors' effort limits (the plant clips no elastic joint's torque: its
        spring may carry more than the motor gives)."""
        return np.clip(self._command.Eval(context), -self._effort, self._effort)

    def _feedforward(self, context, output) -> None:
        output.SetFromVector(np.where(self._elastic, 0.0, self._command.Eval(context)))

    def _link_torque(self, context, output) -> None:
        theta, rate = self._motors(context)
        q, v = self._joints(context)
        spring = self._k * (theta - q) + self._d * (rate - v)
        output.SetFromVector(np.where(self._elastic, spring, self._command.Eval(context)))

    def start(self, context, torque: np.ndarray) -> None:
        """The motors of this system's `context` at rest holding `torque` (m,) N m against the joints' state now: each
        spring deflected by torque / k, each motor moving with its joint."""
        q, v = self._joints(context)
        theta = q + np.where(self._elastic, np.asarray(torque, float) / np.where(self._elastic, self._k, 1.0), 0.0)
        context.SetDiscreteState(self._motor, np.where(np.tile(self._elastic, 2), np.concatenate([theta, v]), 0.0))


ACTUATORS = "actuators"   # the name of the ActuatorDynamics system in a plant's diagram
MOTORS = "elastic_transmissions"   # the ElasticTransmissions system's
MEASUREMENT = "measurement_delay"   # the measurement delay's (a DiscreteTimeDelay of the plant's state)


def add_effect_systems(builder, plant, instance, robot, effects: PlantEffects, time_step: float,
                       motors: dict | None = None) -> None:
    """The effects' systems in the diagram of `plant` (finalized): the joint friction driving its applied
    generalized force; the actuators (`ActuatorDynamics`, named ACTUATORS) and the motors of elastic transmissions
    (`ElasticTransmissions`, MOTORS) between a command and its actuation, the first of them taking the "command"
    `actuation_input` returns; the measurement delay (MEASUREMENT) on its state, which `measured_state_output`
    returns; motors: the elastic joints' effort limits by name (`effects.add_effects_to_plant`'s: their motors'). InputError
    (one line) for a delay that is no whole number of plant steps, or an effect that acts every plant step (lag,
    delays, elastic transmissions) on a continuous plant."""
    n = robot.num_joints
    coulomb = effects.coulomb(n)
    joints = [plant.GetJointByName(name, instance) for name in robot.joint_names]
    if coulomb is not None:
        indices = [joint.velocity_start() for joint in joints]
        friction = builder.AddSystem(JointFriction(plant, indices, *coulomb, effects.stribeck(n), effects.ripple(n),
                                                   [joint.position_start() for joint in joints]))
        friction.set_name("joint_friction")
        builder.Connect(plant.get_state_output_port(), friction.get_input_port())
        builder.Connect(friction.get_output_port(), plant.get_applied_generalized_force_input_port())
    lag = effects.joint_values("actuator_time_constant", robot.action_dim)
    stepped = effects.acting_later() + (["measurement_delay"] if effects.measurement_delay > 0 else [])
    if not stepped:
        return
    if time_step <= 0:
        raise InputError(f"plant effects {' and '.join(stepped)} act every plant step: they need a discrete plant "
                         "(--plant-time-step > 0)")
    delays = {name: plant_steps(effects, name, time_step) for name in ("actuation_delay", "measurement_delay")}
    command = plant.get_actuation_input_port()
    elastic = effects.elastic(n)
    if elastic is not None:
        actuated = [plant.get_joint_actuator(index) for index in plant.GetJointActuatorIndices()]
        if any(actuator.model_instance() != instance for actuator in actuated):
            raise InputError("plant effects transmission_stiffness: the plant has actuators outside the arm's model "
                             "(a nested model's); elastic transmissions need the arm's alone")
        order = [robot.joint_names.index(actuator.joint().name()) for actuator in actuated]
        motors = builder.AddSystem(ElasticTransmissions(
            plant, [actuator.joint() for actuator in actuated], *(values[order] for values in elastic),
            [(motors or {}).get(actuator.joint().name(), actuator.effort_limit()) for actuator in actuated], time_step))
        motors.set_name(MOTORS)
        builder.Connect(plant.get_state_output_port(), motors.GetInputPort("state"))
        builder.Connect(motors.GetOutputPort("desired_state"), plant.get_desired_state_input_port(instance))
        builder.Connect(motors.GetOutputPort("feedforward"), command)
        command = motors.GetInputPort("command")
    if np.any(lag > 0) or delays["actuation_delay"]:
        actuators = builder.AddSystem(ActuatorDynamics(lag, delays["actuation_delay"], time_step))
        actuators.set_name(ACTUATORS)
        builder.Connect(actuators.get_output_port(), command)
    if delays["measurement_delay"]:
        size = plant.num_positions() + plant.num_velocities()
        measurement = builder.AddSystem(DiscreteTimeDelay(time_step, delays["measurement_delay"], size))
        measurement.set_name(MEASUREMENT)
        builder.Connect(plant.get_state_output_port(), measurement.get_input_port())


def plant_steps(effects: PlantEffects, name: str, time_step: float) -> int:
    """The delay `name` of `effects` in whole plant steps of `time_step` s; InputError (one line) where it is none (a
    delay shorter than one step too: it would be no delay)."""
    steps = getattr(effects, name) / time_step
    if abs(steps - round(steps)) > 1e-6 or (steps > 0 and round(steps) < 1):
        raise InputError(f"plant effects {name} {getattr(effects, name):g} s is not a whole number of plant steps of "
                         f"{time_step:g} s")
    return int(round(steps))


def actuation_input(builder, plant):
    """Where a torque command goes in a diagram `make_plant` built in `builder`: the actuators' "command" input
    where the effects have them, else the elastic transmissions' motors', else the plant's actuation input."""
    for name in (ACTUATORS, MOTORS):
        if builder.HasSubsystemNamed(name):
            return builder.GetSubsystemByName(name).GetInputPort("command")
    return plant.get_actuation_input_port()


def measured_state_output(builder, plant):
    """The state [q, v] a controller measures in a diagram `make_plant` built in `builder`: the measurement delay's
    output where the effects have one, else the plant's state output."""
    if builder.HasSubsystemNamed(MEASUREMENT):
        return builder.GetSubsystemByName(MEASUREMENT).get_output_port()
    return plant.get_state_output_port()


def start_actuators(diagram, context, torque) -> None:
    """The effects' systems of `diagram` with state (the actuators, the elastic transmissions' motors, the measurement
    delay) as if at rest for ever before, holding `torque` (m,) N m, in its root `context` whose plant state is set;
    `torque` may be a function that gives it (called only where there is such a system)."""
    held = None
    for name in (ACTUATORS, MOTORS, MEASUREMENT):
        if diagram.HasSubsystemNamed(name):
            held = (torque() if callable(torque) else torque) if held is None else held
            system = diagram.GetSubsystemByName(name)
            subcontext = system.GetMyMutableContextFromRoot(context)
            if name == MEASUREMENT:   # (every sample of its buffer the state now)
                now = system.get_input_port().Eval(subcontext)
                subcontext.SetDiscreteState(np.tile(now, subcontext.get_discrete_state_vector().size() // len(now)))
            else:
                system.start(subcontext, held)


def link_torque(diagram, plant, plant_context, context):
    """The torque (m,) N m the joints get now in `diagram` (root `context`): the elastic transmissions' springs' where
    the effects have them, else the plant's actuation input (the actuators' output: lagging or delayed)."""
    if diagram.HasSubsystemNamed(MOTORS):
        motors = diagram.GetSubsystemByName(MOTORS)
        return motors.GetOutputPort("link_torque").Eval(motors.GetMyContextFromRoot(context))
    return plant.get_actuation_input_port().Eval(plant_context)


class TorqueNoise(LeafSystem):
    """The plant effects' torque noise inside a diagram: input "torque" (m,) N m, output "noisy_torque"
    (m,) = clip(torque + n_k, -effort, effort), n_k = std * z_k with z_k the rows of
    numpy.random.default_rng(seed).standard_normal((steps, m)), one per sample period and held over it,
    like the action (the same process as `Station`'s data: white, zero-order hold). Row k applies from the
    update at k period + offset s (the controller's update times), row 0 from initialization; past
    the last row the noise is 0. The rows are fixed at construction, so the output is a function of
    the Context (its discrete state: the current row)."""

    def __init__(self, std, effort_limit, period: float, offset: float, steps: int, seed: int):
        super().__init__()
        self._std = np.asarray(std, dtype=float)
        self._limit = np.asarray(effort_limit, dtype=float)
        self._period = period
        m = len(self._std)
        self._rows = self._std * np.random.default_rng(seed).standard_normal((steps, m))
        self._input = self.DeclareVectorInputPort("torque", m)
        self._noise = self.DeclareDiscreteState(m)
        self.DeclareVectorOutputPort("noisy_torque", BasicVector(m), self._output)
        self.DeclareInitializationDiscreteUpdateEvent(self._draw)
        self.DeclarePeriodicDiscreteUpdateEvent(period, offset, self._draw)

    def _draw(self, context, discrete_state):
        k = int(np.floor(context.get_time() / self._period + 0.5 + 1e-9))   # as MpcController's update
        row = self._rows[k] if k < len(self._rows) else np.zeros(len(self._std))
        discrete_state.get_mutable_vector(int(self._noise)).SetFromVector(row)

    def _output(self, context, output) -> None:
        noisy = self._input.Eval(context) + context.get_discrete_state(int(self._noise)).get_value()
        output.SetFromVector(np.clip(noisy, -self._limit, self._limit))
