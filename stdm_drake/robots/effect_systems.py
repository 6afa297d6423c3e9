"""The plant effects' systems in a plant's diagram (`plant.make_plant` adds them): the joint friction driving the
plant's applied generalized force, the actuators between a torque command and the plant's actuation, and the torque
noise between a controller and the actuators (`effects.PlantEffects` holds what each is; its module docstring the
models)."""
import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem

from stdm_drake.errors import InputError
from stdm_drake.robots.effects import PlantEffects, coulomb_torque


class JointFriction(LeafSystem):
    """Coulomb (and Stribeck) joint friction of the arm joints as a generalized force: input "state" (the plant's
    [q, v]), output "generalized_force" (the plant's velocities), `coulomb_torque` of each arm joint's velocity, 0
    elsewhere. Direct feedthrough: a discrete plant samples it every step."""

    def __init__(self, plant, joint_velocity_indices, friction: np.ndarray, velocity_scale: np.ndarray,
                 stribeck: tuple[np.ndarray, np.ndarray] | None = None):
        super().__init__()
        self._indices = np.asarray(joint_velocity_indices, dtype=int)
        self._friction = np.asarray(friction, dtype=float)
        self._scale = np.asarray(velocity_scale, dtype=float)
        self._stribeck = stribeck
        self._nq, self._nv = plant.num_positions(), plant.num_velocities()
        self._state = self.DeclareVectorInputPort("state", self._nq + self._nv)
        self.DeclareVectorOutputPort("generalized_force", BasicVector(self._nv), self._output)

    def _output(self, context, output) -> None:
        v = self._state.Eval(context)[self._nq:]
        force = np.zeros(self._nv)
        force[self._indices] = coulomb_torque(v[self._indices], self._friction, self._scale, self._stribeck)
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


ACTUATORS = "actuators"   # the name of the ActuatorDynamics system in a plant's diagram


def add_effect_systems(builder, plant, instance, robot, effects: PlantEffects, time_step: float) -> None:
    """The effects' systems in the diagram of `plant` (finalized): the joint friction driving its applied
    generalized force, and the actuators (`ActuatorDynamics`, named ACTUATORS) driving its actuation, whose
    "command" input `actuation_input` returns; InputError (one line) for a delay that is no whole number of plant
    steps, or a lag or delay on a continuous plant."""
    n = robot.num_joints
    coulomb = effects.coulomb(n)
    if coulomb is not None:
        indices = [plant.GetJointByName(name, instance).velocity_start() for name in robot.joint_names]
        friction = builder.AddSystem(JointFriction(plant, indices, *coulomb, effects.stribeck(n)))
        friction.set_name("joint_friction")
        builder.Connect(plant.get_state_output_port(), friction.get_input_port())
        builder.Connect(friction.get_output_port(), plant.get_applied_generalized_force_input_port())
    lag = effects.joint_values("actuator_time_constant", robot.action_dim)
    if not np.any(lag > 0) and effects.actuation_delay == 0:
        return
    if time_step <= 0:
        raise InputError("plant effects actuator_time_constant and actuation_delay act every plant step: they need "
                         "a discrete plant (--plant-time-step > 0)")
    steps = effects.actuation_delay / time_step
    if abs(steps - round(steps)) > 1e-6:
        raise InputError(f"plant effects actuation_delay {effects.actuation_delay:g} s is not a whole number of plant "
                         f"steps of {time_step:g} s")
    actuators = builder.AddSystem(ActuatorDynamics(lag, int(round(steps)), time_step))
    actuators.set_name(ACTUATORS)
    builder.Connect(actuators.get_output_port(), plant.get_actuation_input_port())


def actuation_input(builder, plant):
    """Where a torque command goes in a diagram `make_plant` built in `builder`: the actuators' "command" input
    where the effects have them, else the plant's actuation input."""
    if builder.HasSubsystemNamed(ACTUATORS):
        return builder.GetSubsystemByName(ACTUATORS).get_input_port()
    return plant.get_actuation_input_port()


def start_actuators(diagram, context, torque) -> None:
    """The actuators of `diagram` (if any) at `torque` (m,) N m held before, in its root `context`; `torque` may be
    a function that gives it (called only where there are actuators)."""
    if diagram.HasSubsystemNamed(ACTUATORS):
        actuators = diagram.GetSubsystemByName(ACTUATORS)
        actuators.start(actuators.GetMyMutableContextFromRoot(context), torque() if callable(torque) else torque)


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
