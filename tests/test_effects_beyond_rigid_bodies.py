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
from stdm_drake.robots.station import StationConfig

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
    from stdm_drake.robots.plant_effects_check import coulomb_stability_gains
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


WHEEL_URDF = """<?xml version="1.0"?>
<robot name="wheel">
  <link name="base"/>
  <link name="disc">
    <inertial><origin xyz="0 0 0"/><mass value="2.0"/>
      <inertia ixx="0.03" iyy="0.03" izz="0.05" ixy="0" ixz="0" iyz="0"/></inertial>
  </link>
  <joint name="weld" type="fixed"><parent link="world"/><child link="base"/></joint>
  <joint name="spin" type="revolute"><parent link="base"/><child link="disc"/><axis xyz="0 0 1"/>
    <limit lower="-100" upper="100" velocity="100" effort="1000"/></joint>
  <transmission name="t"><type>transmission_interface/SimpleTransmission</type>
    <joint name="spin"><hardwareInterface>EffortJointInterface</hardwareInterface></joint>
    <actuator name="m"><mechanicalReduction>1</mechanicalReduction></actuator></transmission>
</robot>
"""
WHEEL_INERTIA = 0.05   # kg m²: the disc's about its vertical joint (gravity does not act on it)


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    """One vertical revolute joint turning a disc of 0.05 kg m²: a joint whose dynamics are analytic."""
    from stdm_drake.robots.robot import load_robot
    folder = tmp_path_factory.mktemp("wheel")
    (folder / "wheel.urdf").write_text(WHEEL_URDF)
    (folder / "wheel.yaml").write_text("name: wheel\nmodel: wheel.urdf\narm_joints: [spin]\nhome: [0.0]\n"
                                       "tool_frame: disc\n")
    return load_robot(folder / "wheel.yaml")


def released_spring(robot, effects: PlantEffects, step: float, steps: int, torque: float = 10.0):
    """From rest holding `torque` N m through the elastic transmission (spring deflected by torque / k), the command
    dropped to 0 at t = 0: (t (steps,) s, the link's q and v, the motor's theta and theta' (steps,) each)."""
    from stdm_drake.robots.effect_systems import MOTORS
    simulation = PlantSimulator(PlantConfig.discrete(step, effects=effects), robot=robot)
    simulation.start(np.zeros(2), np.array([torque]))
    simulation.hold(np.zeros(1))
    motors = simulation.diagram.GetSubsystemByName(MOTORS).GetMyContextFromRoot(simulation.context)
    rows = []
    for k in range(1, steps + 1):
        x = simulation.advance_to(k * step)
        rows.append([k * step, x[0], x[1], *motors.get_discrete_state_vector().get_value()[:2]])
    return np.array(rows).T


def ringing(t, deflection):
    """(the angular frequency rad/s from the zero crossings, the amplitude's decay per radian of phase) of a
    deflection that rings about zero."""
    crossings = np.flatnonzero(np.diff(np.sign(deflection)))
    at = t[crossings] - deflection[crossings] * (t[crossings + 1] - t[crossings]) / (
        deflection[crossings + 1] - deflection[crossings])
    frequency = np.pi / np.mean(np.diff(at))
    cycle = int(round(2 * np.pi / frequency / (t[1] - t[0])))
    first, last = np.abs(deflection[:cycle]).max(), np.abs(deflection[-cycle:]).max()
    return frequency, np.log(first / last) / (frequency * (t[-cycle // 2] - t[cycle // 2]))


def test_an_elastic_joint_rings_at_the_two_inertia_frequency_and_keeps_its_momentum(wheel):
    """A released spring between a motor of J = 0.2 kg m² and the disc (I = 0.05 kg m²), k = 2000 N m/rad: the
    deflection rings at omega = sqrt(k (1 / J + 1 / I)) (to 0.01 % at omega h = 0.02, 0.5 % at the default step,
    omega h = 0.22); no torque acts on the pair, so J theta' + I q' stays 0 to rounding; the numerical damping (Drake's
    first-order link step, `ElasticTransmissions`) is below 0.25 omega h as a damping ratio."""
    stiffness, motor = 2000.0, 0.2
    omega = np.sqrt(stiffness * (1 / motor + 1 / WHEEL_INERTIA))
    effects = PlantEffects(rotor_inertia=[motor], transmission_stiffness=[stiffness])
    for step, tolerance in ((1e-4, 1e-4), (1e-3, 5e-3)):
        t, q, v, theta, rate = released_spring(wheel, effects, step, int(8 * 2 * np.pi / omega / step))
        frequency, damping = ringing(t, theta - q)
        assert frequency == pytest.approx(omega, rel=tolerance)
        assert np.max(np.abs(motor * rate + WHEEL_INERTIA * v)) < 1e-12
        assert 0 <= damping < 0.25 * omega * step
        assert np.max(np.abs(theta - q)) <= 10.0 / stiffness * (1 + 1e-9)   # (never beyond the start's deflection)


def test_a_transmission_damper_damps_the_ring_as_the_analytic_two_inertia_pair(wheel):
    """With d in parallel with the spring the deflection decays at the damping ratio d / (2 sqrt(k mu)) of the pair
    (mu = J I / (J + I) its reduced inertia), to within the step's numerical damping (omega h = 0.01 here)."""
    stiffness, motor, damper = 2000.0, 0.2, 0.4
    reduced = motor * WHEEL_INERTIA / (motor + WHEEL_INERTIA)
    omega = np.sqrt(stiffness / reduced)
    effects = PlantEffects(rotor_inertia=[motor], transmission_stiffness=[stiffness], transmission_damping=[damper])
    step = 5e-5
    t, q, v, theta, rate = released_spring(wheel, effects, step, int(8 * 2 * np.pi / omega / step))
    frequency, damping = ringing(t, theta - q)
    ratio = damper / (2 * np.sqrt(stiffness * reduced))
    assert frequency == pytest.approx(omega * np.sqrt(1 - ratio ** 2), rel=2e-3)
    assert damping == pytest.approx(ratio, abs=0.25 * omega * step + 2e-3)
    assert np.max(np.abs(motor * rate + WHEEL_INERTIA * v)) < 1e-12


def test_a_stiff_transmission_on_a_light_link_stays_bounded(wheel):
    """k = 2e6 N m/rad at the default 1 ms step (omega h = 6.5, far past an explicit spring's limit of 2): the
    implicit pair stays bounded by its start's deflection and keeps its momentum."""
    stiffness, motor = 2e6, 1.0
    t, q, v, theta, rate = released_spring(wheel, PlantEffects(rotor_inertia=[motor], transmission_stiffness=[stiffness]),
                                           1e-3, 300)
    assert np.max(np.abs(theta - q)) <= 10.0 / stiffness * (1 + 1e-9)
    assert np.max(np.abs(motor * rate + WHEEL_INERTIA * v)) < 1e-12


UR10_ELASTIC = PlantEffects(rotor_inertia=[0.0, 3.7434, 0.0, 0.0708, 0.2342, 0.4365],
                            transmission_stiffness=[0.0, 3e4, 0.0, 1e4, 1e4, 1e4], transmission_damping=[5.0])


def test_an_elastic_arm_started_holding_gravity_stays_put_and_collects_its_link_torque():
    """The UR-10 with elastic transmissions on its joints with a motor inertia, started at rest holding gravity: the
    arm does not move (each spring deflected by its torque); collection records the springs' torque on the links as
    the torque that acts (the true accelerations are its), not the command."""
    from stdm_drake.robots.control import JointSensor, SensorConfig
    from stdm_drake.robots.plant import Dynamics
    from stdm_drake.robots.station import Station, StationConfig
    gravity = Dynamics(UR10).gravity_torque(UR10.home)
    simulation = PlantSimulator(PlantConfig.discrete(STEP, effects=UR10_ELASTIC), robot=UR10)
    x0 = np.concatenate([UR10.home, np.zeros(6)])
    simulation.start(x0, gravity)
    np.testing.assert_allclose(simulation.advance_to(0.2), x0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(simulation.applied_torque(), gravity, rtol=1e-9, atol=1e-6)
    station = Station(StationConfig(robot=UR10, plant=PlantConfig.discrete(STEP, effects=UR10_ELASTIC),
                                    sensor=SensorConfig()))
    kick = np.array([0.0, 40.0, 0.0, 3.0, 0.0, 0.0])
    control = lambda k, t, q, v: gravity + (kick if k >= 1 else 0.0)   # noqa: E731
    rng = np.random.default_rng(0)
    traj = station.run(UR10.home, 6, control, JointSensor(SensorConfig(), rng), rng)
    true = Dynamics(UR10, UR10_ELASTIC)
    # the kick is commanded at sample 1: through the springs the links feel it later and ringing, not as commanded
    commanded = true.acceleration(traj["q_true"][1], traj["v_true"][1], gravity + kick)
    assert abs(traj["qdd"][1][1]) < 0.5 * abs(commanded[1])
    assert np.all(np.isfinite(traj["qdd"])) and np.abs(traj["q_true"][-1] - UR10.home).max() > 1e-4


def test_a_closed_loop_on_elastic_transmissions_tends_to_the_rigid_one_as_they_stiffen():
    """The MPC's closed loop (the description as model, 100 Hz) on the UR-10 with elastic transmissions: ten times
    stiffer than UR10_ELASTIC's (3e5 / 1e5 N m/rad), it tracks as on the rigid plant with the same motor inertias to
    within 5 % of that loop's error at every control step; at UR10_ELASTIC's own stiffness and a 2 ms measurement delay
    it stays finite and departs from the rigid loop (the description knows neither: measured, such a loop can leave
    its plan and fall back)."""
    model = PlantModel(0.01, robot=UR10, integrator="rk4")
    reference, config = quintic_reference(40), load_mpc_config()
    errors = {}
    stiff = dataclasses.replace(UR10_ELASTIC, transmission_stiffness=[0.0, 3e5, 0.0, 1e5, 1e5, 1e5])
    for name, effects in (("rigid", PlantEffects(rotor_inertia=UR10_ELASTIC.rotor_inertia)), ("stiff", stiff),
                          ("soft", dataclasses.replace(UR10_ELASTIC, measurement_delay=0.002))):
        log = run_closed_loop(model, reference, config, PlantConfig.discrete(STEP, effects=effects), robot=UR10)
        states = np.array(log.state)
        assert np.all(np.isfinite(states))
        assert name == "soft" or not any(log.fallback)
        errors[name] = np.abs(states[:, :6] - reference.q[:len(states)]).max(axis=1)
    np.testing.assert_allclose(errors["stiff"], errors["rigid"], rtol=0.05, atol=1e-4)
    assert np.abs(errors["soft"] - errors["rigid"]).max() > 1e-2


def test_friction_ripple_follows_the_joint_position(wheel):
    """F_c (1 + r sin(2 pi q / P)): the analytic friction, and the plant's step from rest-free motion at two positions
    a half period apart accelerates the disc by (tau - F(q) tanh(v / v_s)) / I (a 10 µs step: the explicit friction
    sampled at the step's start)."""
    coulomb, scale, ripple, period = 2.0, 0.05, 0.5, 0.1
    friction = coulomb_torque(np.array([1.0, 1.0]), np.full(2, coulomb), np.full(2, scale), None,
                              (np.full(2, ripple), np.full(2, period)), np.array([period / 4, 3 * period / 4]))
    np.testing.assert_allclose(friction, -coulomb * np.tanh(1.0 / scale) * np.array([1.5, 0.5]), rtol=1e-12)
    effects = PlantEffects(coulomb_friction=[coulomb], coulomb_velocity_scale=[scale], friction_ripple=[ripple],
                           friction_ripple_period=[period])
    step, v0, torque = 1e-5, 0.03, 1.0
    for q0 in (period / 4, 3 * period / 4):
        simulation = PlantSimulator(PlantConfig.discrete(step, effects=effects), robot=wheel)
        simulation.start(np.array([q0, v0]), np.array([torque]))
        v1 = simulation.advance_to(step)[1]
        magnitude = coulomb * (1 + ripple * np.sin(2 * np.pi * q0 / period))
        expected = (torque - magnitude * np.tanh(v0 / scale)) / WHEEL_INERTIA
        assert (v1 - v0) / step == pytest.approx(expected, rel=1e-6)
    from stdm_drake.robots.plant import Dynamics
    assert Dynamics(wheel, effects).acceleration(np.array([period / 4]), np.array([v0]), np.array([torque]))[0] == \
        pytest.approx((torque - coulomb * 1.5 * np.tanh(v0 / scale)) / WHEEL_INERTIA, rel=1e-12)


def test_the_measurement_delay_shows_the_state_of_whole_plant_steps_before():
    """measurement_delay d h: the state a sensor reads at step k is the plant's at step k - d (the state at t = 0
    before that: at rest before the start); collected with a delay of one sample period, the recorded q is the true
    q of the sample before."""
    from stdm_drake.robots.control import JointSensor, SensorConfig
    from stdm_drake.robots.plant import Dynamics
    from stdm_drake.robots.station import Station, StationConfig
    gravity = Dynamics(UR10).gravity_torque(UR10.home)
    simulation = PlantSimulator(PlantConfig.discrete(STEP, effects=PlantEffects(measurement_delay=3 * STEP)), robot=UR10)
    x0 = np.concatenate([UR10.home, np.zeros(6)])
    simulation.start(x0, gravity + 20.0)
    true, measured = [x0], [simulation.measured_state()]
    for k in range(1, 12):
        true.append(simulation.advance_to(k * STEP))
        measured.append(simulation.measured_state())
    for k in range(12):
        np.testing.assert_array_equal(measured[k], true[max(k - 3, 0)])
    station = Station(StationConfig(robot=UR10, plant=PlantConfig.discrete(STEP, effects=PlantEffects(
        measurement_delay=0.01)), sensor=SensorConfig()))
    rng = np.random.default_rng(0)
    traj = station.run(UR10.home, 5, lambda k, t, q, v: gravity + 20.0, JointSensor(SensorConfig(), rng), rng)
    np.testing.assert_array_equal(traj["q"][1:], traj["q_true"][:-1])
    assert np.abs(traj["q_true"][-1] - traj["q_true"][0]).max() > 1e-4


def test_the_new_effects_are_checked_and_recorded(wheel):
    for effects, message in (
            (PlantEffects(transmission_damping=[1.0]), "transmission_damping needs transmission_stiffness"),
            (PlantEffects(transmission_stiffness=[1e4]), "transmission_stiffness needs rotor_inertia"),
            (PlantEffects(coulomb_friction=[1.0], friction_ripple=[0.2]), "friction_ripple needs friction_ripple_period"),
            (PlantEffects(friction_ripple=[0.2], friction_ripple_period=[0.1]), "friction_ripple needs coulomb_friction"),
            (PlantEffects(coulomb_friction=[1.0], friction_ripple=[2.0], friction_ripple_period=[0.1]),
             "friction_ripple 2 is beyond any robot's"),
            (PlantEffects(measurement_delay=2.0), "measurement_delay must be in")):
        with pytest.raises(InputError, match=message):
            effects.validate()
    with pytest.raises(InputError, match="transmission_stiffness on joint 1 needs a rotor_inertia > 0 there"):
        PlantEffects(rotor_inertia=[0.0, 1.0, 1.0, 1.0, 1.0, 1.0], transmission_stiffness=[1e4]).elastic(6)
    from stdm_drake.robots.plant_effects_check import plant_effects_for
    with pytest.raises(InputError, match="friction_ripple_period must be > 0 rad where friction_ripple is on"):
        plant_effects_for(PlantEffects(coulomb_friction=[1.0], friction_ripple=[0.2], friction_ripple_period=[0.0]),
                          UR10, STEP)
    broadcast = PlantEffects(coulomb_friction=[1.0, 1.0, 1.0, 0.0, 0.0, 0.0], friction_ripple=[0.2],
                             friction_ripple_period=[0.1, 0.1, 0.1, 0.0, 0.0, 0.0], coulomb_velocity_scale=[1.0])
    with pytest.raises(InputError, match="friction_ripple on wrist_1_joint, whose coulomb_friction is 0"):
        plant_effects_for(dataclasses.replace(broadcast, friction_ripple=[0.2, 0.2, 0.2, 0.2, 0.0, 0.0]), UR10, STEP)
    assert plant_effects_for(broadcast, UR10, STEP) is broadcast   # (one ripple for all: where it can; period 0: none)
    np.testing.assert_array_equal(coulomb_torque(np.full(2, 0.5), np.ones(2), np.ones(2), None,
                                                 (np.array([0.0, 0.2]), np.array([0.0, 0.1])), np.zeros(2)),
                                  -np.tanh(0.5) * np.ones(2))
    with pytest.raises(InputError, match="measurement_delay 0.0015 s is not a whole number of plant steps"):
        PlantSimulator(PlantConfig.discrete(STEP, effects=PlantEffects(measurement_delay=0.0015)), robot=UR10)
    with pytest.raises(InputError, match="transmission_stiffness act every plant step: they need a discrete plant"):
        PlantSimulator(PlantConfig.discrete(0.0, effects=UR10_ELASTIC), robot=UR10)
    with pytest.raises(InputError, match="cannot hold the affected plant's transmission_stiffness"):
        PlantModel(0.01, PlantConfig.discrete(STEP, effects=UR10_ELASTIC), robot=UR10)
    rippled = PlantEffects(coulomb_friction=[1.0], friction_ripple=[0.2], friction_ripple_period=[0.1])
    with pytest.raises(InputError, match="does not hold its friction_ripple"):
        PlantModel(0.01, PlantConfig.discrete(STEP, effects=rippled), robot=UR10, integrator="rk4")
    PlantModel(0.01, PlantConfig.discrete(STEP, effects=PlantEffects(measurement_delay=0.002)), robot=UR10,
               integrator="rk4")   # (the loop's delay, not the plant's: a plant model holds the plant)
    for effects in (UR10_ELASTIC, rippled, PlantEffects(measurement_delay=0.002)):
        assert PlantEffects.from_record(effects.record()) == effects
    assert not {"transmission_stiffness", "friction_ripple", "measurement_delay"} & set(PlantEffects().record())
    from stdm_drake.robots.plant_effects_check import coulomb_stability_gains   # (the ripple's peak friction counts)
    plain = PlantEffects(coulomb_friction=[1.0], coulomb_velocity_scale=[0.01])
    np.testing.assert_allclose(coulomb_stability_gains(dataclasses.replace(plain, friction_ripple=[0.5],
                                                                           friction_ripple_period=[0.1]), UR10, STEP),
                               1.5 * coulomb_stability_gains(plain, UR10, STEP))


def test_a_spring_may_carry_more_than_its_motor_gives_and_the_motor_clips_the_command(wheel):
    """Review of the change: the effort limit is the motor's. A step of 900 N m (of 1000) through a spring on a light
    motor overshoots to about twice that on the link, unclipped, and the pair's momentum grows by exactly the motor's
    torque times the time, J theta' + I q' = u t; a command of 1200 N m drives the motor at its 1000; a spring the plant
    step cannot resolve (sqrt(k / J) h >= pi) is refused naming the step that would."""
    from stdm_drake.robots.effect_systems import MOTORS
    motor, stiffness, step = 0.01, 2000.0, 1e-4
    effects = PlantEffects(rotor_inertia=[motor], transmission_stiffness=[stiffness])
    for command, acting in ((900.0, 900.0), (1200.0, 1000.0)):
        simulation = PlantSimulator(PlantConfig.discrete(step, effects=effects), robot=wheel)
        simulation.start(np.zeros(2), np.zeros(1))
        simulation.hold(np.array([command]))
        motors = simulation.diagram.GetSubsystemByName(MOTORS).GetMyContextFromRoot(simulation.context)
        peak = 0.0
        for k in range(1, 400):
            x = simulation.advance_to(k * step)
            peak = max(peak, float(simulation.applied_torque()[0]))
            rate = motors.get_discrete_state_vector().get_value()[1]
            assert motor * rate + WHEEL_INERTIA * x[1] == pytest.approx(acting * k * step, rel=1e-9)
        assert peak > 1.5 * acting
    with pytest.raises(InputError, match=r"rings at .* which the plant step 0.001 s cannot resolve .* lower "
                                         r"--plant-time-step below 0.000702"):
        PlantSimulator(PlantConfig.discrete(1e-3, effects=PlantEffects(rotor_inertia=[motor],
                                                                       transmission_stiffness=[2e5])), robot=wheel)


@pytest.mark.slow
def test_identify_on_a_plant_no_rigid_body_model_holds_fits_and_says_what_it_misses(tmp_path, capsys):
    """Held-out run 29: identification of data from a plant with friction ripple runs (a real arm has such effects
    too) and says in one warning line that the identified robot is a rigid-body fit, not a model of them."""
    from stdm_drake.cli import main
    (tmp_path / "e.yaml").write_text("coulomb_friction: [2.0, 2.0, 1.0, 0, 0, 0]\nfriction_ripple: [0.3, 0.3, 0.3, 0, 0, 0]\n"
                                     "friction_ripple_period: [0.2]\n")   # (the light wrists: no friction, stable)
    data = tmp_path / "d.h5"
    assert main(["collect", "--protocol", "tracking", "--count", "16", "--quiet", "--plant-effects",
                 str(tmp_path / "e.yaml"), "-o", str(data)]) == 0
    capsys.readouterr()
    assert main(["identify", str(data), "-o", str(tmp_path / "i.yaml"), "--quiet"]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if "friction_ripple, which no rigid-body" in line]
    assert len(warnings) == 1 and (tmp_path / "i.yaml").exists()


@pytest.mark.parametrize("effects, field, advice", [
    (dict(coulomb_friction=[0.02], coulomb_velocity_scale=[0.05]), "coulomb_velocity_scale",
     "coulomb_velocity_scale to at least "),
    (dict(actuator_time_constant=[1e-6]), "actuator_time_constant", "or at least "),
    (dict(transmission_stiffness=[100.0], rotor_inertia=[0.1]), "transmission_stiffness", "give at least "),
])
def test_an_advised_bound_typed_back_as_printed_is_accepted(effects, field, advice):
    """Held-out run 33: a floor printed at 3 digits and rounded down ("at least 0.0588" for 0.05880...; 2.72e-05 s for
    a lag of 2.7207e-05; 105 N m/rad for 330 / pi) was refused again when typed back. Each printed bound is now
    rounded away from the refused side (`errors.bound_text`); the value given once holds for every joint, the one
    the refusal names the most demanding."""
    from stdm_drake.robots.plant_effects_check import check_plant_effects
    first = PlantEffects(**effects)
    with pytest.raises(InputError) as refused:
        check_plant_effects(first, UR10, 0.001)
    value = float(str(refused.value).split(advice)[1].split(" ")[0])
    check_plant_effects(dataclasses.replace(first, **{field: [value]}), UR10, 0.001)


def test_bound_text_rounds_away_from_the_refused_side():
    from stdm_drake.errors import bound_text
    assert bound_text(0.058800004, at_least=True) == "0.0589" and bound_text(0.058800004, at_least=False) == "0.0588"
    assert bound_text(330 / np.pi, at_least=True) == "106" and bound_text(np.pi / 0.01, at_least=False, digits=4) == "314.1"
    assert bound_text(6000.0, at_least=False) == "6e+03" and bound_text(0.0, at_least=True) == "0"


def test_a_per_joint_field_that_must_be_positive_takes_its_neutral_value_where_its_companion_is_off():
    """Held-out run 34: a per-joint gear_ratio (or velocity scale) on a joint whose rotor_inertia (friction) is 0 was
    refused with "give it 0 on that joint", and 0 was refused as not > 0, so no per-joint list could load. The
    neutral value (a gear ratio of 1, the scales' defaults) stands for none there, and the advice names it."""
    from stdm_drake.robots.plant_effects_check import check_plant_effects
    rotor = [0.0, 3.7434, 0.0, 0.0708, 0.2342, 0.4365]
    check_plant_effects(PlantEffects(rotor_inertia=rotor, gear_ratio=[1, 101, 1, 101, 101, 101]), UR10, 0.001)
    with pytest.raises(InputError, match="give it 1 on that joint"):
        check_plant_effects(PlantEffects(rotor_inertia=rotor, gear_ratio=[7, 101, 1, 101, 101, 101]), UR10, 0.001)
    friction = [0.0, 1.0, 1.0, 0.1, 0.1, 0.05]
    check_plant_effects(PlantEffects(coulomb_friction=friction, coulomb_velocity_scale=[0.05, 1, 1, 1, 1, 1]), UR10,
                        0.001)
    with pytest.raises(InputError, match="give it 0.05 on that joint"):
        check_plant_effects(PlantEffects(coulomb_friction=friction, coulomb_velocity_scale=[0.3, 1, 1, 1, 1, 1]),
                            UR10, 0.001)


def test_coulomb_advice_beyond_the_speed_range_gives_the_plant_step_or_friction_that_holds_it():
    """Held-out run 34: "raise its coulomb_velocity_scale to at least 6.77 rad/s" on a wrist whose velocity limit is
    3.14 rad/s, refused when followed. The refusal now gives the plant step (at this scale) and the friction that
    hold it, and each typed back loads."""
    from stdm_drake.robots.plant_effects_check import check_plant_effects
    effects = PlantEffects(coulomb_friction=[2.3], coulomb_velocity_scale=[0.2])
    with pytest.raises(InputError) as refused:
        check_plant_effects(effects, UR10, 0.001)
    message = str(refused.value)
    assert "is wider than the joint's speed range (3.1416 rad/s)" in message, message
    step = float(message.split("lower the plant step to ")[1].split(" ")[0])
    friction = float(message.split("or the friction to at most ")[1].split(" ")[0])
    check_plant_effects(effects, UR10, step)
    check_plant_effects(dataclasses.replace(effects, coulomb_friction=[friction]), UR10, 0.001)
    assert StationConfig(robot=UR10, plant=PlantConfig.discrete(step)).substeps() >= 1   # (it divides 10 ms)


def test_coulomb_advice_names_the_stribeck_velocity_its_scale_needs():
    """Held-out run 42: "raise its coulomb_velocity_scale to at least 0.0589 rad/s" for a wrist with a Stribeck
    breakaway at 0.05 rad/s, typed back, was refused for the Stribeck velocity the new scale hides. The advice now
    names both, and both typed back as printed load."""
    from stdm_drake.robots.plant_effects_check import check_plant_effects
    effects = PlantEffects(coulomb_friction=[1, 1, 1, 0.1, 0.1, 0.01], stribeck_friction=[2, 2, 2, 0.2, 0.2, 0.02],
                           stribeck_velocity=[0.05])
    with pytest.raises(InputError) as refused:
        check_plant_effects(effects, UR10, 0.001)
    message = str(refused.value)
    assert "on wrist_3_joint" in message and "and, beside that scale, its stribeck_velocity to at least" in message
    scale = float(message.split("coulomb_velocity_scale to at least ")[1].split(" ")[0])
    width = float(message.split("its stribeck_velocity to at least ")[1].split(" ")[0])
    with pytest.raises(InputError, match="stribeck_velocity 0.05 rad/s on wrist_3_joint ends the breakaway"):
        check_plant_effects(dataclasses.replace(effects, coulomb_velocity_scale=[0.05] * 5 + [scale]), UR10, 0.001)
    check_plant_effects(dataclasses.replace(effects, coulomb_velocity_scale=[0.05] * 5 + [scale],
                                            stribeck_velocity=[0.05] * 5 + [width]), UR10, 0.001)


def test_coulomb_advice_names_every_unstable_joint_with_the_scale_that_holds_it():
    """Held-out run 42: the line named one joint where three were unstable, so a user fixed them one run at a time.
    It names each now, with the scale that holds it at this step, and all typed back as printed load."""
    from stdm_drake.robots.plant_effects_check import check_plant_effects
    effects = PlantEffects(coulomb_friction=[1, 1, 1, 0.1, 0.1, 0.01], coulomb_velocity_scale=[0.001])
    with pytest.raises(InputError) as refused:
        check_plant_effects(effects, UR10, 0.001)
    message = str(refused.value)
    scales = [0.001] * 6
    scales[5] = float(message.split("raise its coulomb_velocity_scale to at least ")[1].split(" ")[0])
    others = message.split("unstable too at this plant step: ")[1].split("), ")
    assert [other.split(" ")[0] for other in others] == ["wrist_2_joint", "wrist_1_joint"], message
    for other in others:
        scales[UR10.joint_names.index(other.split(" ")[0])] = float(other.split("at least ")[1].split(" ")[0])
    check_plant_effects(dataclasses.replace(effects, coulomb_velocity_scale=scales), UR10, 0.001)


def test_an_advised_plant_step_divides_the_sample_period_within_the_step_budget():
    """Held-out run 35: "lower the plant step to at most 1.13e-07 s at this scale (at most 0.000356 s with the scale
    at 3.1416 rad/s)": the first is 88,500 steps per 10 ms sample (at most 10,000 run), the second no whole fraction
    of 10 ms; both refused when typed back. A step is advised now only where one divides the sample period within
    the budget, as printed, and each advised step loads with its scale and runs."""
    from stdm_drake.robots.plant_effects_check import check_plant_effects, stable_plant_step
    assert stable_plant_step(0.000356, 0.01) == 0.0003125 and stable_plant_step(1.13e-7, 0.01) is None
    assert stable_plant_step(0.001, 0.01) == 0.001 and stable_plant_step(0.0004, 0.002) == 0.0004
    assert stable_plant_step(1e-6, 0.01) == 1e-6 and stable_plant_step(1e-320, 0.01) is None   # (the budget's edge;
    assert stable_plant_step(0.0, 0.01) is None and stable_plant_step(float("nan"), 0.01) is None   # no quotient)
    # (held-out run 37: 0.01 / 2997 printed as 3.33667e-06 s is 2997.000003 steps, which the station refuses: every
    # step advised is one the station takes, by the same test)
    assert stable_plant_step(0.01 / 2997 * (1 + 1e-12), 0.01) != 3.33667e-06
    for period in (0.01, 0.007, 0.02, 0.004):
        for steps in range(1, 10_001, 13):
            step = stable_plant_step(period / steps, period)
            assert step is None or StationConfig(robot=UR10, sample_period=period,
                                                 plant=PlantConfig.discrete(step)).substeps() >= steps
    friction = [0, 0, 0, 0, 0, 3.0]
    for scale, period in ((0.001, 0.01), (3.1416, 0.01), (3.1416, 0.002)):
        effects = PlantEffects(coulomb_friction=friction, coulomb_velocity_scale=[0.05] * 5 + [scale])
        with pytest.raises(InputError) as refused:
            check_plant_effects(effects, UR10, 0.001, period)
        message = str(refused.value)
        advised = [float(part.split(" ")[0]) for part in message.split("the plant step to ")[1:]]
        assert advised and (scale == 3.1416 or "with the scale at 3.1416 rad/s" in message), message
        step = advised[-1]
        check_plant_effects(dataclasses.replace(effects, coulomb_velocity_scale=[0.05] * 5 + [3.1416]), UR10, step,
                            period)
        assert StationConfig(robot=UR10, sample_period=period, plant=PlantConfig.discrete(step)).substeps() >= 1
    with pytest.raises(InputError, match=r"lower the friction to at most .* \(no plant step within 10000 per sample "
                                         r"period of 0.01 s holds it\)"):
        check_plant_effects(PlantEffects(coulomb_friction=[0, 0, 0, 0, 0, 3e5],
                                         coulomb_velocity_scale=[0.05] * 5 + [3.1416]), UR10, 0.001)


def test_a_transmission_the_plant_step_cannot_resolve_is_refused_with_a_step_that_divides_the_period():
    """Held-out run 38: "lower --plant-time-step below 3.14e-05 s" for a 1e7 N m/rad spring behind 0.001 kg m² (at
    1.59e4 Hz), which divides none of 7, 10 and 20 ms: typed back, refused. The advice is now a step that divides
    the sample period and resolves the ring, or the stiffness the plant step resolves; both load as printed."""
    from stdm_drake.robots.plant_effects_check import check_plant_effects
    stiff = PlantEffects(rotor_inertia=[0, 0, 0, 0, 0, 0.001], transmission_stiffness=[0, 0, 0, 0, 0, 1e7])
    for period in (0.01, 0.007, 0.02):
        with pytest.raises(InputError) as refused:
            check_plant_effects(stiff, UR10, 0.001, period)
        message = str(refused.value)
        assert "rings at 1.59e+04 Hz, which the plant step 0.001 s cannot resolve (omega h = 100 >= pi)" in message
        step = float(message.split("lower --plant-time-step to ")[1].split(" ")[0])
        stiffness = float(message.split("give a transmission_stiffness below ")[1].split(" ")[0])
        check_plant_effects(stiff, UR10, step, period)
        assert StationConfig(robot=UR10, sample_period=period, plant=PlantConfig.discrete(step)).substeps() >= 1
        check_plant_effects(dataclasses.replace(stiff, transmission_stiffness=[0, 0, 0, 0, 0, stiffness]), UR10,
                            0.001, period)
