"""The UR-10 description against its published numbers, and Drake's offline behaviour."""
import math
import time

import numpy as np
import pytest

from stdm_drake.robots.plant import Dynamics, SelfCollisionChecker, joint_limits, make_plant
from stdm_drake.robots.model_file import offline_parser
from presets import UR10

DH = [(0, 0.1273, math.pi / 2), (-0.612, 0, 0), (-0.5723, 0, 0),
      (0, 0.163941, math.pi / 2), (0, 0.1157, -math.pi / 2), (0, 0.0922, 0)]


def dh_forward_kinematics(q):
    transform = np.eye(4)
    for (a, d, alpha), theta in zip(DH, q):
        ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
        transform = transform @ np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st],
                                          [0, sa, ca, d], [0, 0, 0, 1]])
    return transform


@pytest.fixture(scope="module")
def plant_and_context():
    plant, _ = make_plant(robot=UR10)
    return plant, plant.CreateDefaultContext()


def test_forward_kinematics_equals_dh_product(plant_and_context):
    plant, context = plant_and_context
    rng = np.random.default_rng(0)
    for q in rng.uniform(-np.pi, np.pi, size=(20, 6)):
        plant.SetPositions(context, q)
        X = plant.CalcRelativeTransform(context, plant.GetFrameByName("base_link_inertia"), plant.GetFrameByName(UR10.tool_frame))
        np.testing.assert_allclose(X.GetAsMatrix4(), dh_forward_kinematics(q), atol=1e-11)


def test_mass_matrix_positive_definite_and_total_mass(plant_and_context):
    plant, context = plant_and_context
    rng = np.random.default_rng(1)
    for q in rng.uniform(-np.pi, np.pi, size=(20, 6)):
        plant.SetPositions(context, q)
        M = plant.CalcMassMatrix(context)
        np.testing.assert_allclose(M, M.T, atol=1e-12)
        assert np.linalg.eigvalsh(M).min() > 1e-5
    masses = [plant.get_body(i).default_mass() for i in plant.GetBodyIndices(plant.GetModelInstanceByName("ur10"))]
    assert sum(masses) == pytest.approx(32.435, abs=1e-9)  # published total, base (4.0 kg) included


def test_gravity_torque_at_zero_matches_published():
    tau = Dynamics(UR10).gravity_torque(np.zeros(6))
    assert abs(tau[1]) == pytest.approx(119.17, abs=0.1)
    assert abs(tau[2]) == pytest.approx(38.43, abs=0.1)
    assert np.abs(tau[[0, 4, 5]]).max() < 1e-9


def test_limits_read_back_from_plant(plant_and_context):
    limits = joint_limits(plant_and_context[0])
    two_pi = 2 * math.pi
    np.testing.assert_allclose(limits.position_upper, [two_pi, two_pi, math.pi, two_pi, two_pi, two_pi])
    np.testing.assert_allclose(limits.position_lower, -limits.position_upper)
    np.testing.assert_allclose(limits.velocity, [2.0944, 2.0944, 3.1416, 3.1416, 3.1416, 3.1416])
    np.testing.assert_allclose(limits.effort, [330, 330, 150, 56, 56, 56])


def test_actuation_is_clamped_to_effort_limits():
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    builder = DiagramBuilder()
    plant, _ = make_plant(builder=builder, robot=UR10)
    builder.ExportInput(plant.get_actuation_input_port(), "actuation")
    diagram = builder.Build()

    def velocity_after(torque):
        simulator = Simulator(diagram)
        context = simulator.get_mutable_context()
        diagram.GetInputPort("actuation").FixValue(context, torque)
        simulator.AdvanceTo(0.002)
        return plant.GetVelocities(plant.GetMyContextFromRoot(context))

    np.testing.assert_allclose(velocity_after(np.array([0, 0, 0, 0, 0, 1e4])),
                               velocity_after(np.array([0, 0, 0, 0, 0, 56.0])), rtol=1e-9)


def test_urdf_matches_generator():
    from tools_import import generate_ur10_urdf
    assert UR10.model_path.read_text() == generate_ur10_urdf.urdf_text()


def test_remote_package_fails_at_once_offline():
    from pydrake.multibody.plant import MultibodyPlant
    parser = offline_parser(MultibodyPlant(0.001))
    started = time.perf_counter()
    with pytest.raises(Exception, match="drake_models"):
        parser.AddModels(url="package://drake_models/ur_description/urdf/ur10.urdf")
    assert time.perf_counter() - started < 5


def test_self_collision_checker():
    checker = SelfCollisionChecker(UR10)
    assert checker.is_collision_free(np.zeros(6))
    assert checker.is_collision_free(np.array([0, -1.57, 1.57, -1.57, -1.57, 0]))
    folded = np.array([0, 0, 3.1, 0, 0, 0])
    assert not checker.is_collision_free(folded)
    assert ("shoulder_link", "forearm_link") in checker.colliding_links(folded)


def test_the_plant_takes_drakes_own_multibody_plant_config():
    """PlantConfig embeds Drake's MultibodyPlantConfig: what it holds reaches AddMultibodyPlant, a dataset
    records every field of it, and it crosses to worker processes (pickled as its YAML)."""
    import pickle

    from pydrake.multibody.plant import DiscreteContactApproximation
    from pydrake.systems.framework import DiagramBuilder

    from stdm_drake.robots.plant import PlantConfig
    config = PlantConfig.discrete(0.002)
    config.multibody.discrete_contact_approximation = "lagged"
    config.multibody.penetration_allowance = 0.005
    plant, _ = make_plant(config, builder=DiagramBuilder(), robot=UR10)
    assert plant.time_step() == 0.002
    assert plant.get_discrete_contact_approximation() == DiscreteContactApproximation.kLagged
    record = config.record()
    assert record["penetration_allowance"] == 0.005 and record["self_collision"] is True
    assert pickle.loads(pickle.dumps(config)).record() == record
    assert PlantConfig.continuous().time_step == 0.0 and PlantConfig().record()["discrete_contact_approximation"] == "sap"
