"""Real-time dynamics: the analytic rigid-body model built from the Drake plant, the plant model's exact
Jacobians, the one batched horizon evaluation every `DynamicsModel` offers (its conformance test), and
the real-time iteration that uses it."""
import dataclasses

import numpy as np
import pytest
import torch

from presets import UR10, free_limits
from stdm_drake.dynamics.model import DynamicsModel, HeldInputSubsteps
from stdm_drake.learning.learned_model import LearnedModel
from stdm_drake.learning.models import EnsembleMLP, ModelConfig
from stdm_drake.dynamics.physics import ConstantVelocity, PlantModel, StaysPut, central_difference_jacobians
from stdm_drake.learning.structure import DEFAULT, PAPER, ModelStructure
from stdm_drake.robots.effects import PlantEffects, load_plant_effects
from stdm_drake.robots.plant import Dynamics, PlantConfig
from stdm_drake.robots.rigid_body import robot_dynamics
from stdm_drake.robots.robot import load_robot
from stdm_drake.paths import MODELS_DIR

def inertial(com: str, rpy: str, mass: float, i: float, j: float, k: float) -> str:
    """An <inertial> with products of inertia (a tenth of the smallest moment: positive definite)."""
    product = 0.1 * min(i, j, k)
    return (f'<inertial><origin xyz="{com}" rpy="{rpy}"/><mass value="{mass}"/><inertia ixx="{i}" ixy="{product:g}" '
            f'ixz="{-0.5 * product:g}" iyy="{j}" iyz="{0.3 * product:g}" izz="{k}"/></inertial>')



LIMIT = '<limit lower="-2.8" upper="2.8" effort="{effort}" velocity="2.5"/>'

# A published-style arm description: joint frames with rpy offsets, a skewed revolute axis, a prismatic arm
# joint, an inertial frame rotated off its link with products of inertia, joint damping, a massive flange
# welded to the last link and a locked gripper joint (welded by the robot config).
PUBLISHED_ARM = f"""<?xml version="1.0"?>
<robot name="skewed_arm">
  <link name="base">{inertial(com="0 0 0.05", rpy="0 0 0", mass=4.0, i=0.03, j=0.03, k=0.02)}</link>
  <link name="link1">{inertial(com="0.02 0.01 0.12", rpy="0.1 0.2 0.3", mass=3.0, i=0.04, j=0.05, k=0.03)}</link>
  <link name="link2">{inertial(com="0.15 0 0.01", rpy="0 0.4 0", mass=2.0, i=0.02, j=0.06, k=0.05)}</link>
  <link name="slider">{inertial(com="0 0.05 0", rpy="0 0 0", mass=1.0, i=0.01, j=0.008, k=0.01)}</link>
  <link name="wrist">{inertial(com="0 0 0.03", rpy="0.3 0 0", mass=0.5, i=0.002, j=0.002, k=0.001)}</link>
  <link name="flange">{inertial(com="0 0 0.01", rpy="0 0 0", mass=0.3, i=0.0004, j=0.0004, k=0.0003)}</link>
  <link name="finger">{inertial(com="0 0 0.02", rpy="0 0 0", mass=0.05, i=0.0001, j=0.0001, k=0.0001)}</link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="link1"/>
    <origin xyz="0 0 0.1" rpy="0 0 0.5"/><axis xyz="0 0 1"/>{LIMIT.format(effort=150)}</joint>
  <joint name="j2" type="revolute"><parent link="link1"/><child link="link2"/>
    <origin xyz="0 0.05 0.25" rpy="0.2 -0.1 0"/><axis xyz="0 0.6 0.8"/>{LIMIT.format(effort=120)}
    <dynamics damping="2.0"/></joint>
  <joint name="j3" type="prismatic"><parent link="link2"/><child link="slider"/>
    <origin xyz="0.3 0 0" rpy="0 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-0.1" upper="0.1" effort="200" velocity="0.5"/></joint>
  <joint name="j4" type="revolute"><parent link="slider"/><child link="wrist"/>
    <origin xyz="0 0.1 0" rpy="1.5707963 0 0"/><axis xyz="1 0 0"/>{LIMIT.format(effort=30)}
    <dynamics damping="0.1"/></joint>
  <joint name="flange_fixed" type="fixed"><parent link="wrist"/><child link="flange"/>
    <origin xyz="0 0 0.08" rpy="0 0.3 0"/></joint>
  <joint name="finger_joint" type="prismatic"><parent link="flange"/><child link="finger"/>
    <origin xyz="0 0 0.02"/><axis xyz="1 0 0"/><limit lower="0" upper="0.04" effort="10" velocity="0.1"/></joint>
</robot>
"""
PUBLISHED_CONFIG = """name: skewed_arm
model: skewed_arm.urdf
weld_frame: base
arm_joints: [j1, j2, j3, j4]
locked_joints: {finger_joint: 0.02}
home: [0.2, 0.4, 0.03, -0.3]
tool_frame: flange
"""


@pytest.fixture(scope="module")
def published_arm(tmp_path_factory):
    folder = tmp_path_factory.mktemp("published_arm")
    (folder / "skewed_arm.urdf").write_text(PUBLISHED_ARM)
    (folder / "skewed_arm.yaml").write_text(PUBLISHED_CONFIG)
    return load_robot(folder / "skewed_arm.yaml")


def robot_cases(published_arm):
    """(label, robot, effects): every shipped robot, the affected UR-10 and Panda, the published-style arm."""
    shipped = {name: load_robot(MODELS_DIR / f"{name}.yaml") for name in ("ur10", "panda", "acrobot", "ur10_limit_free")}
    return [(name, robot, None) for name, robot in shipped.items()] + [
        ("ur10 affected", shipped["ur10"], load_plant_effects(MODELS_DIR / "ur10_effects.yaml")),
        ("panda affected", shipped["panda"], load_plant_effects(MODELS_DIR / "panda_effects.yaml")),
        ("published-style arm", published_arm, None),
        ("published-style arm, mass scale and payload", published_arm,
         PlantEffects(mass_scale={"link2": 1.3}, viscous_friction=[0.5], coulomb_friction=[1.0],
                      coulomb_velocity_scale=[0.05]))]


def random_rows(robot, count: int, seed: int = 0):
    """q near home, v and τ (gravity at q plus noise) rows (count, n), (count, n), (count, m)."""
    rng = np.random.default_rng(seed)
    n = robot.num_joints
    q = robot.home + rng.uniform(-0.3, 0.3, (count, n))
    v = rng.uniform(-1.0, 1.0, (count, n))
    gravity = Dynamics(robot)
    tau = np.array([gravity.actuated_gravity_torque(row) for row in q]) + rng.normal(0.0, 2.0, (count, robot.action_dim))
    return q, v, tau


def test_rigid_body_dynamics_equal_drakes_forward_dynamics_and_its_derivatives(published_arm):
    """On every robot case, over random states: accelerations equal Drake's (M⁻¹ of the plant's own mass
    matrix, bias and gravity terms, damping and friction) to 1e-9 relative, and the analytic derivatives
    equal central differences of Drake's accelerations to 1e-6 relative."""
    for label, robot, effects in robot_cases(published_arm):
        dynamics, drake = robot_dynamics(robot, effects), Dynamics(robot, effects)
        q, v, tau = random_rows(robot, 6)
        n = robot.num_joints

        def reference(q, v, tau):
            return np.array([drake.acceleration(*row) for row in zip(q, v, tau)])
        expected = reference(q, v, tau)
        values, jacobian = dynamics.acceleration_and_jacobians(q, v, tau)
        scale = np.abs(expected).max()
        assert np.abs(dynamics.acceleration(q, v, tau) - expected).max() <= 1e-9 * scale, label
        assert np.abs(values - expected).max() <= 1e-9 * scale, label
        for i in range(len(q)):
            assert np.abs(dynamics.acceleration_row(q[i], v[i], tau[i]) - expected[i]).max() <= 1e-9 * scale, label
        point = np.hstack([q, v, tau])
        numeric = np.empty_like(jacobian)
        for k in range(point.shape[1]):
            epsilon = 1e-6 * max(1.0, np.abs(point[:, k]).max())
            ahead, behind = point.copy(), point.copy()
            ahead[:, k] += epsilon
            behind[:, k] -= epsilon
            numeric[:, :, k] = (reference(ahead[:, :n], ahead[:, n:2 * n], ahead[:, 2 * n:])
                                - reference(behind[:, :n], behind[:, n:2 * n], behind[:, 2 * n:])) / (2 * epsilon)
        assert np.abs(jacobian - numeric).max() <= 1e-6 * np.abs(numeric).max(), label


def bare_network(structure: ModelStructure, robot, *, members: int = 1, probabilistic: bool = False,
                 seed: int = 0) -> LearnedModel:
    """An untrained network of `structure` on `robot` (random weights: the Jacobians are what is tested)."""
    inputs, outputs = structure.network_sizes(robot.state_dim, robot.action_dim)
    torch.manual_seed(seed)
    network = EnsembleMLP(ModelConfig(input_dim=inputs, output_dim=outputs, residual=True, hidden_width=32,
                                      hidden_layers=2, ensemble_size=members, probabilistic=probabilistic))
    return LearnedModel(network, structure=structure, robot=robot, sample_period=0.01, name=f"network {structure.label}")


def conformance_models():
    """(model, relative tolerance of its Jacobians): every kind of DynamicsModel the toolbox ships."""
    effects = load_plant_effects(MODELS_DIR / "ur10_effects.yaml")
    identified = PlantEffects(mass_scale={"forearm_link": 1.2}, viscous_friction=[0.8], payload=effects.payload)
    affected_config = PlantConfig.discrete(0.001, effects=effects)
    float64 = [ConstantVelocity(12, 6, 0.01), StaysPut(12, 6, 0.01),
               PlantModel(0.01, robot=UR10, integrator="rk4"),
               PlantModel(0.01, affected_config, robot=UR10, integrator="rk4"),
               PlantModel(0.01, PlantConfig.discrete(0.001, effects=identified), robot=UR10, integrator="rk4",
                          name="identified"),
               HeldInputSubsteps(PlantModel(0.005, robot=UR10, integrator="rk4"), 2)]
    networks = [bare_network(PAPER, UR10), bare_network(DEFAULT, UR10),
                bare_network(ModelStructure("state", "nominal_acceleration"), UR10),
                bare_network(ModelStructure("velocity", "period_acceleration"), UR10),
                bare_network(ModelStructure("velocity", "plant_step", plant_integrator="rk4"), UR10),
                bare_network(ModelStructure("state", "plant_step", plant_integrator="rk4"), UR10),
                bare_network(PAPER, UR10, members=5, probabilistic=True),
                bare_network(DEFAULT, UR10, members=5)]
    return [(model, 1e-5) for model in float64] + [(model, 5e-3) for model in networks]


@pytest.mark.slow
def test_every_dynamics_model_evaluates_a_horizon_in_one_call_with_exact_jacobians():
    """The conformance test of the `DynamicsModel` contract: for every model kind, `linearize` over a horizon of
    rows gives the same next states as `step` (and `step_single` row by row), and Jacobians equal to central
    differences of `step`: 1e-5 relative for float64 models (the physics baselines, the plant models of the
    description, the affected plant and an identified robot, held substeps), 5e-3 for the float32 networks
    (every structure and input, ensembles: the differences' own float32 rounding reaches ~2e-3, a wrong
    chain rule is off by O(1))."""
    q, v, tau = random_rows(UR10, 5, seed=1)
    x = np.hstack([q, v])
    for model, tolerance in conformance_models():
        assert isinstance(model, DynamicsModel)
        following, A, B = model.linearize(x, tau)
        stepped = model.step(x, tau)
        exactness = 1e-12 if tolerance == 1e-5 else 1e-5
        np.testing.assert_allclose(following, stepped, rtol=exactness, atol=exactness * np.abs(stepped).max(),
                                   err_msg=model.name)
        single = np.array([model.step_single(x[i], tau[i]) for i in range(len(x))])
        np.testing.assert_allclose(single, stepped, rtol=exactness, atol=exactness * np.abs(stepped).max(),
                                   err_msg=model.name)
        if tolerance == 1e-5:
            numeric_A, numeric_B = central_difference_jacobians(model.step, x, tau)
        else:     # float32 networks: a step large against their rounding
            numeric_A, numeric_B = _float32_differences(model, x, tau)
        for name, mine, numeric in (("A", A, numeric_A), ("B", B, numeric_B)):
            error = np.abs(mine - numeric).max() / max(np.abs(numeric).max(), 1e-12)   # (zero: kinematic baselines' B)
            assert error <= tolerance, f"{model.name}: d step / d {'x' if name == 'A' else 'a'} off by {error:.2g}"
        np.testing.assert_array_equal(np.concatenate(model.jacobians(x, tau), axis=2), np.concatenate([A, B], axis=2))


def _float32_differences(model, x, tau):
    """Richardson-extrapolated central differences, (4 D(h/2) - D(h)) / 3 with h = 1e-2 (rad, rad/s, N m):
    steps large against the float32 rounding of outputs up to ~100 (untrained networks on raw torques),
    the second-order truncation of steep inputs (a light wrist's M⁻¹ τ) cancelled."""
    S = x.shape[1]
    point = np.hstack([x, tau])

    def differences(epsilon):
        jacobian = np.empty((len(x), S, point.shape[1]))
        for k in range(point.shape[1]):
            ahead, behind = point.copy(), point.copy()
            ahead[:, k] += epsilon
            behind[:, k] -= epsilon
            jacobian[:, :, k] = (model.step(ahead[:, :S], ahead[:, S:]) - model.step(behind[:, :S], behind[:, S:])) / (2 * epsilon)
        return jacobian
    jacobian = (4.0 * differences(5e-3) - differences(1e-2)) / 3.0
    return jacobian[:, :, :S], jacobian[:, :, S:]


def test_the_simulators_plant_model_has_its_own_steps_central_differences():
    """The evaluation baseline (the discrete Drake plant) differentiates its own step; the control model
    (RK4) differs from it by the simulator's discretization, a small part of the one-step change."""
    simulator, rk4 = PlantModel(0.01, robot=UR10), PlantModel(0.01, robot=UR10, integrator="rk4")
    q, v, tau = random_rows(UR10, 2, seed=2)
    x = np.hstack([q, v])
    A, B = simulator.jacobians(x, tau)
    assert A.shape == (2, 12, 12) and B.shape == (2, 12, 6) and np.all(np.isfinite(A))
    difference = np.abs(rk4.step(x, tau) - simulator.step(x, tau))[:, 6:].max()
    assert difference < 0.05 * np.abs(simulator.step(x, tau) - x)[:, 6:].max()


def test_rk4_substeps_follow_the_fastest_damping(tmp_path):
    """One RK4 step on an undamped arm; a joint whose damping stops it faster than the period gets steps no
    longer than its time constant, and the step stays stable: its fast mode decays as exp(-T / time constant)
    (one RK4 step over the period would multiply it by ~250), no eigenvalue grows."""
    assert PlantModel(0.01, robot=UR10, integrator="rk4").substeps == 1
    stiff = PUBLISHED_ARM.replace('<dynamics damping="0.1"/>', '<dynamics damping="5.0"/>')
    (tmp_path / "skewed_arm.urdf").write_text(stiff)
    (tmp_path / "skewed_arm.yaml").write_text(PUBLISHED_CONFIG)
    robot = load_robot(tmp_path / "skewed_arm.yaml")
    model = PlantModel(0.01, robot=robot, integrator="rk4")
    assert model.substeps > 1
    inverse = np.diag(model.dynamics.inverse_mass_matrix(robot.home))
    assert 0.01 / model.substeps <= 1.0 / np.max(model.dynamics.damping * inverse)
    x = np.concatenate([robot.home, np.zeros(4)])[None]
    A, _ = model.jacobians(x, Dynamics(robot).actuated_gravity_torque(robot.home)[None])
    moduli = np.abs(np.linalg.eigvals(A[0]))
    assert moduli.max() < 1.02 and moduli.min() < 1e-3


def test_the_real_time_iteration_finds_the_exact_lqr_solution_on_a_linear_model():
    """One RTI step on a linear model from any warm start is the exact minimizer of the MPC cost (no
    torque limit active): the same as the iLQR's and as one least-squares solve over all torques."""
    from test_mpc import LinearModel, exact_lqr_controls
    from stdm_drake.closed_loop.mpc import MpcConfig
    from stdm_drake.closed_loop.rti import Rti, RtiSolver
    model, config = LinearModel(), MpcConfig(horizon=8, optimizer=Rti(regularization=0.0))
    rng = np.random.default_rng(3)
    x0 = rng.normal(size=12) * 0.1
    reference = rng.normal(size=(config.horizon + 1, 12)) * 0.1
    u_ff = rng.normal(size=(config.horizon, 6))
    solver = RtiSolver(model, config.cost(6), np.full(6, 1e9), config.optimizer)
    expected = exact_lqr_controls(model, config, x0, reference, u_ff)
    for nodes in (None, rng.normal(size=(config.horizon + 1, 12))):   # a rollout, or arbitrary warm-start states
        result = solver.solve(x0, rng.normal(size=(config.horizon, 6)), reference, u_ff, x_init=nodes)
        np.testing.assert_allclose(result.u, expected, rtol=1e-6, atol=1e-8 * np.abs(expected).max())
        np.testing.assert_allclose(result.x[1:], model.rollout(x0[None], result.u[None]).mean[0], rtol=1e-9, atol=1e-12)


def test_an_rti_horizon_beyond_its_dense_system_is_refused_in_one_line():
    from stdm_drake.closed_loop.ilqr import Ilqr
    from stdm_drake.closed_loop.mpc import MpcConfig
    from stdm_drake.errors import InputError
    config = dataclasses.replace(MpcConfig(), horizon=200)
    with pytest.raises(InputError, match="optimizer: !Ilqr"):
        config.solver(PlantModel(0.01, robot=UR10, integrator="rk4"), free_limits(100.0))
    dataclasses.replace(config, optimizer=Ilqr()).solver(ConstantVelocity(12, 6, 0.01), free_limits(100.0))
    with pytest.raises(InputError, match="optimizer must be one of"):
        dataclasses.replace(MpcConfig(), optimizer="mppi").validate()


BRANCHED = """<?xml version="1.0"?>
<robot name="branched">
  <link name="base">{base}</link>
  <link name="torso">{torso}</link>
  <link name="left">{left}</link>
  <link name="left_hand">{hand}</link>
  <link name="right">{right}</link>
  <link name="right_hand">{hand}</link>
  <joint name="waist" type="revolute"><parent link="base"/><child link="torso"/><origin xyz="0 0 0.2"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="100" velocity="2"/></joint>
  <joint name="left_shoulder" type="revolute"><parent link="torso"/><child link="left"/>
    <origin xyz="0 0.2 0.3" rpy="0.3 0 0"/><axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="80" velocity="2"/></joint>
  <joint name="right_shoulder" type="revolute"><parent link="torso"/><child link="right"/>
    <origin xyz="0 -0.2 0.3" rpy="-0.3 0 0"/><axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="80" velocity="2"/>
    <dynamics damping="0.5"/></joint>
  <joint name="left_elbow" type="revolute"><parent link="left"/><child link="left_hand"/>
    <origin xyz="0.3 0 0"/><axis xyz="1 0 1"/><limit lower="-3" upper="3" effort="40" velocity="2"/></joint>
  <joint name="right_elbow" type="prismatic"><parent link="right"/><child link="right_hand"/>
    <origin xyz="0.3 0 0"/><axis xyz="1 0 0"/><limit lower="-0.1" upper="0.1" effort="40" velocity="1"/></joint>
</robot>
"""


def test_a_branched_tree_gets_pinocchios_depth_first_order():
    """Two arms on a torso, the joints listed breadth first in the file (waist, both shoulders, both elbows):
    Pinocchio's model numbers each subtree's joints together (depth first; a breadth-first numbering gave
    Jacobians and M⁻¹ off by half their size), and accelerations, M⁻¹ and the derivatives equal Drake's (its
    forward dynamics, its mass matrix, central differences) to 1e-9 / 1e-6 relative."""
    from pydrake.multibody.plant import MultibodyPlant
    from stdm_drake.robots.model_file import offline_parser
    from stdm_drake.robots.rigid_body import RigidBodyDynamics
    links = {name: inertial(com, "0 0 0", mass, i, i, 0.8 * i) for name, com, mass, i in (
        ("base", "0 0 0.1", 5.0, 0.05), ("torso", "0 0 0.2", 4.0, 0.04), ("left", "0.15 0 0", 2.0, 0.02),
        ("right", "0.15 0.01 0", 2.5, 0.025), ("hand", "0.05 0 0.02", 0.6, 0.004))}
    plant = MultibodyPlant(0.0)
    offline_parser(plant).AddModelsFromString(BRANCHED.format(**links), "urdf")
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("base"))
    for name in ("waist", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow"):
        plant.AddJointActuator(f"{name}_motor", plant.GetJointByName(name))
    plant.Finalize()
    context = plant.CreateDefaultContext()
    dynamics = RigidBodyDynamics(plant, context)
    rng = np.random.default_rng(4)
    q, v, tau = rng.uniform(-1, 1, (4, 5)), rng.uniform(-1, 1, (4, 5)), rng.normal(0, 5, (4, 5))

    def drake(q, v, tau):
        out = np.empty_like(q)
        for i in range(len(q)):
            plant.SetPositionsAndVelocities(context, np.concatenate([q[i], v[i]]))
            plant.get_actuation_input_port().FixValue(context, tau[i])
            out[i] = plant.EvalTimeDerivatives(context).CopyToVector()[5:]
        return out
    expected = drake(q, v, tau)
    values, jacobian = dynamics.acceleration_and_jacobians(q, v, tau)
    np.testing.assert_allclose(values, expected, rtol=0, atol=1e-9 * np.abs(expected).max())
    np.testing.assert_allclose(dynamics.acceleration(q, v, tau), expected, rtol=0, atol=1e-9 * np.abs(expected).max())
    plant.SetPositions(context, q[0])
    inverse = np.linalg.inv(plant.CalcMassMatrix(context))
    np.testing.assert_allclose(dynamics.inverse_mass_matrix(q[0]), inverse, rtol=0, atol=1e-9 * np.abs(inverse).max())
    point, numeric = np.hstack([q, v, tau]), np.empty_like(jacobian)
    for k in range(15):
        ahead, behind = point.copy(), point.copy()
        ahead[:, k] += 1e-6
        behind[:, k] -= 1e-6
        numeric[:, :, k] = (drake(ahead[:, :5], ahead[:, 5:10], ahead[:, 10:])
                            - drake(behind[:, :5], behind[:, 5:10], behind[:, 10:])) / 2e-6
    assert np.abs(jacobian - numeric).max() <= 1e-6 * np.abs(numeric).max()
