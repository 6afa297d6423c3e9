"""The robots shipped beside the UR-10: the 7-joint Franka Emika Panda (models/panda.yaml) through every
command, and the Acrobot from the drake wheel (models/acrobot.yaml, underactuated) through excitation,
training and evaluation, with tracking and MPC refused."""
import dataclasses
import json

import numpy as np
import pytest
from conftest import closed_loop_status

from stdm_drake.errors import InputError
from stdm_drake.robots.effects import load_plant_effects
from stdm_drake.paths import MODELS_DIR
from stdm_drake.robots.plant import Dynamics, PlantConfig, SelfCollisionChecker, joint_limits, make_plant
from presets import UR10
from stdm_drake.robots.robot import load_robot

PANDA_CONFIG = MODELS_DIR / "panda.yaml"
ACROBOT_CONFIG = MODELS_DIR / "acrobot.yaml"


@pytest.fixture(scope="module")
def panda():
    return load_robot(PANDA_CONFIG)


@pytest.fixture(scope="module")
def acrobot():
    return load_robot(ACROBOT_CONFIG)


def modified_dh(a: float, d: float, alpha: float, theta: float) -> np.ndarray:
    """Craig's link transform: Rot_x(alpha) Trans_x(a) Rot_z(theta) Trans_z(d)."""
    ca, sa, ct, st = np.cos(alpha), np.sin(alpha), np.cos(theta), np.sin(theta)
    return np.array([[ct, -st, 0, a], [st * ca, ct * ca, -sa, -sa * d], [st * sa, ct * sa, ca, ca * d], [0, 0, 0, 1]])


def test_panda_file_is_the_published_arm(panda):
    from tools_import import generate_panda_urdf
    assert panda.model_path.read_text() == generate_panda_urdf.urdf_text()   # written by its generator
    plant, _ = make_plant(PlantConfig.continuous(), robot=panda)
    limits = joint_limits(plant)
    assert panda.num_joints == 7 and panda.action_dim == 7
    np.testing.assert_array_equal(limits.position_upper, [2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])
    np.testing.assert_array_equal(limits.velocity, [2.175] * 4 + [2.61] * 3)
    np.testing.assert_array_equal(limits.effort, [87.0] * 4 + [12.0] * 3)
    # Franka's modified DH table, flange 0.107 m along link 7's z axis
    dh = [(0.0, 0.333, 0.0), (0.0, 0.0, -np.pi / 2), (0.0, 0.316, np.pi / 2), (0.0825, 0.0, np.pi / 2),
          (-0.0825, 0.384, -np.pi / 2), (0.0, 0.0, np.pi / 2), (0.088, 0.0, np.pi / 2)]
    context = plant.CreateDefaultContext()
    for q in np.random.default_rng(0).uniform(limits.position_lower, limits.position_upper, size=(5, 7)):
        X = np.eye(4)
        for (a, d, alpha), theta in zip(dh, q):
            X = X @ modified_dh(a, d, alpha, theta)
        X = X @ modified_dh(0.0, 0.107, 0.0, 0.0)
        plant.SetPositions(context, q)
        flange = plant.CalcRelativeTransform(context, plant.world_frame(), plant.GetFrameByName("panda_link8"))
        np.testing.assert_allclose(flange.GetAsMatrix4(), X, atol=1e-9)
    assert SelfCollisionChecker(panda).is_collision_free(panda.home)
    gravity = Dynamics(panda).gravity_torque(panda.home)
    assert np.all(np.abs(gravity) < 0.3 * limits.effort)   # the arm holds itself at home with margin


def test_redundant_arm_plans_have_exact_derivatives(panda):
    """A 7-joint arm's quintic plan: the tool follows the line, the redundant joint moves linearly along
    it, and q̇, q̈ are the derivatives of q; ruckig and toppra end in the same configuration."""
    from stdm_drake.robots.kinematics import RobotKinematics, rotation_log
    from stdm_drake.collection.plan import derived_tracking_spec, initial_configuration, sample_final_pose
    from stdm_drake.collection.planners import plan_trajectory

    spec = derived_tracking_spec(panda)
    sampling, planner = spec.sampling, spec.planner
    kinematics = RobotKinematics(robot=panda)
    assert len(kinematics.redundant_joints) == 1
    (r,) = kinematics.redundant_joints
    q0 = initial_configuration(kinematics, sampling.initial_poses[1], planner)
    X_goal = sample_final_pose(kinematics.tool_pose(q0), sampling, np.random.default_rng(3))
    plan = plan_trajectory(kinematics, q0, X_goal, config=planner, num_steps=100, sample_period=0.01)
    moving = plan.t < plan.duration
    assert np.ptp(plan.q[:, r]) > 1e-3                                   # the redundant joint moves...
    progress = (plan.q[:, r] - q0[r]) / (plan.q_goal[r] - q0[r])
    X_start = kinematics.tool_pose(q0)
    for k in np.flatnonzero(moving)[::10]:                               # ...in step with the tool on the line
        X = kinematics.tool_pose(plan.q[k])
        s = progress[k]
        expected = X_start.translation() + s * (X_goal.translation() - X_start.translation())
        np.testing.assert_allclose(X.translation(), expected, atol=1e-9)
    assert np.linalg.norm(rotation_log(kinematics.tool_pose(plan.q_goal).rotation().matrix()
                                       @ X_goal.rotation().matrix().T)) < 1e-9
    # derivatives: evaluate() is exact, so central differences at 1e-5 s agree to O(h^2)
    h = 1e-5
    for time in (0.2, 0.5, 0.8):
        q_minus, qd_minus, _ = plan.evaluate(time - h)
        q_plus, qd_plus, _ = plan.evaluate(time + h)
        _, qd, qdd = plan.evaluate(time)
        np.testing.assert_allclose((q_plus - q_minus) / (2 * h), qd, atol=1e-6)
        np.testing.assert_allclose((qd_plus - qd_minus) / (2 * h), qdd, atol=1e-4)
    for kind in ("ruckig", "toppra"):
        other = plan_trajectory(kinematics, q0, X_goal, config=planner.as_kind(kind),
                                num_steps=100, sample_period=0.01)
        np.testing.assert_allclose(other.q_goal, plan.q_goal, atol=1e-9)


def test_derived_tracking_spec_starts_at_home_within_reach(panda):
    from stdm_drake.collection.plan import derived_tracking_spec
    spec = derived_tracking_spec(panda)
    sampling, planner = spec.sampling, spec.planner
    assert len(sampling.initial_poses) == 4 and sampling.initial_poses[0].q_seed == panda.home.tolist()
    seeds = np.array([pose.q_seed for pose in sampling.initial_poses])
    assert np.all(np.abs(seeds - panda.home) <= 0.3)
    assert len(planner.acceleration_limits) == 7 and max(planner.acceleration_limits) <= 5.0
    assert 0.05 < sampling.position_offset[0] < 0.15                     # a tenth of the Panda's reach


def test_mpc_weights_for_other_robots_follow_the_ur10_fit():
    """A robot without an MPC file (the Panda, the Acrobot) gets the effort weights of the power law fitted
    here, by log-log least squares, to controllers/mpc.yaml's hand-tuned UR-10 weights against the UR-10's
    effective inertias at home (to the 3 % the rounded law leaves); that fit reproduces every UR-10 weight
    within a factor of 2.2."""
    from stdm_drake.closed_loop.mpc import load_mpc_config, mpc_config_for
    tuned = np.array(load_mpc_config().effort_weight)
    assert len(tuned) == UR10.num_joints and mpc_config_for(UR10).effort_weight == tuned.tolist()
    exponent, log_scale = np.polyfit(np.log(Dynamics(UR10).effective_inertia(UR10.home)), np.log(tuned), 1)
    fitted_ur10 = np.exp(log_scale) * Dynamics(UR10).effective_inertia(UR10.home) ** exponent
    assert np.all(np.abs(np.log(fitted_ur10 / tuned)) < np.log(2.2)), fitted_ur10 / tuned
    for config in (PANDA_CONFIG, ACROBOT_CONFIG):
        robot = load_robot(config)
        assert robot.default_file("mpc") is None                       # no file of its own: derived
        derived = np.array(mpc_config_for(robot).effort_weight)
        fitted = np.exp(log_scale) * Dynamics(robot).effective_inertia(robot.home) ** exponent
        np.testing.assert_allclose(derived, fitted, rtol=0.03, err_msg=robot.name)


@pytest.mark.slow
def test_panda_collect_train_evaluate_mpc_view(tmp_path, capsys, panda):
    """The 7-joint arm through every command with only its robot config: derived tracking poses,
    the default controller (one gain for every joint), derived MPC weights."""
    from stdm_drake.cli import main
    from stdm_drake.data.dataset import load_dataset

    data = tmp_path / "panda.h5"
    robot = str(PANDA_CONFIG)
    assert main(["collect", "--robot", robot, "--count", "12", "--workers", "1", "--quiet", "-o", str(data)]) == 0
    dataset = load_dataset(data)
    assert dataset.trajectory(0).q.shape == (101, 7) and dataset.trajectory(0).tau.shape == (100, 7)
    assert dataset.metadata.record["controller"]["kp"] == [225.0] * 7          # recorded per joint
    assert len(dataset.metadata.record["task_space_sampling"]["initial_poses"]) == 4
    assert main(["inspect", str(data), "--robot", robot]) == 0
    summary = capsys.readouterr().out
    true_q_mse = float(summary.split("true            q ")[1].split()[0])
    assert "tracking error (MSE against the plan)" in summary and "UR-10" not in summary   # (the paper's arm: the UR-10)
    assert true_q_mse < 1e-5                                             # it tracks its plans
    assert main(["train", str(data), "--robot", robot, "--model", "DD", "--epochs", "3", "--train", "1", "--val", "1",
                 "--test", "1", "--quiet", "-o", str(tmp_path / "dd")]) == 0
    checkpoint = str(tmp_path / "dd" / "seed0" / "checkpoint.pt")
    assert main(["evaluate", checkpoint, str(data), "--robot", robot, "--horizon", "10"]) == 0
    code = main(["mpc", str(data), "--robot", robot, "--model", f"DD={checkpoint}", "--plans", "1", "--quiet",
                 "-o", str(tmp_path / "mpc")])
    summary = json.loads((tmp_path / "mpc" / "mpc.json").read_text())["summary"]
    assert code == closed_loop_status(summary)               # a few-epoch DD may leave the limits: exit 2 then
    rows = {row["model"]: row for row in summary}
    assert rows["plant"]["q_mse_rad2"] < 1e-6 and rows["plant"]["limit_violations"] == 0
    from stdm_drake.learning.checkpoint import load_checkpoint
    from stdm_drake.learning.learned_model import trained_name
    named = trained_name(load_checkpoint(checkpoint))   # ("DD-naive" where its alpha grid kept naive training)
    assert named in ("DD", "DD-naive") and np.isfinite(rows[named]["q_mse_rad2"])
    assert main(["view", checkpoint, str(data), "--robot", robot, "--trajectories", "1",
                 "--html", str(tmp_path / "view.html")]) == 0
    assert (tmp_path / "view.html").stat().st_size > 1000
    capsys.readouterr()
    assert main(["mpc", str(data), "--robot", "stdm-drake:models/ur10.yaml", "--plans", "1", "--quiet",
                 "-o", str(tmp_path / "mpc_ur10")]) == 2
    assert "collected with robot panda" in capsys.readouterr().err      # another robot is refused
    from stdm_drake.data.compatibility import shipped_preset_of
    from stdm_drake.data.dataset import load_dataset
    assert shipped_preset_of(load_dataset(data)).name == "panda.yaml"  # without --robot: the preset it records


@pytest.mark.slow
def test_acrobot_excitation_train_evaluate_and_refusals(tmp_path, capsys, acrobot):
    """The underactuated Acrobot: one torque (the elbow's) per step, the shoulder swinging free;
    tracking and MPC refuse it in one line before any work."""
    from stdm_drake.cli import main
    from stdm_drake.data.dataset import load_dataset

    assert acrobot.joint_names == ("shoulder", "elbow") and acrobot.actuated_joint_names == ("elbow",)
    plant, _ = make_plant(PlantConfig.continuous(), robot=acrobot)
    assert plant.num_actuators() == 1 and joint_limits(plant).effort.tolist() == [20.0]
    data = tmp_path / "acrobot.h5"
    robot = str(ACROBOT_CONFIG)
    assert main(["collect", "--robot", robot, "--protocol", "excitation", "--count", "6", "--workers", "1",
                 "--quiet", "-o", str(data)]) == 0
    dataset = load_dataset(data)
    traj = dataset.trajectory(0)
    assert traj.q.shape == (51, 2) and traj.tau.shape == (50, 1) and traj.tau_next.shape == (1,)
    assert np.ptp(traj.q_true[:, 0]) > 0.01                          # the free shoulder swings
    dynamics = Dynamics(acrobot)   # the recorded accelerations are the plant's under the elbow torque alone
    np.testing.assert_allclose(dynamics.acceleration(traj.q_true[3], traj.v_true[3], traj.tau[3]),
                               traj.qdd[3], rtol=1e-9, atol=1e-9)
    assert main(["inspect", str(data), "--robot", robot]) == 0
    assert "(none)" in capsys.readouterr().out                          # no torque column for the shoulder
    assert main(["train", str(data), "--robot", robot, "--model", "DD", "--epochs", "3", "--train", "4", "--val", "1",
                 "--quiet", "-o", str(tmp_path / "dd")]) == 0
    checkpoint = str(tmp_path / "dd" / "seed0" / "checkpoint.pt")
    assert main(["evaluate", checkpoint, str(data), "--robot", robot, "--horizon", "10"]) == 0
    assert main(["view", checkpoint, str(data), "--robot", robot, "--trajectories", "1",
                 "--html", str(tmp_path / "view.html")]) == 0
    capsys.readouterr()
    for command in (["collect", "--robot", robot, "-o", str(tmp_path / "tracking.h5")],
                    ["mpc", str(data), "--robot", robot, "-o", str(tmp_path / "mpc")]):
        assert main(command) == 2
        error = capsys.readouterr().err
        assert "acrobot is underactuated (shoulder without an actuator)" in error and error.count("\n") == 1
    assert not (tmp_path / "tracking.h5").exists() and not (tmp_path / "mpc").exists()


def test_robot_config_underactuation_and_model_package_errors(tmp_path):
    text = ACROBOT_CONFIG.read_text()
    for replace, message in (
            (("unactuated_joints: [shoulder]", "unactuated_joints: [wrist]"), "unactuated_joints must list distinct arm"),
            (("unactuated_joints: [shoulder]", "unactuated_joints: [shoulder, elbow]"), "every arm joint is unactuated"),
            (("package://drake/", "package://nowhere/"), "unknown package 'nowhere'"),
            (("effort_limits: {elbow: 20.0}", ""), "'elbow' has no effort limit"),
            (("velocity_limits: {shoulder: 10.0, elbow: 10.0}", ""), "'shoulder' has no velocity limit")):
        path = tmp_path / "robot.yaml"
        path.write_text(text.replace(*replace))
        with pytest.raises(InputError) as error:
            make_plant(PlantConfig.continuous(), robot=load_robot(path))
        assert message in str(error.value) and "\n" not in str(error.value), str(error.value)


def test_actuators_follow_the_arm_order_when_the_file_gives_only_some(tmp_path):
    """A file with a <transmission> on the elbow only: the shoulder's actuator is created, and the
    action's order (the actuation port's) is still shoulder, elbow."""
    from test_robot_config import GOOD, two_link_urdf, write_robot
    transmission = ('<transmission name="elbow_trans"><type>transmission_interface/SimpleTransmission</type>'
                    '<joint name="elbow"><hardwareInterface>hardware_interface/EffortJointInterface'
                    '</hardwareInterface></joint><actuator name="elbow_motor"/></transmission>\n</robot>')
    robot = load_robot(write_robot(tmp_path, two_link_urdf().replace("</robot>", transmission), GOOD))
    plant, _ = make_plant(PlantConfig.continuous(), robot=robot)
    names = [plant.get_joint_actuator(index).joint().name() for index in plant.GetJointActuatorIndices()]
    assert names == ["shoulder", "elbow"]
    np.testing.assert_array_equal(joint_limits(plant).effort, [40.0, 20.0])
    np.testing.assert_array_equal(plant.MakeActuationMatrix(), np.eye(2))


@pytest.mark.slow
def test_pid_gains_sized_from_the_effective_inertia(tmp_path, panda):
    """controllers/pid_sized.yaml gives the UR-10 gains close to pid.yaml's hand-set ones, and tracks
    the Panda's plans with no per-robot tuning; a file with both gains and a bandwidth is refused."""
    from stdm_drake.cli import main
    from stdm_drake.collection.collect import collection_request
    from stdm_drake.robots.control import load_controller_config
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.paths import CONTROLLERS_DIR
    hand_set = load_controller_config(CONTROLLERS_DIR / "pid.yaml")
    sized = dataclasses.replace(load_controller_config(CONTROLLERS_DIR / "pid_sized.yaml"),
                                bandwidth=[25.0] * 3 + [35.0] * 3).for_robot(UR10)
    for name in ("kp", "ki", "kd"):
        ratio = np.array(getattr(sized, name)) / np.array(getattr(hand_set, name))
        assert np.all((ratio > 0.6) & (ratio < 1.1)), (name, ratio)
    request = collection_request("tracking", count=4, robot=panda, controller=CONTROLLERS_DIR / "pid_dither_sized.yaml")
    assert len(request.settings.controller.kp) == 7 and min(request.settings.controller.dither_std) > 0
    data = tmp_path / "pid.h5"
    assert main(["collect", "--robot", str(PANDA_CONFIG), "--controller", str(CONTROLLERS_DIR / "pid_sized.yaml"),
                 "--count", "4", "--workers", "1", "--quiet", "-o", str(data)]) == 0
    traj = load_dataset(data).trajectory(0)
    assert np.mean((traj.q_true - traj.q_planned) ** 2) < 1e-4
    both = tmp_path / "both.yaml"
    both.write_text("controller: !Pid\n  kp: [100.0]\n  bandwidth: [25.0]\n")
    with pytest.raises(InputError, match="give kp, ki, kd or bandwidth, not both"):
        collection_request("tracking", count=1, robot=panda, controller=both)


@pytest.mark.slow
def test_reproduce_quick_on_the_affected_panda(tmp_path, capsys, monkeypatch):
    """`reproduce --quick --robot panda --plant-effects`: every stage on the 7-joint arm with its derived
    protocols, on the plant with models/panda_effects.yaml (the MPC with the nominal and the true plant). The
    underactuated Acrobot is refused before any work. The stages run at a smaller size than the quick profile's
    (fewer trajectories, epochs and sine-sum networks): the robot's path through every stage is what this test
    checks; the quick profile's own size runs in the README's main job (tests/test_reproduce.py)."""
    from stdm_drake.cli import main
    from stdm_drake.commands import reproduce as reproduce_command
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.experiments import sine_sum
    from stdm_drake.experiments.jobs import QUICK
    monkeypatch.setattr(reproduce_command, "QUICK", dataclasses.replace(
        QUICK, excitation_count=12, tracking_count=20, sim_train_sizes=(2, 4), sim_val=2, sim_test=4, real_val=1,
        real_test=2, max_epochs=4, patience=4, horizon=20, default_model_seeds=2,
        default_model_epochs=4))
    monkeypatch.setattr(sine_sum, "QUICK", dataclasses.replace(sine_sum.QUICK, seeds=2, headline_seeds=2, epochs=200,
                                                               table_seeds=2))
    out = tmp_path / "reproduce"
    code = main(["reproduce", "--quick", "--robot", str(PANDA_CONFIG), "--quiet", "--plant-effects",
                 str(MODELS_DIR / "panda_effects.yaml"), "-o", str(out)])
    # the quick profile's models (25 epochs) may leave the Panda's limits in MPC: the report is written and
    # the exit status says so
    tables = json.loads((out / "results.json").read_text())["tables"]
    assert code == closed_loop_status(tables["mpc_runs"])
    report = (out / "report.md").read_text()
    assert "profile 'quick', robot panda" in report and "Simulated panda: activations" in report
    assert "pid_dither_sized.yaml" in report and "## Closed-loop MPC" in report and "affected plant" in report
    datasets = sorted((out / "data").glob("*.h5"))
    assert len(datasets) == 4
    for path in datasets:
        dataset = load_dataset(path)
        assert dataset.metadata.robot_name == "panda" and dataset.trajectory(0).q.shape[1] == 7
        assert dataset.metadata.plant_effects == load_plant_effects(MODELS_DIR / "panda_effects.yaml")
    rows = {row["model"]: row for row in tables["mpc"]}
    assert rows["true-plant"]["limit_violations"] == 0 and rows["plant"]["limit_violations"] == 0
    capsys.readouterr()
    assert main(["reproduce", "--quick", "--robot", str(ACROBOT_CONFIG), "--quiet", "-o", str(tmp_path / "acro")]) == 2
    assert "acrobot is underactuated" in capsys.readouterr().err and not (tmp_path / "acro").exists()


@pytest.mark.slow
def test_the_reality_gap_and_identification_studies_on_the_affected_panda(tmp_path):
    """`tools/study.py reality-gap --quick` and `identification --quick` on the 7-joint arm with its derived
    protocols and models/panda_effects.yaml. The reality gap: its files and figures with a verdict; each model's
    MPC setting chosen on validation plans only, the test plans run with it and with the shipped one. The
    identification study: the white box, the grey and black boxes and the tuned closed loop."""
    from tools_import import study
    out, data = tmp_path / "out", tmp_path / "data"
    affected = ["--quick", "--robot", str(PANDA_CONFIG), "--plant-effects", str(MODELS_DIR / "panda_effects.yaml")]
    assert study.main(["reality-gap", "--allow-dirty", *affected, "-o", str(out / "reality_gap"), "--data", str(data / "reality_gap")]) == 0
    for name in ("results.json", "closed_loop.csv", "open_loop.csv", "closed_loop.png", "open_loop.png"):
        assert (out / "reality_gap" / name).stat().st_size > 0
    results = json.loads((out / "reality_gap" / "results.json").read_text())
    assert results["robot"] == "panda" and results["verdict"]["text"]
    closed = {(row["setting"], row["model"]) for row in results["closed_loop"]}
    assert closed == {(setting, model) for setting in ("tuned", "shipped") for model in ("plant", "true-plant", "D", "DD")}
    assert {row["plant"] for row in results["open_loop"]} == {"friction", "payload", "all"}
    grid = {tuple(setting) for setting in results["design"]["mpc_grid"]}
    assert {run["split"] for run in results["tuning_runs"]} == {"val"} and {run["split"] for run in results["runs"]} == {"test"}
    tuning_plans = {run["trajectory"] for run in results["tuning_runs"]}
    assert tuning_plans and not tuning_plans & {run["trajectory"] for run in results["runs"]}
    for name, setting in results["chosen_mpc_settings"].items():
        assert tuple(setting) in grid
        assert {(run["effort_scale"], run["observer_gain"]) for run in results["runs"]
                if run["model"] == name and run["setting"] == "tuned"} == {tuple(setting)}
    checkpoints = sorted((data / "reality_gap" / "runs").rglob("checkpoint.pt"))
    assert len(checkpoints) == 2 * 2 + 2 * 3   # D, DD: 2 seeds closed loop, 1 seed on each of 3 plants
    # the identification study: the white box on the 7-joint arm (torques to 0.1 % with true derivatives; its
    # preset's Coulomb velocity scale differs per joint, the model's is one for all), the grey and black boxes
    assert study.main(["identification", "--allow-dirty", *affected, "-o", str(out / "sysid"), "--data", str(data / "sysid")]) == 0
    white = json.loads((out / "sysid" / "results.json").read_text())
    assert [row["run"] for row in white["rows"]] == ["A", "C"]      # (the quick profile's runs)
    assert white["rows"][0]["torque_error"] < 0.01 < white["rows"][0]["description_torque_error"]
    grey = json.loads((out / "sysid" / "grey_box.json").read_text())
    assert {row["model"] for row in grey["sensors"]["ideal"]["1"]["rows"]} >= {"D", "G-id-state", "identified", "plant"}
    # its tuned closed loop: every model a user has beside the grey box, tuned on validation plans, then the test plans
    closed = json.loads((out / "sysid" / "closed_loop.json").read_text())["sensors"]["paper"]
    assert [row["model"] for row in closed["rows"]] == ["plant", "true-plant", "identified", "D", "G-id-state"]
    assert {run["split"] for run in closed["tuning_runs"]} == {"val"} and {run["split"] for run in closed["runs"]} == {"test"}
    assert closed["verdict"]["text"] in (out / "sysid" / "closed_loop.md").read_text()


def test_locked_mimic_fingers_load_and_a_mimic_on_an_arm_joint_is_refused(tmp_path):
    """Drake turns <mimic> into a coupler constraint, which blocks welding; a pair of locked fingers is
    dropped (as in pybullet's Panda), a pair that touches an arm joint is a one-line error."""
    from test_robot_config import GOOD, LINK, two_link_urdf, write_robot
    finger2 = (LINK.format(name="finger2", mass=0.1, com=0.0)
               + '  <joint name="finger_joint2" type="prismatic"><parent link="fore"/><child link="finger2"/>'
                 '<origin xyz="0 0 0.3"/><axis xyz="-1 0 0"/><limit lower="0" upper="0.04" effort="5" velocity="0.1"/>'
                 '<mimic joint="{leader}"/></joint>\n</robot>')
    fingers = two_link_urdf().replace("</robot>", finger2.format(leader="finger_joint"))
    robot = load_robot(write_robot(tmp_path, fingers, GOOD.replace("{finger_joint: 0.02}",
                                                                   "{finger_joint: 0.02, finger_joint2: 0.02}")))
    plant, _ = make_plant(PlantConfig.continuous(), robot=robot)
    assert plant.num_positions() == 2 and plant.num_constraints() == 0
    for leader, locked, message in (("elbow", "{finger_joint: 0.02, finger_joint2: 0.02}", "arm joint 'elbow' is in a <mimic>"),
                                    ("finger_joint", "{finger_joint: 0.02}", "lock every joint of a mimic pair")):
        config = GOOD.replace("{finger_joint: 0.02}", locked)
        path = write_robot(tmp_path, two_link_urdf().replace("</robot>", finger2.format(leader=leader)), config)
        with pytest.raises(InputError) as error:
            make_plant(PlantConfig.continuous(), robot=load_robot(path))
        assert message in str(error.value) and "\n" not in str(error.value), str(error.value)
