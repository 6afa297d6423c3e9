"""The simulated station: a robot's discrete plant with its joint sensor and tracking controller,
stepped one sample period at a time with the action held in between (zero-order hold).

`Station.run` is what both data protocols simulate; `StationConfig` is what they share (sample
period, plant, sensor, controller, robot). Each trajectory starts from a fresh state at t = 0, so its
data depend only on its own inputs, not on what the station simulated before or in which process.
"""
import dataclasses
import math

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.robots.control import ControllerConfig, InverseDynamics, JointSensor, SampledJointController, SensorConfig
from stdm_drake.robots.plant import Dynamics, PlantConfig, PlantSimulator, SelfCollisionChecker, joint_limits
from stdm_drake.robots.robot import Robot
from stdm_drake.robots.simulation_errors import simulation_errors

DEFAULT_SAMPLE_PERIOD = 0.01  # s: 100 Hz, the rate of the learned model, the LeafSystem and MPC
MAX_SUBSTEPS = 10_000        # plant steps per sample period


@dataclasses.dataclass
class StationConfig:
    """What every protocol shares: the robot, sample period (s), plant, sensor and tracking controller."""
    robot: Robot
    sample_period: float = DEFAULT_SAMPLE_PERIOD
    plant: PlantConfig = dataclasses.field(default_factory=PlantConfig)
    sensor: SensorConfig = dataclasses.field(default_factory=SensorConfig)
    controller: ControllerConfig = dataclasses.field(default_factory=InverseDynamics)

    def substeps(self) -> int:
        """Plant steps per sample period; the period must be a whole multiple of the plant step."""
        if not (math.isfinite(self.sample_period) and self.sample_period > 0):
            raise InputError(f"sample period must be a finite number > 0 s, got {self.sample_period}")
        if not (math.isfinite(self.plant.time_step) and self.plant.time_step > 0):
            raise InputError(f"collection needs a discrete plant (a finite time_step > 0), got {self.plant.time_step}")
        ratio = self.sample_period / self.plant.time_step
        if ratio > MAX_SUBSTEPS:
            raise InputError(f"plant step {self.plant.time_step} s is {ratio:.3g} steps per sample period; at most "
                             f"{MAX_SUBSTEPS} (a finer step is a run that does not end)")
        steps = whole_substeps(self.sample_period, self.plant.time_step)
        if steps is None:
            raise InputError(f"sample period {self.sample_period} s is not a whole multiple of the plant "
                             f"step {self.plant.time_step} s")
        return steps


def whole_substeps(sample_period: float, time_step: float) -> int | None:
    """The plant steps of `time_step` s per sample period of `sample_period` s where the period is a whole multiple
    of the step (to 1e-9 of a step), else None: the one test of `StationConfig.substeps` and of the plant steps the
    checks advise (`plant_effects_check.stable_plant_step`)."""
    ratio = sample_period / time_step
    return int(round(ratio)) if abs(ratio - round(ratio)) <= 1e-9 and round(ratio) >= 1 else None


def loop_settings(settings: StationConfig) -> list[str]:
    """What besides the gains shapes a tracking loop of `settings`, where on, as phrases: the controller's velocity
    filter, the plant effects' delays, lag and torque noise (held-out run 31: all were blamed on the gains alone), and
    elastic transmissions, by the least damped: its motor rings on the spring at sqrt(k / J) with damping ratio
    d / (2 sqrt(k J)) (held-out run 36: an undamped shoulder spring shook the wrists out of their limits)."""
    controller = settings.controller
    parts = []
    if controller.velocity_filter_time_constant > 0:
        parts.append(f"its velocity_filter_time_constant ({controller.velocity_filter_time_constant:g} s)")
    return parts + loop_effects(settings.plant.effects, list(settings.robot.joint_names))


def loop_effects(effects, names: list[str]) -> list[str]:
    """The plant effects (`robots.effects.PlantEffects` or None) that shape a closed loop, where on, as phrases
    (`loop_settings`; `mpc`'s failure lines): delays, lag, torque noise and, by the least damped, elastic
    transmissions. names: the robot's joints (plant effects give one value per joint)."""
    parts = []
    if effects is None:
        return parts
    for name, unit in (("actuation_delay", "s"), ("measurement_delay", "s"), ("actuator_time_constant", "s"),
                       ("torque_noise_std", "N m")):
        values = getattr(effects, name)
        largest = max(values, default=0.0) if isinstance(values, list) else values
        if largest > 0:
            parts.append(f"the plant effects' {name} ({largest:g} {unit})")
    elastic = effects.elastic(len(names))
    if elastic is not None and np.any(elastic[0] > 0):
        stiffness, damping, motor = (values[elastic[0] > 0] for values in elastic)
        ratio = damping / (2.0 * np.sqrt(stiffness * motor))
        least = int(np.argmin(ratio))
        springs = [name for name, k in zip(names, elastic[0]) if k > 0]
        parts.append(f"the plant effects' transmission springs on {', '.join(springs)} ({springs[least]}'s motor rings "
                     f"at {np.sqrt(stiffness[least] / motor[least]) / (2 * np.pi):.3g} Hz with damping ratio "
                     f"{ratio[least]:.2g} (transmission_damping); a ring shakes the joints it carries)")
    return parts


class Station:
    """The collection diagram (plant + scene graph) and a simulator stepped sample by sample.

    Each trajectory starts from a fresh default context at t = 0, so its data depend only on its
    own inputs, not on what the rig simulated before (or in which worker process).
    """

    def __init__(self, settings: StationConfig):
        self.settings = settings
        settings.substeps()
        self.robot = settings.robot
        self.simulation = PlantSimulator(settings.plant, robot=settings.robot)
        self.plant = self.simulation.plant
        self.dynamics = Dynamics(settings.robot)   # the nominal model: what controllers and protocols know
        self.limits = joint_limits(self.dynamics.plant)   # (the description's: an elastic joint's plant has none)
        effects = settings.plant.effects
        # the simulated plant's own dynamics: the recorded true accelerations
        self.true_dynamics = self.dynamics if effects is None else Dynamics(settings.robot, effects)
        self._torque_noise = (effects.joint_values("torque_noise_std", settings.robot.action_dim)
                              if effects is not None and effects.has_torque_noise() else None)
        self.collision_checker = SelfCollisionChecker(settings.robot)
        self._controller = None

    @property
    def controller(self) -> SampledJointController:
        """The tracking controller (built on first use: the excitation protocol has none)."""
        if self._controller is None:
            settings = self.settings
            self._controller = SampledJointController(settings.controller, settings.sample_period, settings.robot)
        return self._controller

    def run(self, q0: np.ndarray, num_steps: int, control, sensor: JointSensor,
            rng: np.random.Generator | None = None) -> dict:
        """Simulate one trajectory from rest at q0 (n,) rad for num_steps sample periods.

        control(k, t, q_measured, v_measured) -> action (m,) N m for [t_k, t_k+1); t = k * period;
        the controller gets the raw measurement, the dataset records q_measured and the filtered v.
        With the plant effects' torque noise, the plant gets the action plus a draw from `rng` each
        period (the dataset records the action; qdd, the applied torque's acceleration).
        Returns the arrays of one dataset trajectory (see stdm_drake.data.dataset).
        """
        if self._torque_noise is not None and rng is None:
            raise ValueError("a plant with torque noise needs the trajectory's rng")
        dt = self.settings.sample_period
        simulation = self.simulation
        n = self.robot.num_joints
        x = np.concatenate([q0, np.zeros(n)])
        q_true, v_true, q_meas, v_meas, tau, applied, ending = [], [], [], [], [], [], []
        k = 0
        with simulation_errors(lambda: k * dt):   # (Drake's failure to step the plant: one line)
            for k in range(num_steps + 1):
                q_true.append(x[:n])
                v_true.append(x[n:])
                measured = x if k == 0 else simulation.measured_state()   # (with the effects' measurement delay: older)
                q_k, v_k, v_filtered = sensor.measure(measured[:n], measured[n:])
                q_meas.append(q_k)
                v_meas.append(v_filtered)
                tau_k = np.clip(control(k, k * dt, q_k, v_k), -self.limits.effort, self.limits.effort)
                tau.append(tau_k)
                if self._torque_noise is not None:
                    tau_k = np.clip(tau_k + self._torque_noise * rng.standard_normal(len(tau_k)), -self.limits.effort,
                                    self.limits.effort)
                if k == 0:   # (at rest holding the first action: the actuators, where the effects have them, too)
                    simulation.start(x, tau_k)
                simulation.hold(tau_k)
                applied.append(simulation.applied_torque())   # (the actuators' output, lagging or delayed: what acts)
                if k < num_steps:
                    x = simulation.advance_to((k + 1) * dt)
                    ending.append(simulation.applied_torque())
        acceleration = self.true_dynamics.acceleration
        qdd = [acceleration(q_true[k], v_true[k], applied[k]) for k in range(num_steps + 1)]
        qdd_end = [acceleration(q_true[k + 1], v_true[k + 1], ending[k]) for k in range(num_steps)]
        return dict(q=np.array(q_meas), v=np.array(v_meas), tau=np.array(tau[:-1]), tau_next=tau[-1],
                    q_true=np.array(q_true), v_true=np.array(v_true), qdd=np.array(qdd), qdd_end=np.array(qdd_end))

    def limit_violation(self, traj: dict, position_margin: float, velocity_fraction: float,
                        check_self_collision: bool) -> str | None:
        """Why the trajectory is unusable (first reason found), or None if it is fine."""
        lower = self.limits.position_lower + position_margin
        upper = self.limits.position_upper - position_margin
        q, v = traj["q_true"], traj["v_true"]
        for name, bad in (("position", (q < lower) | (q > upper)),
                          ("velocity", np.abs(v) > velocity_fraction * self.limits.velocity)):
            if bad.any():
                step, joint = np.argwhere(bad)[0]
                return f"{self.robot.joint_names[joint]} {name} limit at step {step}"
        if check_self_collision:
            for step, q_step in enumerate(q):
                if not self.collision_checker.is_collision_free(q_step):
                    links = self.collision_checker.colliding_links(q_step)
                    return f"self-collision {links[0][0]}/{links[0][1]} at step {step}"
        return None

    def gravity_beyond(self, positions, reach: np.ndarray | None = None, joint_name: str = "") -> tuple[bool, str]:
        """(whether no torque can hold the arm, why) a protocol's arm may drift at `positions` ((n,) rad each) from
        gravity alone: the plant's own gravity (effects included) beyond an actuated joint's effort limit (True); else,
        on an affected plant, the gravity the compensation (the description's) does not hold, beyond `reach` (N m per
        actuated joint: the excitation's torques; None: 1e-3 of the effort limit, what any feedback must then hold),
        naming `joint_name` (the joint that left its limits) where it is one of those pulled. (False, "") where
        neither."""
        if not len(positions):
            return False, ""
        names = [self.robot.joint_names[index] for index in self.robot.actuated_indices]
        effort = self.limits.effort   # (m,): per actuated joint
        beyond = gravity_beyond_effort(self.true_dynamics, effort, positions, names)
        if beyond:
            return True, beyond
        if self.true_dynamics is self.dynamics:
            return False, ""
        unheld = np.max([np.abs(self.true_dynamics.actuated_gravity_torque(q) - self.dynamics.actuated_gravity_torque(q))
                         for q in positions], axis=0)
        reach = 1e-3 * effort if reach is None else np.asarray(reach, dtype=float)
        if not np.any(unheld > reach):
            return False, ""
        joint = names.index(joint_name) if joint_name in names and unheld[names.index(joint_name)] > reach[
            names.index(joint_name)] else int(np.argmax(unheld / np.maximum(reach, 1e-300)))
        return False, (f"the plant effects pull {names[joint]} with up to {unheld[joint]:.3g} N m of gravity that the "
                       "compensation (the robot's description) does not hold")


def gravity_beyond_effort(dynamics: Dynamics, effort: np.ndarray, positions, names: list[str],
                          where: str = "there") -> str:
    """Why no torque holds the arm of `dynamics` (a plant, effects included) at `positions` ((n,) rad each): the
    gravity on an actuated joint (`names`, m) beyond its effort limit (m,) N m; "" where it holds everywhere."""
    if not len(positions):
        return ""
    pull = np.max([np.abs(dynamics.actuated_gravity_torque(q)) for q in positions], axis=0)
    if not np.any(pull > effort):
        return ""
    joint = int(np.argmax(pull / effort))
    return (f"gravity pulls {names[joint]} with up to {pull[joint]:.3g} N m {where}, beyond its effort limit "
            f"{effort[joint]:g} N m: no torque holds the arm; lighten the bodies it carries")
