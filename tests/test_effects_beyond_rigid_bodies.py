"""Plant effects no rigid-body model has (issue 59, robots/effect_systems.py): each against its analytic response,
in the plant's diagram, in a closed loop, and refused where a model that cannot hold it is asked for."""
import dataclasses

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from presets import UR10
from test_mpc import quintic_reference
from stdm_drake.closed_loop.mpc import load_mpc_config, run_closed_loop
from stdm_drake.dynamics.physics import PlantModel
from stdm_drake.errors import InputError
from stdm_drake.robots.effect_systems import ActuatorDynamics
from stdm_drake.robots.effects import PlantEffects, coulomb_torque
from stdm_drake.robots.plant import PlantConfig, PlantSimulator

STEP = 0.001


def actuator_response(time_constant, delay_steps: int, command, steps: int) -> np.ndarray:
    """The actuators' torque (steps + 1, m) over plant step k (from t = k h) for a command held from t = 0, from rest
    (zero torque)."""
    builder = DiagramBuilder()
    source = builder.AddSystem(ConstantVectorSource(np.asarray(command, dtype=float)))
    actuators = builder.AddSystem(ActuatorDynamics(np.asarray(time_constant, dtype=float), delay_steps, STEP))
    builder.Connect(source.get_output_port(), actuators.get_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = actuators.GetMyContextFromRoot(simulator.get_mutable_context())
    simulator.Initialize()
    torques = [actuators.get_output_port().Eval(context).copy()]
    for k in range(1, steps + 1):   # (what a discrete plant's step k uses: the torque after the updates before k h)
        simulator.AdvanceTo((k - 0.5) * STEP)
        torques.append(actuators.get_output_port().Eval(context).copy())
    return np.array(torques)


def test_the_actuator_lag_and_delay_follow_the_first_order_step_response():
    """A step of the command u from rest reaches u (1 - exp(-(t - d h) / T)) at t = k h, k >= d (0 before): the
    continuous lag's response sampled, delayed by d plant steps; a joint without lag follows the delayed command."""
    command, lag = np.array([10.0, -4.0, 2.0]), np.array([0.02, 0.005, 0.0])
    for delay in (0, 3):
        torque = actuator_response(lag, delay, command, 60)
        t = np.arange(61) * STEP
        after = np.clip(t - delay * STEP, 0.0, None)
        expected = command[:2] * (1.0 - np.exp(-after[:, None] / lag[None, :2]))
        np.testing.assert_allclose(torque[:, :2], expected, rtol=0, atol=1e-12)
        # time to 63 % of the step: the time constant (to a step), after the delay
        reached = np.argmax(np.abs(torque[:, 0]) >= 0.632 * abs(command[0]))
        assert abs(reached * STEP - (delay * STEP + lag[0])) <= STEP
        held = np.where(np.arange(61) >= delay, command[2], 0.0)
        np.testing.assert_array_equal(torque[:, 2], held)


def test_a_delayed_plant_is_the_plant_a_few_steps_later():
    """In the plant's own diagram (PlantSimulator, what collection steps): with a delay of 3 plant steps, a command
    changed at t = 0 moves the arm as the undelayed plant moves 3 steps later (started as if the old command had
    been held)."""
    x0 = np.concatenate([UR10.home, np.zeros(6)])
    hold, change = np.array([0.0, -60.0, -20.0, 0.0, 0.0, 0.0]), np.array([20.0, -80.0, -30.0, 2.0, 1.0, 0.5])
    delayed = PlantSimulator(PlantConfig.discrete(STEP, effects=PlantEffects(actuation_delay=3 * STEP)), robot=UR10)
    plain = PlantSimulator(PlantConfig.discrete(STEP), robot=UR10)
    delayed.start(x0, hold)
    delayed.hold(change)
    plain.start(x0, hold)
    plain.advance_to(3 * STEP)
    plain.hold(change)
    for k in range(1, 30):
        np.testing.assert_allclose(delayed.advance_to((k + 3) * STEP), plain.advance_to((k + 3) * STEP), rtol=0,
                                   atol=1e-12)


def test_stribeck_friction_breaks_away_above_coulomb_at_rest():
    """|friction| is F_s (the breakaway) just above zero velocity's smoothing and F_c far from it; the Stribeck
    curve in between, monotone down in magnitude past the smoothing."""
    coulomb, scale, breakaway, stribeck_velocity = np.array([5.0]), np.array([1e-4]), np.array([8.0]), np.array([0.1])
    at = lambda v: -coulomb_torque(np.array([v]), coulomb, scale, (breakaway, stribeck_velocity))[0]   # noqa: E731
    assert at(0.0) == 0.0
    assert at(1e-3) == pytest.approx(8.0, rel=1e-3)
    assert at(1.0) == pytest.approx(5.0, rel=1e-12)
    assert at(0.1) == pytest.approx(5.0 + 3.0 * np.exp(-1.0), rel=1e-6)
    assert at(-0.1) == pytest.approx(-at(0.1))
    magnitudes = [at(v) for v in np.linspace(0.002, 0.5, 50)]
    assert all(a >= b for a, b in zip(magnitudes, magnitudes[1:]))


def test_the_effects_are_checked_and_a_model_that_cannot_hold_them_says_so():
    for effects, message in (
            (PlantEffects(stribeck_friction=[3.0]), "stribeck_friction needs coulomb_friction"),
            (PlantEffects(coulomb_friction=[5.0], stribeck_friction=[3.0]), "stribeck_friction must be at least "
                                                                              "coulomb_friction"),
            (PlantEffects(actuation_delay=-0.001), "actuation_delay must be in"),
            (PlantEffects(actuator_time_constant=[100.0]), "actuator_time_constant 100 s is beyond any robot's"),
            (PlantEffects(stribeck_velocity=[0.0]), "stribeck_velocity must be > 0")):
        with pytest.raises(InputError, match=message):
            effects.validate()
    with pytest.raises(InputError, match="actuation_delay 0.0015 s is not a whole number of plant steps of 0.001 s"):
        PlantSimulator(PlantConfig.discrete(STEP, effects=PlantEffects(actuation_delay=0.0015)), robot=UR10)
    lagged = PlantConfig.discrete(STEP, effects=PlantEffects(actuator_time_constant=[0.005], actuation_delay=0.002))
    with pytest.raises(InputError, match="does not hold its actuator_time_constant, actuation_delay"):
        PlantModel(0.01, lagged, robot=UR10, integrator="rk4")
    record = lagged.effects.record()
    assert record["actuation_delay"] == 0.002 and "stribeck_friction" not in record
    assert PlantEffects.from_record(record) == lagged.effects
    assert "actuation_delay" not in PlantEffects(coulomb_friction=[1.0]).record()   # (files without them: as before)


def test_a_closed_loop_on_a_lagging_plant_runs_and_tracks_worse_than_on_the_plain_plant():
    """The MPC's closed loop (the plant's diagram with its actuators, started holding gravity) with a 3 ms lag and
    a 1 ms delay: the loop runs without a fallback and tracks worse than on the plant without them (the model, the
    description, knows neither; a 10 ms lag, the control period, drives this loop off its plan: measured, not
    tested)."""
    model = PlantModel(0.01, robot=UR10, integrator="rk4")
    reference, config = quintic_reference(40), load_mpc_config()
    errors = {}
    for name, effects in (("plain", None), ("lagging", PlantEffects(actuator_time_constant=[0.003],
                                                                     actuation_delay=0.001))):
        log = run_closed_loop(model, reference, config, PlantConfig.discrete(STEP, effects=effects), robot=UR10)
        states = np.array(log.state)
        errors[name] = float(np.mean((states[:, :6] - reference.q[:len(states)]) ** 2))
        assert np.all(np.isfinite(states)) and not any(log.fallback)
    assert errors["lagging"] > errors["plain"]


def test_collection_records_the_acceleration_of_the_torque_that_acts():
    """Held-out review: on a plant with a lag and a delay the station starts its actuators holding the first action
    (the arm at rest does not sag), and the recorded true accelerations are those of the actuators' torque, not of
    the command (with Stribeck friction in the dynamics too); without these effects, the command's, as before."""
    from stdm_drake.robots.control import JointSensor, SensorConfig
    from stdm_drake.robots.plant import Dynamics
    from stdm_drake.robots.station import Station, StationConfig
    effects = PlantEffects(actuator_time_constant=[0.004], actuation_delay=0.002, coulomb_friction=[2.0],
                           stribeck_friction=[3.0])
    station = Station(StationConfig(robot=UR10, plant=PlantConfig.discrete(STEP, effects=effects),
                                    sensor=SensorConfig()))
    gravity = Dynamics(UR10).gravity_torque(UR10.home)
    kick = np.array([30.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    control = lambda k, t, q, v: gravity + (kick if k >= 2 else 0.0)   # noqa: E731
    rng = np.random.default_rng(0)
    traj = station.run(UR10.home, 5, control, JointSensor(SensorConfig(), rng), rng)
    true = Dynamics(UR10, effects)
    # at rest holding the first action: no acceleration but friction's (none at rest) and the rest of gravity's
    np.testing.assert_allclose(traj["qdd"][0], true.acceleration(UR10.home, np.zeros(6), gravity), atol=1e-9)
    # the kick is commanded at sample 2; its torque acts 2 ms later and through the lag: less than the command
    commanded = true.acceleration(traj["q_true"][2], traj["v_true"][2], gravity + kick)
    assert abs(traj["qdd"][2][0]) < 0.5 * abs(commanded[0])
    plain = Station(StationConfig(robot=UR10, plant=PlantConfig.discrete(STEP), sensor=SensorConfig()))
    traj = plain.run(UR10.home, 3, control, JointSensor(SensorConfig(), rng), rng)
    np.testing.assert_allclose(traj["qdd"][2], Dynamics(UR10).acceleration(traj["q_true"][2], traj["v_true"][2],
                                                                          gravity + kick), atol=1e-9)


def test_a_one_step_plant_model_of_a_lagging_plant_is_refused_and_stribeck_counts_in_the_stability_check():
    lagged = PlantConfig.discrete(STEP, effects=PlantEffects(actuator_time_constant=[0.004]))
    with pytest.raises(InputError, match="a one-step plant model cannot hold the affected plant's actuator_time_constant"):
        PlantModel(0.01, lagged, robot=UR10)
    PlantModel(0.01, PlantConfig.discrete(STEP, effects=PlantEffects(coulomb_friction=[1.0], stribeck_friction=[2.0])),
               robot=UR10)   # (Stribeck friction is a function of (q, v): the simulator's step holds it)
    from stdm_drake.robots.plant import coulomb_stability_gains
    plain = PlantEffects(coulomb_friction=[1.0], coulomb_velocity_scale=[0.01])
    breaking = dataclasses.replace(plain, stribeck_friction=[3.0])
    np.testing.assert_allclose(coulomb_stability_gains(breaking, UR10, STEP),
                               3.0 * coulomb_stability_gains(plain, UR10, STEP))


def test_the_actuators_hold_what_they_were_started_with_until_the_delay_passes():
    simulation = PlantSimulator(PlantConfig.discrete(STEP, effects=PlantEffects(actuation_delay=2 * STEP)), robot=UR10)
    before, after = np.full(6, 1.0), np.full(6, 2.0)
    simulation.start(np.concatenate([UR10.home, np.zeros(6)]), before)
    simulation.hold(after)
    np.testing.assert_array_equal(simulation.applied_torque(), before)
    simulation.advance_to(2.5 * STEP)
    np.testing.assert_array_equal(simulation.applied_torque(), after)
    plain = PlantSimulator(PlantConfig.discrete(STEP), robot=UR10)
    plain.start(np.concatenate([UR10.home, np.zeros(6)]), before)
    plain.hold(after)
    np.testing.assert_array_equal(plain.applied_torque(), after)
