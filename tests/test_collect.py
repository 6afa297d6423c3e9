"""Data collection: zero-order-hold exactness, protocols, determinism, CLI and bad input."""
import subprocess
import sys

import numpy as np
import pytest

from presets import UR10
from stdm_drake.cli import main
from stdm_drake.collection.collect import StationConfig, Station
from stdm_drake.robots.control import JointSensor, Pid, SampledJointController, SensorConfig
from stdm_drake.data.dataset import load_dataset
from stdm_drake.data.inspect import tracking_errors, tracking_smoothness


@pytest.mark.parametrize("name", ["excitation_dataset", "tracking_dataset"])
def test_next_state_is_a_function_of_state_and_held_torque(name, request):
    """Re-simulating one sample period from (x_k, a_k) on a fresh rig reproduces x_k+1 exactly (the
    tracking controller's filter and integral live outside the plant: the torque is held)."""
    dataset = load_dataset(request.getfixturevalue(name))
    rig = Station(StationConfig(robot=UR10)).simulation
    traj = dataset.trajectory(1)
    for k in (0, 17, 49):
        x_k = np.concatenate([traj.q_true[k], traj.v_true[k]])
        rig.diagram.SetDefaultContext(rig.context)
        rig.context.SetTime(0.0)
        rig.plant.SetPositionsAndVelocities(rig.plant_context, x_k)
        rig.diagram.GetInputPort("actuation").FixValue(rig.context, traj.tau[k])
        rig.simulator.Initialize()
        rig.simulator.AdvanceTo(dataset.sample_period)
        x_next = rig.plant.GetPositionsAndVelocities(rig.plant_context)
        np.testing.assert_allclose(x_next[:6], traj.q_true[k + 1], atol=1e-12)
        np.testing.assert_allclose(x_next[6:], traj.v_true[k + 1], atol=1e-10)


def test_excitation_dataset_contents(excitation_dataset):
    dataset = load_dataset(excitation_dataset)
    assert dataset.protocol == "excitation" and dataset.num_trajectories == 4
    assert dataset.sample_period == 0.01 and dataset.metadata.record["plant"]["time_step"] == 0.001
    params = np.array(dataset.metadata.record["excitation_parameters"])
    assert params.shape == (4, 24)
    for i in range(4):
        traj = dataset.trajectory(i)
        assert traj.q.shape == (51, 6) and traj.tau.shape == (50, 6)
        np.testing.assert_array_equal(traj.q, traj.q_true)  # ideal sensor by default
        # the recorded action is the total applied torque: gravity compensation + eq. (10)
        amplitude, frequency, offset, phase = params[i].reshape(4, 6)
        t = np.arange(50)[:, None] * dataset.sample_period
        from stdm_drake.robots.plant import Dynamics
        gravity = np.array([Dynamics(UR10).gravity_torque(q) for q in traj.q_true[:-1]])
        np.testing.assert_allclose(traj.tau, gravity + amplitude * np.sin(frequency * t + phase) + offset,
                                   atol=1e-9)
        # true accelerations agree with the velocity differences (first order in dt)
        v_diff = np.diff(traj.v_true, axis=0) / dataset.sample_period
        midpoint = 0.5 * (traj.qdd[:-1] + traj.qdd_end)
        assert np.abs(v_diff - midpoint).max() < 0.05 * np.abs(v_diff).max() + 1e-3


@pytest.mark.slow
def test_same_seed_same_bytes_any_worker_count(tmp_path):
    def collect(seed, workers, name):
        assert main(["collect", "--protocol", "excitation", "--count", "3", "--seed", str(seed), "--quiet",
                     "--workers", str(workers), "-o", str(tmp_path / name)]) == 0

    collect(11, 1, "a.h5")
    collect(11, 2, "b.h5")
    collect(12, 1, "c.h5")
    assert (tmp_path / "a.h5").read_bytes() == (tmp_path / "b.h5").read_bytes()
    assert (tmp_path / "a.h5").read_bytes() != (tmp_path / "c.h5").read_bytes()


def test_the_default_worker_count_is_one_for_a_small_job(monkeypatch):
    """Issue 57: two workers made a 4-plan collect slower than one (a second process's start-up outweighs the work
    it takes over): without --workers a job under 25,000 plant steps runs in one process, a larger one in
    min(2, cores) (tools/bench_collect_workers.py measured the threshold)."""
    from stdm_drake.collection import collect as collect_module
    monkeypatch.setattr(collect_module.os, "cpu_count", lambda: 8)
    assert collect_module.default_workers(16 * 100 * 10) == 1          # 16 tracked plans of 100 samples at 1 ms
    assert collect_module.default_workers(25_000) == collect_module.default_workers(48 * 100 * 10) == 2
    monkeypatch.setattr(collect_module.os, "cpu_count", lambda: 1)
    assert collect_module.default_workers(10 ** 6) == 1
    seen = []
    monkeypatch.setattr(collect_module, "job_pool", lambda config, **options: seen.append(config.workers) or
                        (_ for _ in ()).throw(RuntimeError("stop")))
    request = collect_module.collection_request("excitation", count=3, robot=UR10)
    with pytest.raises(RuntimeError, match="stop"):
        collect_module.collect(request, progress=False)
    assert request.workers is None and seen == [1]                     # 3 x 50 samples x 10 plant steps


def test_tracking_dataset_tracks_tightly(tracking_dataset):
    dataset = load_dataset(tracking_dataset)
    assert dataset.protocol == "tracking" and dataset.num_trajectories == 8
    np.testing.assert_array_equal(np.bincount(dataset.groups), [2, 2, 2, 2])
    errors = tracking_errors(dataset)
    # the paper's PID on the real UR-10: 1.818e-5 rad^2 and 0.029 (rad/s)^2
    assert errors["true_q"] < 3e-5 and errors["measured_v"] < 0.029
    for i in range(dataset.num_trajectories):
        traj = dataset.trajectory(i)
        np.testing.assert_allclose(traj.q_true[0], traj.q_planned[0], atol=1e-12)  # starts on the plan
        assert not np.array_equal(traj.q, traj.q_true)  # measured with noise
        for key in ("v_planned", "qdd_planned"):
            assert np.abs(getattr(traj, key)[[0, -1]]).max() < 1e-6  # plans start and end at rest
    assert dataset.metadata.record["controller"]["kind"] == "inverse_dynamics"
    assert dataset.metadata.record["controller"]["velocity_filter_time_constant"] == 0.015
    assert dataset.metadata.record["planner"]["kind"] == "quintic"


def test_sensor_filter_is_a_causal_moving_average():
    sensor = JointSensor(SensorConfig(velocity_filter_window=3), np.random.default_rng(0))
    outputs = [sensor.measure(np.zeros(6), np.full(6, float(k)))[2][0] for k in range(5)]
    assert outputs == [0.0, 0.5, 1.0, 2.0, 3.0]


@pytest.mark.slow
def test_default_controller_does_not_chatter_where_pid_does(tmp_path, tracking_dataset):
    """Same plans and sensor noise: the diagonal PID (pid.yaml) makes the wrists chatter, the default
    filtered computed-torque controller does not (wrist velocity error and sign-flip rate >= 3x lower)
    and tracks the joint angles well within the paper's 1.8e-5 rad^2."""
    path = tmp_path / "pid.h5"
    assert main(["collect", "--protocol", "tracking", "--controller", "controllers/pid.yaml",
                 "--count", "8", "--seed", "5", "--workers", "1", "--quiet", "-o", str(path)]) == 0
    pid, default = load_dataset(path), load_dataset(tracking_dataset)
    assert pid.metadata.record["controller"]["kind"] == "pid"
    rough, smooth = tracking_smoothness(pid), tracking_smoothness(default)
    wrists = slice(3, 6)
    assert np.all(rough["sign_flip_rate"][wrists] > 0.5)  # chatter: close to white noise's 2/3
    assert np.all(smooth["sign_flip_rate"][wrists] * 3 <= rough["sign_flip_rate"][wrists])
    chattering = slice(3, 5)  # wrist_1, wrist_2: where the velocity error was largest
    assert np.all(smooth["velocity_error_rms"][chattering] * 3 <= rough["velocity_error_rms"][chattering])
    assert np.all(smooth["peak_acceleration"] < 2 * smooth["peak_planned_acceleration"].max())
    assert tracking_errors(default)["true_q"] < 1.8e-5


def test_controller_velocity_filter_is_first_order():
    """D-only controller (kp = ki = 0, kd = 1, no gravity): torque = -v_filtered; with a time constant
    equal to the period the filter moves halfway each sample, starting at the first reading."""
    config = Pid(kp=[0.0] * 6, ki=[0.0] * 6, kd=[1.0] * 6, gravity_feedforward=False,
                 velocity_filter_time_constant=0.01)
    controller = SampledJointController(config, 0.01, UR10)
    zeros = np.zeros(6)
    torques = [controller.torque(zeros, np.full(6, v), zeros, zeros, zeros)[0] for v in (2.0, 0.0, 0.0, 4.0)]
    np.testing.assert_allclose(torques, [-2.0, -1.0, -0.5, -2.25])
    controller.reset()
    assert controller.torque(zeros, np.full(6, 3.0), zeros, zeros, zeros)[0] == pytest.approx(-3.0)


def test_inspect_prints_summary(tracking_dataset, capsys):
    assert main(["inspect", str(tracking_dataset)]) == 0
    out = capsys.readouterr().out
    assert "protocol        tracking" in out and "tracking error" in out and "groups          0: 2" in out
    assert "dv sign flips" in out and "v error rms" in out
    assert "v error rms in rad/s, dv sign flips as a fraction of sample pairs, |qdd| peaks in rad/s^2" in out   # (units)
    for key, words in (("q rad", 2), ("v rad/s", 2), ("tau N m", 3), ("qdd rad/s^2", 2)):   # one cell per joint,
        (row,) = [line for line in out.splitlines() if line.startswith(key + " ")]       # never run together
        cells = row.split()[words:]
        assert len(cells) == 6 and all(".." in cell for cell in cells), row


def run_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "stdm_drake.cli", *args], capture_output=True, text=True, cwd=cwd)


@pytest.mark.slow
@pytest.mark.parametrize("yaml_text, message", [
    ("num_steps: [1, 2\n", "malformed excitation config"),
    ("bogus_key: 1\n", "unknown to the schema"),
    ("amplitude_max: [1.0, 2.0]\n", "amplitude_max has 2 values; the robot has 6 joints"),
])
def test_bad_excitation_yaml_one_line_error_no_file(tmp_path, yaml_text, message):
    config = tmp_path / "bad.yaml"
    config.write_text(yaml_text)
    result = run_cli("collect", "--protocol", "excitation", "--config", str(config), "--count", "1",
                     "-o", str(tmp_path / "out.h5"))
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1 and message in result.stderr
    assert str(config) in result.stderr
    assert not (tmp_path / "out.h5").exists()


@pytest.mark.slow
def test_paper_excitation_preset_fails_clearly(tmp_path):
    result = run_cli("collect", "--protocol", "excitation", "--config", "trajectories/excitation_paper.yaml",
                     "--count", "1", "--workers", "1", "--quiet", "-o", str(tmp_path / "out.h5"))
    assert result.returncode == 2
    assert "no trajectory within limits after 50 attempts" in result.stderr and "wrist_3_joint" in result.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_unreachable_pose_fails_clearly(tmp_path):
    text = open("trajectories/tracking.yaml").read().replace("xyz: [0.65, 0.35, 0.45]", "xyz: [2.5, 0.35, 0.45]", 1)
    config = tmp_path / "far.yaml"
    config.write_text(text)
    result = run_cli("collect", "--protocol", "tracking", "--config", str(config), "--count", "1",
                     "--workers", "1", "--quiet", "-o", str(tmp_path / "out.h5"))
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1
    assert "unreachable" in result.stderr.lower() or "inverse kinematics" in result.stderr.lower()
    assert not (tmp_path / "out.h5").exists()


@pytest.mark.slow
def test_bad_controller_and_period(tmp_path):
    gains = tmp_path / "gains.yaml"
    gains.write_text("controller: !Pid\n  kp: [1, 2, 3]\n  ki: [0]\n  kd: [1]\n")
    result = run_cli("collect", "--controller", str(gains), "-o", str(tmp_path / "out.h5"))
    assert result.returncode == 2 and "controller kp has 3 values; the robot has 6 joints" in result.stderr
    gains.write_text(open("controllers/inverse_dynamics.yaml").read().replace(
        "velocity_filter_time_constant: 0.015", "velocity_filter_time_constant: -0.01"))
    result = run_cli("collect", "--controller", str(gains), "-o", str(tmp_path / "out.h5"))
    assert result.returncode == 2 and "velocity_filter_time_constant must be in [0, 10] s" in result.stderr
    result = run_cli("collect", "--sample-period", "0.0015", "-o", str(tmp_path / "out.h5"))
    assert result.returncode == 2 and "whole multiple" in result.stderr
    assert list(tmp_path.iterdir()) == [gains]


def test_html_recording(tmp_path):
    html = tmp_path / "run.html"
    assert main(["collect", "--protocol", "excitation", "--count", "2", "--seed", "1", "--workers", "1", "--quiet",
                 "-o", str(tmp_path / "d.h5"), "--html", str(html)]) == 0
    text = html.read_text()
    assert text.startswith("<!DOCTYPE html>") or "<html" in text[:200]
    assert "animation" in text and len(text) > 100_000


@pytest.mark.slow
def test_torque_dither_is_recorded_and_seeded(tmp_path):
    gains = tmp_path / "dither.yaml"
    gains.write_text(open("controllers/pid.yaml").read() + "  dither_std: [2.0, 2.0, 1.0, 0.1, 0.02, 0.002]\n")

    def collect(controller, name):
        path = tmp_path / name
        assert main(["collect", "--count", "2", "--seed", "4", "--workers", "1", "--quiet",
                     "--controller", str(controller), "-o", str(path)]) == 0
        return load_dataset(path)

    plain, dithered, again = (collect("controllers/pid.yaml", "a.h5"), collect(gains, "b.h5"),
                              collect(gains, "c.h5"))
    difference = dithered.trajectory(0).tau - plain.trajectory(0).tau
    assert np.abs(difference[:, 0]).max() > 1.0  # the dither is in the recorded (applied) torque
    np.testing.assert_array_equal(dithered.trajectory(0).tau, again.trajectory(0).tau)
    assert dithered.metadata.record["controller"]["dither_std"] == [2.0, 2.0, 1.0, 0.1, 0.02, 0.002]
    assert tracking_errors(dithered)["true_q"] < 1e-4


def test_controller_files_are_tagged_and_the_old_kind_layout_loads_with_a_warning(tmp_path, capsys):
    """`controller: !Pid {...}` picks the type by its tag; a file in the layout before the tags (top-level
    `kind: pid`) loads to the same config and says in one line how to update it."""
    from stdm_drake.robots.control import InverseDynamics, load_controller_config
    new = tmp_path / "new.yaml"
    new.write_text("controller: !Pid\n  kp: [1.0]\n  ki: [2.0]\n  kd: [0.5]\n  gravity_feedforward: false\n")
    old = tmp_path / "old.yaml"
    old.write_text("kind: pid\nkp: [1.0]\nki: [2.0]\nkd: [0.5]\ngravity_feedforward: false\n")
    assert load_controller_config(new) == Pid(kp=[1.0], ki=[2.0], kd=[0.5], gravity_feedforward=False)
    assert capsys.readouterr().err == ""
    assert load_controller_config(old) == load_controller_config(new)
    warning = capsys.readouterr().err.strip()
    assert len(warning.splitlines()) == 1 and "old `kind: pid` layout" in warning and "controller: !Pid" in warning
    assert isinstance(load_controller_config("controllers/inverse_dynamics.yaml"), InverseDynamics)
    assert Pid(kp=[1.0], ki=[1.0], kd=[1.0]).record()["kind"] == "pid"



def test_protocol_files_are_tagged_and_name_their_protocol(tmp_path, capsys):
    """`protocol: !Excitation` / `!Tracking` picks the protocol (collect --config needs no --protocol); a file
    asked for as the other protocol is refused; the layout before the tags loads as the protocol asked for,
    with one warning line (without one: tracking, the default before the tags)."""
    from stdm_drake.collection.collect import collection_request
    from stdm_drake.collection.planner_configs import Ruckig
    from stdm_drake.collection.protocols import PROTOCOL_TYPES
    from stdm_drake.data.schema import SIMULATED_PROTOCOLS
    from stdm_drake.errors import InputError
    assert tuple(PROTOCOL_TYPES) == SIMULATED_PROTOCOLS   # one config type per protocol collect simulates
    ruckig = collection_request(config="trajectories/tracking_ruckig.yaml", robot=UR10, count=1, workers=1)
    assert ruckig.protocol == "tracking" and isinstance(ruckig.tracking_spec.planner, Ruckig)
    assert collection_request(config="trajectories/excitation.yaml", robot=UR10, count=1, workers=1).protocol \
        == "excitation"
    with pytest.raises(InputError, match="holds the tracking protocol, not the excitation protocol"):
        collection_request("excitation", config="trajectories/tracking.yaml", robot=UR10, count=1, workers=1)
    assert capsys.readouterr().err == ""
    old = tmp_path / "old.yaml"   # the layout before the tags: the fields at the top
    old.write_text("\n".join(line[2:] for line in open("trajectories/excitation.yaml").read().splitlines()
                             if line.startswith("  ")) + "\n")
    request = collection_request("excitation", config=old, robot=UR10, count=1, workers=1)
    assert request.excitation == collection_request("excitation", robot=UR10, count=1, workers=1).excitation
    warning = capsys.readouterr().err.strip()
    assert len(warning.splitlines()) == 1 and "write `protocol: !Excitation`" in warning
    with pytest.raises(InputError, match=r"malformed tracking spec"):   # untagged, no protocol: tracking, as before
        collection_request(config=old, robot=UR10, count=1, workers=1)


def test_an_old_layout_warning_waits_for_the_command_to_succeed(tmp_path, capsys):
    """A controller file without tag or kind reads as the default (Pid) with one warning line, printed once
    the command has succeeded; when the command fails (here --count 0) only its one error line appears."""
    from stdm_drake.cli import main
    from stdm_drake.robots.control import load_controller_config
    old = tmp_path / "gains.yaml"
    old.write_text("kp: [1.0]\nki: [2.0]\nkd: [0.5]\n")
    assert load_controller_config(old) == Pid(kp=[1.0], ki=[2.0], kd=[0.5])
    assert "has no type tag (read as the default, pid)" in capsys.readouterr().err
    assert main(["collect", "--controller", str(old), "--count", "0", "-o", str(tmp_path / "out.h5")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "--count must be in 1..100000" in lines[0]


def test_a_dataset_is_reused_when_its_record_agrees_field_by_field():
    """Fields only one side records (Drake's added plant settings, a controller kind's dropped unused ones)
    do not make reproduce collect a dataset again; a field both record and that differs does."""
    from stdm_drake.experiments.datasets import _agrees
    old = dict(time_step=0.001, discrete_contact_approximation="sap", self_collision=True)
    new = dict(old, penetration_allowance=0.001, stiction_tolerance=1e-4)
    assert _agrees(old, new) and _agrees(dict(kind="inverse_dynamics", gravity_feedforward=True), {"kind": "inverse_dynamics"})
    assert not _agrees(old, dict(new, time_step=0.002)) and not _agrees(3, 4)

