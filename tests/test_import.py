"""`stdm-drake import` (issue 24): real robots' logs as datasets. The project's simulator writes its data as the
recorders do (RTDE CSV space and comma delimited, ROS 2 bags in sqlite3 and MCAP storage, with timing jitter and
dropped rows); the import must give back the simulated data within its stated resampling error, split logs where
robots pause or stop, and every command must take the logged dataset."""
import json
import pathlib
import shutil

import h5py
import numpy as np
import pytest

from stdm_drake.cli import main
from stdm_drake.data.dataset import load_dataset
from stdm_drake.data.logs import simulated
from stdm_drake.data.logs.importer import Counts, Pieces
from stdm_drake.data.logs.mapping import LogMapping
from stdm_drake.data.logs.rows import Rows
from stdm_drake.errors import InputError
from stdm_drake.paths import CONTROLLERS_DIR, TRAJECTORIES_DIR
from stdm_drake.robots.robot import UR10_CONFIG, load_robot

UR10 = load_robot(UR10_CONFIG)


@pytest.fixture(scope="module")
def simulated_500hz(tmp_path_factory):
    """4 tracked plans of 1 s of the UR-10 sampled at 500 Hz (0.002 s), ideal sensor."""
    folder = tmp_path_factory.mktemp("sim500")
    spec = folder / "tracking_500hz.yaml"
    spec.write_text((TRAJECTORIES_DIR / "tracking.yaml").read_text().replace("num_steps: 100", "num_steps: 500"))
    path = folder / "sim.h5"
    assert main(["collect", "--protocol", "tracking", "--config", str(spec), "--count", "4", "--seed", "3",
                 "--sample-period", "0.002", "--sensor", str(CONTROLLERS_DIR / "sensor_ideal.yaml"), "--workers", "1",
                 "--quiet", "-o", str(path)]) == 0
    return path


@pytest.fixture(scope="module")
def logs(simulated_500hz, tmp_path_factory):
    """The simulated data as each recorder writes it: {name: (log path, LogTiming)}."""
    folder = tmp_path_factory.mktemp("logs")
    data = load_dataset(simulated_500hz)
    rtde_timing, bag_timing = simulated.log_timing(data, seed=1), simulated.log_timing(data, seed=2, clock_start=0.5)
    found = dict(rtde_space=(simulated.write_rtde_csv(data, folder / "record.csv", timing=rtde_timing), rtde_timing),
                 rtde_comma=(simulated.write_rtde_csv(data, folder / "ur_rtde.csv", delimiter=",", timing=rtde_timing),
                             rtde_timing))
    for storage in ("sqlite3", "mcap"):
        found[f"bag_{storage}"] = (simulated.write_ros2_bag(data, folder / f"bag_{storage}", UR10.joint_names,
                                                            storage=storage, timing=bag_timing), bag_timing)
    return found


def imported(log: pathlib.Path, out: pathlib.Path, *extra) -> pathlib.Path:
    assert main(["import", str(log), "-o", str(out), "--quiet", *extra]) == 0
    return out


@pytest.mark.slow
@pytest.mark.parametrize("name", ["rtde_space", "rtde_comma", "bag_sqlite3", "bag_mcap"])
def test_the_import_gives_back_the_simulated_data_within_its_stated_error(simulated_500hz, logs, tmp_path, name):
    """Angles within the stated resampling error of the true motion at the import's grid times, torques exact but
    where a row was dropped, the plan there, the trajectories split where the recorder paused."""
    original = load_dataset(simulated_500hz)
    log, timing = logs[name]
    data = load_dataset(imported(log, tmp_path / "imported.h5"))
    record = data.metadata.record["import"]
    assert data.protocol == "logged" and data.has_plan and data.sample_period == pytest.approx(0.002)
    assert data.num_trajectories == original.num_trajectories and record["trajectories"]["gaps"] == 3
    assert record["format"] == ("ros2_bag" if name.startswith("bag") else "rtde_csv")
    errors, torque_rows = [], []
    for index in range(data.num_trajectories):
        mine, theirs = data.trajectory(index), original.trajectory(index)
        start = record["start_times_s"][index] - timing.starts[index]
        assert abs(start) < 5e-5          # the grid is the log's clock, not a jittered stamp
        times = start + data.sample_period * np.arange(mine.num_steps + 1)
        assert theirs.num_steps - 1 <= mine.num_steps <= theirs.num_steps
        q, v = simulated.true_state_at(theirs, original.sample_period, np.clip(times, 0.0, None))
        errors.append((mine.q - q) ** 2)
        assert np.abs(mine.v - v).max() < 1e-3
        steps = min(mine.num_steps, theirs.num_steps)
        differs = np.abs(mine.tau[:steps] - theirs.tau[:steps]).max(axis=1) > 1e-9
        dropped = np.setdiff1d(np.arange(steps), timing.samples[index])
        assert set(np.flatnonzero(differs)) <= set(dropped)     # a dropped row's period holds its neighbour's command
        torque_rows.append(differs.mean())
        assert np.abs(mine.q_planned - theirs.q_planned[:mine.num_steps + 1]).max() < 1e-3
    rms = float(np.sqrt(np.mean(np.concatenate(errors))))
    stated = record["resampling"]["estimated_q_error_rad"]
    assert rms < 1e-7 and rms <= 2 * stated, (rms, stated)
    assert 0 < np.mean(torque_rows) < 0.03
    assert record["resampling"]["jitter_rms_s"] == pytest.approx(1.5e-4, rel=0.2)


def test_the_same_log_gives_the_same_bytes(logs, tmp_path):
    first = imported(logs["rtde_space"][0], tmp_path / "a.h5")
    assert first.read_bytes() == imported(logs["rtde_space"][0], tmp_path / "b.h5").read_bytes()
    data = load_dataset(first)
    assert data.derivative_sources == ("planned", "measured", "smoothed") and data.default_derivative_source == "planned"
    for source in data.derivative_sources:
        assert np.isfinite(data.transitions([0], derivative_source=source).next_state_rate).all()
    with pytest.raises(InputError, match="derivative source 'true' is not in this logged dataset"):
        data.transitions(derivative_source="true")


@pytest.mark.slow
def test_every_command_takes_an_imported_log(logs, tmp_path, capsys):
    """inspect, train (smoothed derivative targets), evaluate, view, identify (smoothed by default) and mpc's
    model side on a log imported at 0.01 s."""
    data_path = imported(logs["rtde_space"][0], tmp_path / "log.h5", "--sample-period", "0.01")
    capsys.readouterr()
    assert main(["inspect", str(data_path)]) == 0
    text = capsys.readouterr().out
    assert "protocol        logged" in text and "imported from   rtde_csv" in text and "noise floor" not in text
    # newcomer pass 2: no "seed None", the log's period in the sample period's digits, the ranges' columns aligned
    assert "seed            (none: a log)" in text and "seed            None" not in text
    record = load_dataset(data_path).metadata.section("import")["resampling"]["log_period_s"]
    assert f"log period {record:.6g} s" in text
    ranges = text.split("ranges (min..max over all samples)\n")[1].split("\n\n")[0].splitlines()
    assert len({len(line) for line in ranges}) == 1 and ranges[-1].startswith("qdd_smoothed rad/s^2 "), ranges
    assert main(["train", str(data_path), "--epochs", "2", "--train", "2", "--val", "1", "--derivative", "on",
                 "--derivative-source", "smoothed", "--quiet", "-o", str(tmp_path / "run")]) == 0
    checkpoint = tmp_path / "run" / "seed0" / "checkpoint.pt"
    assert main(["evaluate", str(checkpoint), str(data_path)]) == 0
    assert main(["view", str(checkpoint), str(data_path), "--html", str(tmp_path / "view.html")]) == 0
    assert main(["identify", str(data_path), "-o", str(tmp_path / "id.yaml"), "--train", "2", "--val", "1",
                 "--windows", "9", "--regularizations", "1e-4", "--quiet"]) == 0
    report = json.loads((tmp_path / "id.json").read_text())
    assert "truth" not in report and report["test"]["torque_error"] < 1.0
    code = main(["mpc", str(data_path), "--model", f"D={checkpoint}", "--plans", "1", "--quiet", "-o", str(tmp_path / "mpc")])
    result = json.loads((tmp_path / "mpc" / "mpc.json").read_text())
    assert {run["model"] for run in result["runs"]} == {"plant", "D"}
    from conftest import closed_loop_status
    assert code == closed_loop_status(result["summary"])     # a 2-epoch D may leave the limits: exit 2 then only
    rows = {row["model"]: row for row in result["summary"]}
    assert rows["plant"]["limit_violations"] == 0 and rows["plant"]["q_mse_rad2"] < 1e-3   # the log's robot tracks it
    assert np.isfinite(rows["D"]["q_mse_rad2"])


def test_a_format_version_1_dataset_still_loads(logs, tracking_dataset, tmp_path):
    old = tmp_path / "v1.h5"
    shutil.copy(tracking_dataset, old)
    with h5py.File(old, "r+") as file:
        file.attrs["format_version"] = 1
    assert load_dataset(old).num_trajectories == load_dataset(tracking_dataset).num_trajectories
    logged = tmp_path / "logged_v1.h5"
    shutil.copy(imported(logs["bag_mcap"][0], tmp_path / "logged.h5"), logged)
    with h5py.File(logged, "r+") as file:
        file.attrs["format_version"] = 1
    with pytest.raises(InputError, match="unknown protocol 'logged' .format version 1"):
        load_dataset(logged)


def rows_of(t, v, mode=None, running=None):
    t = np.asarray(t, dtype=float)
    v = np.asarray(v, dtype=float)
    q = np.cumsum(v, axis=0) * 0.01
    return Rows(t=t, q=q, v=v, tau=np.zeros_like(v), where=np.arange(len(t)) + 2, mode=mode, running=running)


def pieces_of(blocks, **settings) -> tuple[list, Counts]:
    counts = Counts()
    splitter = Pieces(LogMapping(**settings), 0.01, counts)
    found = [piece for block in blocks for piece in splitter.feed(block)] + splitter.finish()
    return found, counts


def test_a_recording_splits_at_gaps_pauses_mode_changes_and_its_longest_duration():
    moving = np.full((300, 2), 0.5)
    t = np.arange(300) * 0.01
    # a gap of 0.5 s after row 99: two pieces
    gapped = t + np.where(np.arange(300) >= 100, 0.5, 0.0)
    found, counts = pieces_of([rows_of(gapped[:150], moving[:150]), rows_of(gapped[150:], moving[150:])])
    assert [len(piece) for piece in found] == [100, 200] and counts.gaps == 1
    # a pause of 0.8 s (rows 100..179 at rest) inside: left out
    resting = moving.copy()
    resting[100:180] = 0.0
    found, counts = pieces_of([rows_of(t[:120], resting[:120]), rows_of(t[120:], resting[120:])])
    assert [len(piece) for piece in found] == [100, 120] and counts.pauses == 1
    assert found[1].t[0] == pytest.approx(1.8)
    # a short stop (0.2 s) is part of the motion
    stopped = moving.copy()
    stopped[100:120] = 0.0
    found, _ = pieces_of([rows_of(t, stopped)])
    assert [len(piece) for piece in found] == [300]
    # a mode change at row 200, rows 50..59 not running
    mode = np.where(np.arange(300) >= 200, 7, 3)
    running = ~((np.arange(300) >= 50) & (np.arange(300) < 60))
    found, counts = pieces_of([rows_of(t[:55], moving[:55], mode[:55], running[:55]),
                               rows_of(t[55:], moving[55:], mode[55:], running[55:])])
    assert [len(piece) for piece in found] == [50, 140, 100] and counts.mode_changes == 2
    assert counts.rows_not_running == 10
    # cut after max_duration, the next piece starting at the cut's last row; a short tail is still a piece here
    found, counts = pieces_of([rows_of(t, moving)], max_duration=1.0, min_duration=0.1)
    assert [len(piece) for piece in found] == [101, 101, 100] and counts.cuts == 2
    assert found[1].t[0] == found[0].t[-1]


def test_a_mapping_file_names_what_the_log_does_not_say(simulated_500hz, logs, tmp_path):
    """Currents times torque constants give the torques (a classic UR arm logs no joint torque); the bag's
    joints renamed by the mapping file."""
    mapping = tmp_path / "mapping.yaml"
    mapping.write_text(f"torque_source: current\ntorque_constants: {list(simulated.TORQUE_CONSTANTS)}\n")
    by_current = load_dataset(imported(logs["rtde_comma"][0], tmp_path / "current.h5", "--mapping", str(mapping)))
    by_moment = load_dataset(imported(logs["rtde_comma"][0], tmp_path / "moment.h5"))
    assert np.allclose(by_current.trajectory(1).tau, by_moment.trajectory(1).tau, rtol=1e-12, atol=1e-9)
    assert by_current.metadata.record["import"]["torque_source"] == "current"
    data = load_dataset(imported(logs["bag_sqlite3"][0], tmp_path / "bag.h5", "--sample-period", "0.01"))
    assert data.sample_period == 0.01 and data.trajectory(0).num_steps in (99, 100)
    original = load_dataset(simulated_500hz)
    renamed = [f"ur_{name}" for name in UR10.joint_names]
    bag = simulated.write_ros2_bag(original, tmp_path / "renamed_bag", renamed, storage="mcap", controller_state=False)
    (tmp_path / "names.yaml").write_text(f"joint_names: {renamed}\n")
    assert main(["import", str(bag), "-o", str(tmp_path / "x.h5"), "--quiet"]) == 2       # the robot's names are not there
    data = load_dataset(imported(bag, tmp_path / "renamed.h5", "--mapping", str(tmp_path / "names.yaml")))
    assert not data.has_plan and data.default_derivative_source == "smoothed" and data.num_trajectories == 4


def test_collect_exports_its_plans_as_csv_and_a_ros2_bag_of_joint_trajectories(tmp_path, capsys):
    """`collect --export-plans`: per plan a CSV file and one JointTrajectory message in a bag, equal to the
    dataset's plans; plans.json records the robot, its limits and the planner; an excitation run or a used folder
    is refused before any simulation."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore
    from stdm_drake.collection.export import PLAN_TOPIC, PLAN_TYPE
    out = tmp_path / "plans"
    assert main(["collect", "--protocol", "tracking", "--count", "4", "--seed", "1", "--workers", "1", "--quiet",
                 "-o", str(tmp_path / "data.h5"), "--export-plans", str(out)]) == 0
    data = load_dataset(tmp_path / "data.h5")
    record = json.loads((out / "plans.json").read_text())
    assert record["robot"] == "ur10" and record["plans"] == 4 and record["planner"]["kind"] == "quintic"
    assert len(record["limits"]["velocity"]) == 6 and record["sample_period"] == data.sample_period
    table = np.loadtxt(out / "plan_0002.csv", delimiter=",", skiprows=1)
    plan = data.trajectory(2)
    assert np.array_equal(table[:, 1:7], plan.q_planned) and np.array_equal(table[:, 13:], plan.qdd_planned)
    store = get_typestore(Stores.ROS2_HUMBLE)
    with Reader(out / "plans_rosbag2") as reader:
        (connection,) = reader.connections
        assert connection.topic == PLAN_TOPIC and connection.msgtype == PLAN_TYPE
        messages = [store.deserialize_cdr(raw, PLAN_TYPE) for _, _, raw in reader.messages()]
    assert len(messages) == 4 and messages[2].joint_names == list(UR10.joint_names)
    points = messages[2].points
    assert np.array_equal(np.array([p.velocities for p in points]), plan.v_planned)
    last = points[-1].time_from_start
    assert last.sec + 1e-9 * last.nanosec == pytest.approx(plan.num_steps * data.sample_period)
    capsys.readouterr()
    assert main(["collect", "--protocol", "tracking", "--count", "1", "--workers", "1", "--quiet",
                 "-o", str(tmp_path / "again.h5"), "--export-plans", str(out)]) == 2
    assert "not empty" in capsys.readouterr().err and not (tmp_path / "again.h5").exists()
    assert main(["collect", "--protocol", "excitation", "--count", "1", "--workers", "1", "--quiet",
                 "-o", str(tmp_path / "e.h5"), "--export-plans", str(tmp_path / "new")]) == 2
    assert "only with --protocol tracking" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "empty")   # a link to an empty folder: the plans go there
    assert main(["collect", "--protocol", "tracking", "--count", "1", "--workers", "1", "--quiet",
                 "-o", str(tmp_path / "linked.h5"), "--export-plans", str(tmp_path / "link")]) == 0
    assert (tmp_path / "link").is_symlink() and (tmp_path / "empty" / "plans.json").is_file()


@pytest.mark.slow
def test_a_model_trained_on_the_import_is_as_accurate_as_one_trained_on_the_original(tmp_path):
    """`tools/study.py import-round-trip --quick`: D trained on a simulated dataset and on its RTDE log's import
    (the same split), both evaluated on the original's test plans; the ratio import / original paired by seed
    (the full experiment's numbers: docs/real_logs.md)."""
    from tools_import import study
    assert study.main(["import-round-trip", "--allow-dirty", "--quick", "--data", str(tmp_path / "data"), "-o", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "round_trip.json").read_text())
    one_step = result["import_over_original"]["one_step_q"]
    assert one_step["pairs"] == 2 and 0.8 <= one_step["ratio"] <= 1.25 and "every_model_learned" in result
    assert result["trajectories"]["kept"] == 8 and result["errors"]["test_plans"]
    assert {"Euler step", "stays put", "plant", "original seed 1", "import seed 1"} <= set(result["errors"])


def test_a_bag_of_urs_driver_currents_and_a_reference_without_accelerations(simulated_500hz, tmp_path):
    """UR's ROS 2 driver reports motor currents as effort, and its scaled trajectory controller's reference has
    no accelerations: --torque-source current gives the torques, the planned accelerations are the reference
    velocities' derivative; controller_state_topic none leaves the plan out."""
    original = load_dataset(simulated_500hz)
    bag = simulated.write_ros2_bag(original, tmp_path / "ur_bag", UR10.joint_names, effort_as_current=True,
                                   reference_accelerations=False)
    constants = [str(value) for value in simulated.TORQUE_CONSTANTS]
    data = load_dataset(imported(bag, tmp_path / "ur.h5", "--torque-source", "current", "--torque-constants", *constants))
    reference = load_dataset(imported(simulated.write_ros2_bag(original, tmp_path / "plain_bag", UR10.joint_names),
                                      tmp_path / "plain.h5"))
    assert np.allclose(data.trajectory(0).tau, reference.trajectory(0).tau, rtol=1e-12, atol=1e-9)
    planned, derived = reference.trajectory(1).qdd_planned, data.trajectory(1).qdd_planned
    assert np.sqrt(np.mean((derived - planned) ** 2)) < 0.05 * np.sqrt(np.mean(planned ** 2))
    (tmp_path / "no_plan.yaml").write_text("controller_state_topic: none\n")
    assert not load_dataset(imported(bag, tmp_path / "no_plan.h5", "--mapping", str(tmp_path / "no_plan.yaml"),
                                     "--torque-source", "current", "--torque-constants", *constants)).has_plan


def test_a_csv_log_saved_with_a_byte_order_mark_imports_as_without_it(logs, tmp_path):
    """Spreadsheet programs save CSV as UTF-8 with a byte-order mark before the header (issue 56: such a log was
    refused as having no timestamp field): the same data (the source's name and hash aside)."""
    import h5py
    log = logs["rtde_comma"][0]
    marked = tmp_path / "spreadsheet.csv"
    marked.write_bytes(b"\xef\xbb\xbf" + log.read_bytes())
    arrays = []
    for path in (imported(marked, tmp_path / "marked.h5"), imported(log, tmp_path / "plain.h5")):
        with h5py.File(path, "r") as file:
            found = {}
            file.visititems(lambda name, item: found.__setitem__(name, item[()]) if isinstance(item, h5py.Dataset)
                            else None)
            arrays.append(found)
    assert arrays[0].keys() == arrays[1].keys() and len(arrays[0]) > 10
    for name in arrays[0]:
        np.testing.assert_array_equal(arrays[0][name], arrays[1][name], err_msg=name)


def test_blank_lines_are_skipped_and_errors_name_the_right_line(logs, tmp_path, capsys):
    lines = logs["rtde_space"][0].read_text().splitlines(keepends=True)
    spaced = lines[:10] + ["\n", "   \n"] + lines[10:] + ["\n"]
    (tmp_path / "spaced.csv").write_text("".join(spaced))
    assert load_dataset(imported(tmp_path / "spaced.csv", tmp_path / "spaced.h5")).num_trajectories == 4
    cells = spaced[40].split()
    cells[5] = "nan"
    spaced[40] = " ".join(cells) + "\n"
    (tmp_path / "bad.csv").write_text("".join(spaced))
    capsys.readouterr()
    assert main(["import", str(tmp_path / "bad.csv"), "-o", str(tmp_path / "bad.h5")]) == 2
    assert "line 41 holds NaN" in capsys.readouterr().err and not (tmp_path / "bad.h5").exists()


def test_a_hole_longer_than_the_longest_piece_ends_it_whatever_the_gap_factor():
    moving = np.full((200, 2), 0.5)
    t = np.arange(200) * 0.01 + np.where(np.arange(200) >= 100, 5.0, 0.0)
    found, counts = pieces_of([rows_of(t, moving)], gap_factor=1000.0, max_duration=2.0)
    assert [len(piece) for piece in found] == [100, 100] and counts.gaps == 1 and counts.cuts == 0
