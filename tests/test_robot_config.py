"""Robots as typed configs: the UR-10 preset, and an arm brought as a URDF with bad configs refused."""
import json
import os
import pathlib

import numpy as np
import pytest
from conftest import closed_loop_status

from stdm_drake.errors import InputError
from stdm_drake.robots.plant import PlantConfig, joint_limits, make_plant
from presets import UR10
from stdm_drake.robots.robot import load_robot

LINK = """  <link name="{name}">
    <inertial><mass value="{mass}"/><origin xyz="0 0 {com}"/>
      <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.005"/></inertial>
    <visual><geometry><cylinder radius="0.04" length="0.3"/></geometry></visual>
  </link>
"""


def two_link_urdf(effort: bool = True) -> str:
    """A planar 2-link arm (no <transmission>) with a prismatic finger: 3 movable joints."""
    limit = 'effort="{}" ' if effort else ""
    joint = ('  <joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
             '<origin xyz="0 0 {z}"/><axis xyz="{axis}"/>'
             '<limit lower="{lower}" upper="{upper}" ' + limit + 'velocity="{velocity}"/></joint>\n')
    links = "".join(LINK.format(name=name, mass=mass, com=0.15) for name, mass in
                    (("base", 5.0), ("upper", 2.0), ("fore", 1.0), ("finger", 0.1)))
    joints = (joint.format("40", name="shoulder", kind="revolute", parent="base", child="upper", z=0.1, axis="0 1 0",
                           lower=-2.5, upper=2.5, velocity=3.0)
              + joint.format("20", name="elbow", kind="revolute", parent="upper", child="fore", z=0.3, axis="0 1 0",
                             lower=-2.5, upper=2.5, velocity=3.0)
              + joint.format("5", name="finger_joint", kind="prismatic", parent="fore", child="finger", z=0.3,
                             axis="1 0 0", lower=0.0, upper=0.04, velocity=0.1))
    links += '  <link name="tool"/>\n  <joint name="tool_fixed" type="fixed"><parent link="fore"/><child link="tool"/>' \
             '<origin xyz="0 0 0.3"/></joint>\n'
    return f'<?xml version="1.0"?>\n<robot name="two_link">\n{links}{joints}</robot>\n'


def write_robot(folder, urdf_text: str, config_text: str):
    (folder / "two_link.urdf").write_text(urdf_text)
    path = folder / "two_link.yaml"
    path.write_text(config_text)
    return path


GOOD = """name: two_link
model: two_link.urdf
weld_frame: base
arm_joints: [shoulder, elbow]
locked_joints: {finger_joint: 0.02}
home: [0.3, -0.6]
tool_frame: tool
"""


def test_ur10_preset_is_the_default_robot():
    """A command without --robot (and without a dataset naming a preset) gets models/ur10.yaml, `collect`
    included: the preset tests use as UR10, 6 joints, actuated in its joints' order."""
    import argparse

    from stdm_drake.collection.collect_job import CollectJob, job_request
    from stdm_drake.commands import collect
    from stdm_drake.commands.arguments import command_robot
    parser = argparse.ArgumentParser()
    collect.add_arguments(parser)
    args = parser.parse_args(["--protocol", "excitation", "-o", "unused.h5"])
    collected = job_request(CollectJob(output=args.output, protocol=args.protocol, robot=args.robot))
    for default in (command_robot(argparse.Namespace(robot=None)), collected.settings.robot):
        assert default.config_path == UR10.config_path and default.config_path.name == "ur10.yaml"
        assert default.joint_names == UR10.joint_names and default.model_sha256() == UR10.model_sha256()
    assert UR10.name == "ur10" and UR10.num_joints == 6 and UR10.tool_frame == "tool0"
    plant, _ = make_plant(PlantConfig.continuous(), robot=UR10)
    limits = joint_limits(plant)
    assert np.all(UR10.home > limits.position_lower) and np.all(UR10.home < limits.position_upper)
    assert [plant.get_joint_actuator(i).joint().name() for i in plant.GetJointActuatorIndices()] == \
        list(UR10.joint_names)


def test_an_arm_without_transmissions_gets_actuators_from_its_file(tmp_path):
    robot = load_robot(write_robot(tmp_path, two_link_urdf(), GOOD))
    plant, _ = make_plant(PlantConfig.continuous(), robot=robot)
    assert plant.num_positions() == 2 and robot.joint_names == ("shoulder", "elbow")   # the finger is welded
    np.testing.assert_array_equal(joint_limits(plant).effort, [40.0, 20.0])
    np.testing.assert_array_equal(joint_limits(plant).velocity, [3.0, 3.0])
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, robot.home)
    gravity = -plant.CalcGravityGeneralizedForces(context)
    assert np.all(np.isfinite(gravity)) and abs(gravity[0]) > 0.1       # the arm feels gravity
    assert len(robot.model_sha256()) == 64


def test_configured_limits_fill_gaps_and_replace_the_files(tmp_path):
    path = write_robot(tmp_path, two_link_urdf(effort=False),
                       GOOD + "effort_limits: {shoulder: 35.0, elbow: 12.0}\nvelocity_limits: {elbow: 1.5}\n")
    plant, _ = make_plant(PlantConfig.continuous(), robot=load_robot(path))
    np.testing.assert_array_equal(joint_limits(plant).effort, [35.0, 12.0])
    np.testing.assert_array_equal(joint_limits(plant).velocity, [3.0, 1.5])


@pytest.mark.parametrize("urdf, config, message", [
    ("good", GOOD.replace("two_link.urdf", "missing.urdf"), "model file not found"),
    ("good", GOOD.replace("[shoulder, elbow]", "[shoulder, wrist]"), "joint 'wrist' is not in two_link.urdf"),
    ("good", GOOD.replace("[0.3, -0.6]", "[0.3]"), "home must give 2 finite positions"),
    ("good", GOOD + "effort_limits: {finger_joint: 3.0}\n", "'finger_joint' is not an arm joint"),
    ("no effort", GOOD, "'shoulder' has no effort limit; give effort_limits"),
    ("good", GOOD.replace("locked_joints: {finger_joint: 0.02}\n", ""), "list the others under locked_joints"),
    ("good", GOOD.replace("weld_frame: base\n", ""), "floating base (give weld_frame)"),
    ("good", GOOD.replace("weld_frame: base", "weld_frame: plate"), "weld_frame 'plate' is not a frame"),
    ("good", GOOD.replace("[shoulder, elbow]", "[elbow, shoulder]").replace("[0.3, -0.6]", "[0.0, 0.0]"),
     "list arm_joints in the model's order"),
    ("good", GOOD + "wheels: 4\n", "malformed robot config"),
    ("welded", GOOD, "cannot weld 'base' to the world, the model already fixes it there"),
    ("good", GOOD.replace("tool_frame: tool", "tool_frame: flange"), "tool_frame 'flange' is not a frame of two_link"),
    ("good", GOOD.replace("[0.3, -0.6]", "[0.3, -2.6]"), "home -2.6 of 'elbow' is outside its position limits [-2.5, 2.5]"),
])
def test_bad_robot_configs_are_one_line_errors(tmp_path, urdf, config, message):
    text = two_link_urdf(effort=urdf != "no effort")
    if urdf == "welded":     # as ROS descriptions ship: a world link and a fixed joint to the base
        text = text.replace("<robot name=\"two_link\">\n", "<robot name=\"two_link\">\n  <link name=\"world\"/>\n"
                            "  <joint name=\"world_joint\" type=\"fixed\"><parent link=\"world\"/><child link=\"base\"/>"
                            "</joint>\n")
    with pytest.raises(InputError, match=None) as error:
        make_plant(PlantConfig.continuous(), robot=load_robot(write_robot(tmp_path, text, config)))
    assert message in str(error.value) and "\n" not in str(error.value), str(error.value)


def collect_two_link(folder, num_steps: int):
    """Collect 6 excitation trajectories of the 2-joint arm; returns (robot config path, dataset path)."""
    from stdm_drake.cli import main
    robot = write_robot(folder, two_link_urdf(), GOOD)
    excitation = folder / "excitation.yaml"
    excitation.write_text(f"num_steps: {num_steps}\namplitude_max: [2.0, 1.0]\noffset_max: [1.0]\n"
                          "initial_position_lower: [-1.0, -1.5]\ninitial_position_upper: [1.0, 1.5]\n")
    data = folder / "data.h5"
    assert main(["collect", "--protocol", "excitation", "--robot", str(robot), "--config", str(excitation),
                 "--count", "6", "--workers", "1", "--quiet", "-o", str(data)]) == 0
    return robot, data


@pytest.mark.slow
def test_collect_train_evaluate_on_a_robot_brought_as_a_urdf(tmp_path, capsys):
    """The 2-joint arm through the excitation protocol, training and evaluation, with no code change."""
    from stdm_drake.cli import main
    from stdm_drake.data.dataset import load_dataset
    robot, data = collect_two_link(tmp_path, 30)
    dataset = load_dataset(data)
    assert dataset.trajectory(0).q.shape == (31, 2) and dataset.trajectory(0).tau.shape == (30, 2)
    assert dataset.metadata.robot_name == "two_link"
    assert dataset.metadata.joint_names == ["shoulder", "elbow"]
    assert dataset.metadata.record["excitation"]["offset_max"] == [1.0, 1.0]          # one value for both joints
    assert main(["inspect", str(data), "--robot", str(robot)]) == 0
    assert "shoulder" in capsys.readouterr().out
    from stdm_drake.robots.robot import UR10_CONFIG
    for command in (["inspect", str(data)], ["train", str(data), "-o", str(tmp_path / "x")]):
        assert main(command + ["--robot", str(UR10_CONFIG)]) == 2          # --robot checks the dataset's robot
        assert "collected with robot two_link" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
    assert main(["train", str(data), "--model", "DD", "--epochs", "3", "--train", "4", "--val", "1", "--quiet",
                 "-o", str(tmp_path / "dd")]) == 2     # nominal-acceleration inputs need the robot: the UR-10 refuses
    assert "collected with robot two_link" in capsys.readouterr().err
    assert main(["train", str(data), "--robot", str(robot), "--model", "DD", "--epochs", "3", "--train", "4",
                 "--val", "1", "--quiet", "-o", str(tmp_path / "dd")]) == 0
    assert main(["evaluate", str(tmp_path / "dd" / "seed0" / "checkpoint.pt"), str(data), "--robot", str(robot),
                 "--horizon", "10"]) == 0
    assert "one-step MSE" in capsys.readouterr().out


def test_a_checkpoint_refuses_a_dataset_of_another_robot(tmp_path, capsys, excitation_dataset):
    """The checkpoint records the robot of its training data; evaluating on another robot's data is a
    one-line error."""
    from stdm_drake.cli import main
    from stdm_drake.learning.checkpoint import load_checkpoint
    assert main(["train", str(excitation_dataset), "--model", "D", "--epochs", "1", "--train", "2", "--val", "1",
                 "--quiet", "-o", str(tmp_path / "ur10")]) == 0
    checkpoint = load_checkpoint(tmp_path / "ur10" / "seed0" / "checkpoint.pt")
    assert checkpoint.metadata.robot_name == "ur10" and len(checkpoint.metadata.joint_names) == 6
    robot = write_robot(tmp_path, two_link_urdf(), GOOD.replace("name: two_link", "name: ur10"))
    excitation = tmp_path / "excitation.yaml"
    excitation.write_text("num_steps: 10\namplitude_max: [1.0]\noffset_max: [0.5]\n"
                          "initial_position_lower: [-1.0]\ninitial_position_upper: [1.0]\n")
    assert main(["collect", "--protocol", "excitation", "--robot", str(robot), "--config", str(excitation),
                 "--count", "2", "--workers", "1", "--quiet", "-o", str(tmp_path / "other.h5")]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(tmp_path / "ur10" / "seed0" / "checkpoint.pt"), str(tmp_path / "other.h5"),
                 "--split", "all"]) == 2
    assert "state dim 12 and action dim 6, expected state dim 4 and action dim 2" in capsys.readouterr().err
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.learning.checkpoint import save_checkpoint
    other = save_checkpoint(tmp_path / "other.pt", checkpoint.model,
                            metadata=dict(robot_name="arm6", joint_names=[f"j{i}" for i in range(6)],
                                          structure=checkpoint.metadata.structure))
    with pytest.raises(InputError, match=r"trained on another robot .*\(joints differ: arm6 vs ur10\)"):
        load_checkpoint(other).check_fits(load_dataset(excitation_dataset))


@pytest.mark.slow
def test_mpc_and_view_run_on_a_robot_brought_as_a_urdf(tmp_path, capsys):
    """Closed-loop MPC (plant model and a learned model) and the Meshcat view on the 2-joint arm, with
    one-value MPC weights; the UR-10 default refuses its dataset."""
    from stdm_drake.cli import main
    robot, data = collect_two_link(tmp_path, 20)
    assert main(["train", str(data), "--robot", str(robot), "--model", "D", "--epochs", "5", "--train", "4",
                 "--val", "1", "--quiet", "-o", str(tmp_path / "d")]) == 0
    checkpoint = str(tmp_path / "d" / "seed0" / "checkpoint.pt")
    weights = tmp_path / "mpc.yaml"
    weights.write_text("horizon: 5\nposition_weight: [1.0e+4]\nvelocity_weight: [10.0]\neffort_weight: [1.0e-3]\n")
    code = main(["mpc", str(data), "--robot", str(robot), "--config", str(weights), "--model", f"D={checkpoint}",
                 "--plans", "1", "--excitation-references", "--quiet", "-o", str(tmp_path / "mpc")])
    rows = json.loads((tmp_path / "mpc" / "mpc.json").read_text())["summary"]
    assert code == closed_loop_status(rows)                  # a 5-epoch D may leave the limits: exit 2 then
    assert [row["model"] for row in rows] == ["plant", "D"] and rows[0]["limit_violations"] == 0
    assert rows[0]["q_mse_rad2"] < 1e-3                                  # the plant model tracks its own data
    assert main(["view", checkpoint, str(data), "--robot", str(robot), "--trajectories", "1",
                 "--html", str(tmp_path / "view.html")]) == 0
    assert (tmp_path / "view.html").stat().st_size > 1000
    capsys.readouterr()
    assert main(["mpc", str(data), "--model", f"D={checkpoint}", "--plans", "1", "--quiet",
                 "-o", str(tmp_path / "mpc_ur10")]) == 2
    assert "collected with robot two_link" in capsys.readouterr().err


def test_missing_visual_meshes_warn_and_the_dynamics_load(tmp_path, caplog):
    """A visual mesh that is not there is left out with a warning (the plant, its scene graph and a
    Meshcat recording still build); so is a missing collision mesh (the dynamics do not need it)."""
    from stdm_drake.robots.recorder import TrajectoryRecorder
    from pydrake.systems.framework import DiagramBuilder
    cylinder = '<cylinder radius="0.04" length="0.3"/>'
    text = two_link_urdf().replace(cylinder, '<mesh filename="meshes/upper.obj"/>', 2)
    with caplog.at_level("WARNING"):
        robot = load_robot(write_robot(tmp_path, text, GOOD))
        plant, scene_graph = make_plant(PlantConfig(), builder=DiagramBuilder(), robot=robot)
    assert plant.num_positions() == 2 and scene_graph is not None
    assert "visual meshes not found, loaded without them: meshes/upper.obj" in caplog.text
    recorder = TrajectoryRecorder(0.01, robot=robot)
    recorder.add(np.zeros((3, 2)))
    collision = text.replace("</visual>", "</visual><collision><geometry><mesh filename=\"meshes/c.obj\"/>"
                             "</geometry></collision>", 1)
    caplog.clear()
    with caplog.at_level("WARNING"):
        robot = load_robot(write_robot(tmp_path, collision, GOOD))
        make_plant(PlantConfig(), builder=DiagramBuilder(), robot=robot)
    assert "collision meshes not found, loaded without them (the self-collision check and contact leave them " \
           "out): meshes/c.obj" in caplog.text


def test_excitation_ranges_are_derived_for_a_robot_without_an_excitation_file(tmp_path):
    """Without --config, another robot's excitation ranges follow the UR-10's rule (0.5 rad/s^2 times the
    effective inertia at home; start poses home +-0.5 rad inside the limits); the data stay in limits."""
    from stdm_drake.cli import main
    from stdm_drake.data.dataset import load_dataset
    robot = write_robot(tmp_path, two_link_urdf(), GOOD)
    data = tmp_path / "data.h5"
    assert main(["collect", "--protocol", "excitation", "--robot", str(robot), "--count", "3", "--workers", "1",
                 "--quiet", "-o", str(data)]) == 0
    excitation = load_dataset(data).metadata.record["excitation"]
    assert excitation["initial_position_lower"] == pytest.approx([-0.2, -1.1])
    assert excitation["initial_position_upper"] == pytest.approx([0.8, -0.1])
    plant, _ = make_plant(PlantConfig.continuous(), robot=load_robot(robot))
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, np.array([0.3, -0.6]))
    np.testing.assert_allclose(excitation["amplitude_max"], 0.5 * np.diag(plant.CalcMassMatrix(context)))


def test_the_ur10_preset_named_with_robot_collects_the_default_data(tmp_path):
    """`--robot models/ur10.yaml` is the default robot: the same excitation file and the same data."""
    from stdm_drake.cli import main
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.robots.robot import UR10_CONFIG
    paths = [tmp_path / "default.h5", tmp_path / "named.h5"]
    for path, extra in zip(paths, ([], ["--robot", str(UR10_CONFIG)])):
        assert main(["collect", "--protocol", "excitation", "--count", "2", "--seed", "7", "--workers", "1",
                     "--quiet", "-o", str(path), *extra]) == 0
    default, named = (load_dataset(path) for path in paths)
    assert named.metadata.record["excitation"] == default.metadata.record["excitation"]
    np.testing.assert_array_equal(named.trajectory(1).tau, default.trajectory(1).tau)


def test_a_robot_that_does_not_load_fails_collect_in_one_line_before_any_worker(tmp_path, capsys):
    """Excitation collection with worker processes: the plant is built in the command's own process first,
    so a bad description is one line with exit status 2, not a traceback from each worker's initializer."""
    from stdm_drake.cli import main
    robot = write_robot(tmp_path, two_link_urdf(), GOOD.replace("tool_frame: tool", "tool_frame: flange"))
    code = main(["collect", "--protocol", "excitation", "--robot", str(robot), "--count", "4", "--workers", "2",
                 "--quiet", "-o", str(tmp_path / "data.h5")])
    err = capsys.readouterr().err
    assert code == 2 and "tool_frame 'flange' is not a frame" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "data.h5").exists()


def test_plant_model_jacobians_stay_exact_on_stiff_damped_joints(tmp_path):
    """Joint damping with a time constant under 1 ms against the 10 ms period (|A T| ~ 40): the plant
    model's discrete Jacobians (exact zero-order hold of the continuous linearization) agree with finite
    differences of its own discrete step, and the velocity block decays (a truncated series gave
    eigenvalues in the hundreds)."""
    from stdm_drake.dynamics.physics import PlantModel
    urdf = two_link_urdf().replace('<axis xyz="0 1 0"/>', '<axis xyz="0 1 0"/><dynamics damping="40.0"/>')
    robot = load_robot(write_robot(tmp_path, urdf, GOOD))
    model = PlantModel(0.01, robot=robot)
    x, u = np.array([[0.3, -0.6, 0.2, -0.1]]), np.array([[1.0, -0.5]])
    A, B = model.jacobians(x, u)
    numeric = np.empty((4, 6))
    for j in range(6):
        step = np.zeros(6)
        step[j] = 1e-5
        up, down = np.hstack([x, u])[0] + step, np.hstack([x, u])[0] - step
        numeric[:, j] = (model.step(up[None, :4], up[None, 4:]) - model.step(down[None, :4], down[None, 4:]))[0] / 2e-5
    assert np.max(np.abs(np.linalg.eigvals(A[0][2:, 2:]))) < 1.0
    # to the linearization's own error (it holds the gravity terms at x_k over the period): 0.07 here,
    # against entries in the thousands from a 4th-order series
    np.testing.assert_allclose(np.hstack([A[0], B[0]]), numeric, atol=0.1)


def test_a_missing_visual_mesh_beside_present_ones_is_left_out(tmp_path, caplog):
    """The model is re-parsed from text without the missing visual; the meshes that exist keep working
    (their paths are rewritten as file:// URIs, which Drake resolves when parsing from a string)."""
    from pydrake.systems.framework import DiagramBuilder
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "box.obj").write_text(
        "v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nv 0 0 0.05\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    cylinder = '<cylinder radius="0.04" length="0.3"/>'
    text = two_link_urdf().replace(cylinder, '<mesh filename="meshes/box.obj"/>', 1)
    text = text.replace(cylinder, '<mesh filename="meshes/gone.obj"/>', 1)
    with caplog.at_level("WARNING"):
        robot = load_robot(write_robot(tmp_path, text, GOOD))
        plant, scene_graph = make_plant(PlantConfig(), builder=DiagramBuilder(), robot=robot)
    assert plant.num_positions() == 2
    assert "loaded without them: meshes/gone.obj" in caplog.text and "box.obj" not in caplog.text
    inspector = scene_graph.model_inspector()
    meshes = [str(inspector.GetShape(geometry).source().path()) for geometry in inspector.GetAllGeometryIds()
              if type(inspector.GetShape(geometry)).__name__ == "Mesh"]
    assert meshes and all(name.endswith("box.obj") for name in meshes), meshes


def test_drakes_parser_warnings_are_shown_once_per_command(tmp_path, caplog, capsys):
    """A description with joint friction (which Drake's plant does not model) warns once, not once per
    joint and per plant the command builds; one line counts the repeats."""
    from stdm_drake.cli import main
    urdf = two_link_urdf().replace('<axis xyz="0 1 0"/>', '<axis xyz="0 1 0"/><dynamics friction="0.3"/>')
    robot = write_robot(tmp_path, urdf, GOOD)
    with caplog.at_level("WARNING", logger="drake"):
        assert main(["collect", "--protocol", "excitation", "--robot", str(robot), "--count", "2", "--workers", "1",
                     "--quiet", "-o", str(tmp_path / "data.h5")]) == 0
    for logger in ("drake", "stdm_drake.robots.robot"):   # Drake's own warning, and stdm-drake's what-it-means line
        friction = [record for record in caplog.records if record.name == logger and "friction" in record.getMessage()]
        assert len(friction) == 1, [record.getMessage() for record in friction]
    assert "repeats of Drake's warnings above left out" in capsys.readouterr().err


@pytest.mark.slow
def test_drakes_warnings_come_once_from_every_process(tmp_path):
    """With worker processes too, as a user runs it: each warning once on stderr (the workers leave them to the
    main process, which parses the same description), in one format."""
    import subprocess
    import sys
    urdf = two_link_urdf().replace('<axis xyz="0 1 0"/>', '<axis xyz="0 1 0"/><calibration rising="0.0"/>')
    robot = write_robot(tmp_path, urdf, GOOD)
    program = pathlib.Path(sys.executable).with_name("stdm-drake")
    result = subprocess.run([str(program), "collect", "--protocol", "excitation", "--robot",
                             str(robot), "--count", "4", "--workers", "2", "--quiet", "-o", str(tmp_path / "data.h5")],
                            capture_output=True, text=True, env=dict(os.environ, DRAKE_ALLOW_NETWORK="meshcat"),
                            timeout=300)
    assert result.returncode == 0, result.stderr
    warned = [line for line in result.stderr.splitlines() if "'calibration'" in line]
    assert len(warned) == 1 and warned[0].startswith("WARNING:drake:"), result.stderr


SDF = """<?xml version="1.0"?>
<sdf version="1.7"><model name="arm">
  <link name="base"/>
  <link name="upper"><inertial><mass>{mass}</mass><inertia><ixx>0.01</ixx><iyy>0.01</iyy><izz>0.005</izz></inertia>
  </inertial></link>
  <link name="tip"/>
  <joint name="shoulder" type="revolute"><parent>base</parent><child>upper</child>
    <axis><xyz>0 1 0</xyz><limit><lower>{lower}</lower><upper>1</upper><velocity>-1</velocity></limit></axis></joint>
  <joint name="tip_fixed" type="fixed"><parent>upper</parent><child>tip</child></joint>
</model></sdf>
"""


def test_an_sdf_description_is_checked_like_a_urdf(tmp_path):
    """The description checks read SDFormat too: its defaults (a link without <inertial> has 1 kg, a
    velocity limit below 0 is none) pass, a reversed limit and a negative mass are refused by name."""
    from stdm_drake.robots.description import check_description
    path = tmp_path / "arm.sdf"
    path.write_text(SDF.format(mass=2.0, lower=-1))
    check_description(path, "arm", ["shoulder"])
    path.write_text(SDF.format(mass=2.0, lower=2))
    with pytest.raises(InputError, match="arm joint 'shoulder' has its lower position limit 2 above its upper limit 1"):
        check_description(path, "arm", ["shoulder"])
    path.write_text(SDF.format(mass=-2.0, lower=-1))
    with pytest.raises(InputError, match="link 'upper' has mass -2 kg"):
        check_description(path, "arm", ["shoulder"])


def test_an_sdf_world_of_two_models_is_two_trees_not_a_loop(tmp_path):
    """SDFormat scopes names by model: two arms that both have links "base" and "upper" (a world of two models,
    and a model nested in another) are separate trees; a loop inside one model is still one."""
    from stdm_drake.robots.description import check_description, read_description
    model = SDF.format(mass=2.0, lower=-1).split("<sdf version=\"1.7\">")[1].split("</sdf>")[0]
    world = f'<?xml version="1.0"?><sdf version="1.7"><world name="w">{model}{model.replace("arm", "arm2", 1)}</world></sdf>'
    path = tmp_path / "world.sdf"
    path.write_text(world)
    description = check_description(path, "two", ["arm::shoulder"])
    assert sorted(description.links) == ["arm2::base", "arm2::tip", "arm2::upper", "arm::base", "arm::tip", "arm::upper"]
    assert {(joint.name, joint.parent, joint.child) for joint in description.joints if "shoulder" in joint.name} == {
        ("arm::shoulder", "arm::base", "arm::upper"), ("arm2::shoulder", "arm2::base", "arm2::upper")}
    nested = SDF.format(mass=2.0, lower=-1).replace("</model></sdf>", model.replace("arm", "hand", 1) + "</model></sdf>")
    path.write_text(nested)
    assert "hand::upper" in read_description(path).links and "upper" in read_description(path).links
    path.write_text(world.replace('<joint name="tip_fixed" type="fixed"><parent>upper</parent>',
                                  '<joint name="tip_fixed" type="fixed"><parent>tip</parent>', 1)
                    .replace("<child>tip</child>", "<child>upper</child>", 1))
    with pytest.raises(InputError, match="link 'arm::upper' is the child of joints 'arm::shoulder' and 'arm::tip_fixed'"):
        check_description(path, "two", ["arm::shoulder"])


def test_what_drakes_parser_reads_as_written_passes_the_one_reading_checks(tmp_path):
    """Held-out run 24's rules refuse a value whose text Drake's parser reads otherwise (split by a comment or CDATA
    section) and a joint's element stated twice with other content; what reads the same both ways loads: a value in
    one CDATA section, a comment before or after the value or between elements (as SDFormat reads them, measured), the
    same <axis> twice (a published quadruped)."""
    from stdm_drake.robots.description import read_description
    path = tmp_path / "arm.sdf"
    for mass in ("<![CDATA[2.0]]>", "2.0<!-- kg -->", "<!-- kg -->2.0", "<!-- a --><![CDATA[2.0]]>",
                 "\n  <!-- measured -->\n  2.0\n"):
        path.write_text(SDF.format(mass=mass, lower=-1).replace("<link name=\"tip\"/>", "<!-- a tip --><link name=\"tip\"/>"))
        assert read_description(path).links["upper"].mass == 2.0, mass
    path.write_text(SDF.format(mass=2.0, lower=-1).replace("<xyz>0 1 0</xyz>", "<xyz>0 1 0</xyz><xyz> 0 1.0 0 </xyz>"))
    read_description(path)
    urdf = tmp_path / "arm.urdf"
    urdf.write_text('<robot name="r"><link name="a"/><link name="b"><inertial><mass value="1"/><inertia ixx="0.1" '
                    'iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial></link><joint name="j" type="revolute">'
                    '<parent link="a"/><child link="b"/><axis xyz="0 0 1"/><axis xyz="0 0 1 "/><limit lower="-1" '
                    'upper="1" effort="1" velocity="1"/></joint></robot>')
    assert [joint.name for joint in read_description(urdf).joints] == ["j"]
    # (held-out run 26: equal in meaning, refused as differing) an attribute left at its default, a boolean as 1/0
    urdf.write_text(urdf.read_text().replace('<axis xyz="0 0 1 "/>', '').replace(
        '<axis xyz="0 0 1"/>', '<origin xyz="0 0 0.2" rpy="0 0 0"/><origin xyz="0 0 0.2"/><axis xyz="0 0 1"/>'))
    assert [joint.name for joint in read_description(urdf).joints] == ["j"]
    path.write_text(SDF.format(mass=2.0, lower=-1).replace("<link name=\"tip\"/>", "<link name=\"tip\"><gravity>true"
                                                           "</gravity><gravity>1</gravity></link>"))
    read_description(path)
    # (held-out run 27: a material and a reference to it by name say the same; an SDF material's doubled colour not)
    visual = ('<visual><geometry><box size="1 1 1"/></geometry><material name="grey"><color rgba="0.2 0.2 0.2 1"/>'
              '</material><material name="grey"/></visual>')
    urdf.write_text(urdf.read_text().replace('<link name="b">', f'<link name="b">{visual}'))
    assert [joint.name for joint in read_description(urdf).joints] == ["j"]
    path.write_text(SDF.format(mass=2.0, lower=-1).replace("<link name=\"tip\"/>", "<link name=\"tip\"><visual name="
                                                           "\"v\"><geometry><box><size>1 1 1</size></box></geometry>"
                                                           "<material><ambient>1 0 0 1</ambient><ambient>0 1 0 1</ambient>"
                                                           "</material></visual></link>"))
    with pytest.raises(InputError, match="its <material> states 2 <ambient> elements that differ"):
        read_description(path)
    # (a <limit> without lower and upper is unbounded to Drake, not the specification's 0: it differs from one of 0)
    unbounded = urdf.read_text()
    urdf.write_text(unbounded.replace('<limit lower="-1" upper="1" effort="1" velocity="1"/>',
                                      '<limit effort="1" velocity="1"/><limit lower="0" upper="0" effort="1" '
                                      'velocity="1"/>'))
    with pytest.raises(InputError, match="it states 2 <limit> elements that differ"):
        read_description(urdf)
    urdf.write_text(unbounded.replace('<origin xyz="0 0 0.2"/>', '<origin xyz="0 0 0.3"/>'))
    with pytest.raises(InputError, match="joint 'j': it states 2 <origin> elements that differ"):
        read_description(urdf)
    for split in ("2<!-- -->.0", "<!-- kg -->2<!-- -->.0", "2.<![CDATA[0]]>", "<![CDATA[2]]>.0", "<?x?>2.0",
                  "<![CDATA[ ]]>2.0"):
        path.write_text(SDF.format(mass=split, lower=-1))
        with pytest.raises(InputError, match="the text of <mass> .* is split by"):
            read_description(path)
    path.write_text("\n\n" + SDF.format(mass="2<!-- -->.0", lower=-1))   # (the line counts blank lines before the file)
    with pytest.raises(InputError, match=r"the text of <mass> \(line 6\) is split by a comment: '2.0' to these checks, "
                                         "'2' to Drake's parser"):
        read_description(path)


def test_a_long_chain_of_frames_is_checked_in_one_pass(tmp_path):
    """The tree check walks each link once: a chain of 4,900 massless frames (9,799 links and joints, within the
    budget of 10,000) is checked in a few hundredths of a second, where walking up from every link took about 3 s
    (10,000 frames: 12 s); a cycle at its end is still found."""
    import time
    from stdm_drake.robots.description import check_tree, read_description
    count = 4_900
    links = "".join(f'<link name="l{index}"/>' for index in range(count))
    joints = "".join(f'<joint name="j{index}" type="fixed"><parent link="l{index}"/><child link="l{index + 1}"/></joint>'
                     for index in range(count - 1))
    path = tmp_path / "chain.urdf"
    path.write_text(f'<robot name="chain">{links}{joints}</robot>')
    description = read_description(path)
    started = time.perf_counter()
    check_tree(description, "chain")
    assert time.perf_counter() - started < 1.5   # (a bound against a quadratic walk, not a benchmark: 0.02 s here)
    path.write_text(f'<robot name="chain">{links}{joints}<joint name="back" type="fixed"><parent link="l{count - 1}"/>'
                    '<child link="l0"/></joint></robot>')
    with pytest.raises(InputError, match="form a cycle through link"):
        check_tree(read_description(path), "chain")


def test_a_recipe_path_outside_the_checkout_names_the_shipped_file(tmp_path, monkeypatch, capsys):
    """`--robot models/panda.yaml` run from another folder: the one-line error names `stdm-drake:models/panda.yaml`;
    a path that is no shipped file gets no hint."""
    from stdm_drake.cli import main
    from stdm_drake.paths import shipped_hint
    monkeypatch.chdir(tmp_path)
    assert main(["collect", "--protocol", "tracking", "--count", "1", "--robot", "models/panda.yaml",
                 "-o", str(tmp_path / "x.h5")]) == 2
    assert "robot config not found: models/panda.yaml (the shipped one is stdm-drake:models/panda.yaml)" in \
        capsys.readouterr().err
    assert shipped_hint("controllers/pid_dither.yaml") == " (the shipped one is stdm-drake:controllers/pid_dither.yaml)"
    assert shipped_hint("controllers/mine.yaml") == "" and shipped_hint("elsewhere/pid_dither.yaml") == ""


def test_blank_lines_before_the_xml_declaration_are_read_as_drake_reads_them(tmp_path):
    """pybullet's biped2d_pybullet.urdf starts with blank lines before `<?xml ...?>`: Drake's parser (TinyXML2)
    reads past them, Python's (expat) refused the file as not well-formed. Now read as Drake reads it; a fault
    further down is still named at its line in the file."""
    from stdm_drake.robots.description import read_description
    text = (pathlib.Path(__file__).resolve().parent.parent / "models/ur10.urdf").read_text()
    path = tmp_path / "blank.urdf"
    path.write_text("\n \n\t\n" + text)
    assert "shoulder_pan_joint" in {joint.name for joint in read_description(path).joints}
    broken = text.replace("</robot>", "<link></robot>")
    path.write_text("\n\n\n" + broken)
    line = broken[:broken.index("</robot>")].count("\n") + 1 + 3   # (the line of the unclosed tag's end)
    with pytest.raises(InputError, match=rf"not well-formed XML \(mismatched tag: line {line}, "):
        read_description(path)


def test_robot_init_of_a_world_of_two_welded_arms_says_it_takes_one(tmp_path, capsys):
    """Two arms welded to the world's link: robot init names the two moving branches and says it takes one arm (it
    said "no movable joint on a chain", as if nothing moved: held-out run 18's note)."""
    from stdm_drake.cli import main
    model = SDF.format(mass=2.0, lower=-1).split("<sdf version=\"1.7\">")[1].split("</sdf>")[0]
    welded = model.replace('<link name="base"/>', '<link name="base"/><joint name="weld" type="fixed"><parent>world'
                           '</parent><child>base</child></joint>', 1)
    assert welded != model
    path = tmp_path / "world.sdf"
    path.write_text(f'<?xml version="1.0"?><sdf version="1.7"><world name="w">{welded}'
                    f'{welded.replace("arm", "arm2", 1)}</world></sdf>')
    capsys.readouterr()
    assert main(["robot", "init", str(path), "-o", str(tmp_path / "r.yaml")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "branches into 2 moving chains (arm::weld, arm2::weld); robot init takes one arm" in lines[0]
    assert not (tmp_path / "r.yaml").exists()


def test_an_element_under_a_prefix_no_xmlns_declares_is_read_as_drake_reads_it(tmp_path):
    """Drake's parser (TinyXML2) reads names as written, so `<gazebo:plugin/>` or an undeclared `drake:` tag is no
    error to it; the toolbox's own reading refused such a file with a traceback ("unbound prefix": held-out run 19).
    Now it loads, and a Drake tag's value is checked under its written name."""
    from stdm_drake.cli import main
    from stdm_drake.paths import MODELS_DIR
    text = (MODELS_DIR / "ur10.urdf").read_text().replace("</robot>", "<gazebo:plugin name='x'/></robot>")
    (tmp_path / "ur10.urdf").write_text(text)
    assert main(["robot", "init", str(tmp_path / "ur10.urdf"), "-o", str(tmp_path / "ur10.yaml")]) == 0
    assert (tmp_path / "ur10.yaml").is_file()


def test_an_sdf_include_is_read_with_the_same_checks(tmp_path, capsys):
    """A link of -7.1 kg in a model an SDF includes (a model folder, or a file:// URI) is refused in one line naming
    the included file, before Drake parses it (Drake's several-line warnings came first: held-out run 19's
    S-include)."""
    from stdm_drake.cli import main
    from stdm_drake.robots.description import read_description
    model = SDF.format(mass=2.0, lower=-1)
    (tmp_path / "child").mkdir()
    (tmp_path / "child" / "model.config").write_text('<?xml version="1.0"?><model><name>child</name>'
                                                     '<sdf version="1.7">model.sdf</sdf></model>')
    (tmp_path / "child" / "model.sdf").write_text(model.replace("<mass>2.0</mass>", "<mass>-7.1</mass>", 1))
    for uri in ("child", f"file://{tmp_path / 'child' / 'model.sdf'}"):
        (tmp_path / "r.sdf").write_text(model.replace("</model></sdf>", f"<include><uri>{uri}</uri><name>ch</name>"
                                                                        "</include></model></sdf>"))
        capsys.readouterr()
        assert main(["robot", "init", str(tmp_path / "r.sdf"), "-o", str(tmp_path / "r.yaml")]) == 2
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1 and "r.sdf: its included model.sdf: link 'upper' has mass -7.1 kg" in lines[0], lines
        assert not (tmp_path / "r.yaml").exists()
    (tmp_path / "child" / "model.sdf").write_text(model)   # the included model's own links are Drake's to scope
    assert "ch::upper" not in read_description(tmp_path / "r.sdf").links


def test_a_link_mass_drake_would_divide_into_inf_is_refused():
    """(held-out run 22) A mass between 0 and the smallest normal double, or one whose inertia divided by it overflows
    (Drake's plant holds inertia per unit mass: inf, simulated without a word), is one line; a tiny mass whose
    inertia per unit mass is finite is Drake's to take."""
    from stdm_drake.robots.description import Inertial, check_inertial
    with pytest.raises(InputError, match=r"a mass is 0 \(a massless frame\) or at least 2.23e-308 kg$"):
        check_inertial(Inertial(2e-320, np.zeros((3, 3))), "link 'x'")
    # with moments, the least mass that keeps them within a body's reach, which the plant's check asks next (held-out
    # run 42: 2.23e-308 kg typed back was refused there; the battery types a description's advice back whole)
    with pytest.raises(InputError, match=r"a mass is 0 \(a massless frame\) or at least 1e-06 kg \(its largest "
                                         r"principal moment 0.01 kg m² within mass x \(100 m\)², as far as a body "
                                         r"reaches\)$"):
        check_inertial(Inertial(2e-320, np.diag([0.01] * 3)), "link 'x'")
    check_inertial(Inertial(1e-6, np.diag([0.01] * 3)), "link 'x'")
    with pytest.raises(InputError, match="per unit mass they overflow a double"):
        check_inertial(Inertial(3e-308, np.diag([10.0] * 3)), "link 'x'")
    check_inertial(Inertial(1e-300, np.diag([0.01] * 3)), "link 'x'")


def test_robot_check_lines_carry_their_units():
    """The newcomer pass: `robot check`'s per-joint lines gave numbers without units; a revolute joint's are rad,
    rad/s, N m and kg m² (a prismatic one's m, m/s, N and kg)."""
    from stdm_drake.robots.starting_config import check_robot
    from presets import UR10
    lines = check_robot(UR10)
    assert lines[1].startswith("shoulder_lift_joint: range [-6.283, 6.283] rad, velocity 2.094 rad/s, home -1.2 rad, "
                               "gravity at home 68.9 N m, effective inertia 4.44 kg m²")
