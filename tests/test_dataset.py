"""Dataset file format: round trip, determinism, transitions, splits and bad input."""
import h5py
import numpy as np
import pytest

from stdm_drake.data.dataset import Trajectory, load_dataset, split_trajectories
from stdm_drake.data.writer import write_dataset
from stdm_drake.errors import InputError

DT = 0.01


def make_trajectory(rng, num_steps=5, planned=True):
    keys = ["q", "v", "q_true", "v_true", "qdd"] + (["q_planned", "v_planned", "qdd_planned"] if planned else [])
    traj = {key: rng.normal(size=(num_steps + 1, 6)) for key in keys}
    traj.update(tau=rng.normal(size=(num_steps, 6)), qdd_end=rng.normal(size=(num_steps, 6)),
                tau_next=rng.normal(size=6))
    return traj


@pytest.fixture
def trajectories():
    rng = np.random.default_rng(0)
    return [make_trajectory(rng) for _ in range(4)]


def write(path, trajectories, protocol="tracking", groups=(0, 0, 1, 1)):
    return write_dataset(path, [Trajectory(**traj) for traj in trajectories], list(groups),
                         dict(protocol=protocol, sample_period=DT, seed=7))


def test_round_trip_and_byte_identical(tmp_path, trajectories):
    write(tmp_path / "a.h5", trajectories)
    write(tmp_path / "b.h5", trajectories)
    assert (tmp_path / "a.h5").read_bytes() == (tmp_path / "b.h5").read_bytes()
    dataset = load_dataset(tmp_path / "a.h5")
    assert dataset.num_trajectories == 4 and dataset.sample_period == DT and dataset.protocol == "tracking"
    assert dataset.metadata.seed == 7
    np.testing.assert_array_equal(dataset.groups, [0, 0, 1, 1])
    for i, traj in enumerate(trajectories):
        for key, value in traj.items():
            np.testing.assert_array_equal(getattr(dataset.trajectory(i), key), value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.h5", "b.h5"]  # no temp files left


def test_transitions_forward_difference(tmp_path, trajectories):
    dataset = load_dataset(write(tmp_path / "d.h5", trajectories))
    t = dataset.transitions([1, 2])
    assert len(t) == 10 and t.state.shape == (10, 12) and t.action_rate.shape == (10, 6)
    traj = trajectories[1]
    np.testing.assert_array_equal(t.state[:5, :6], traj["q"][:-1])
    np.testing.assert_array_equal(t.next_state[:5, 6:], traj["v"][1:])
    np.testing.assert_array_equal(t.state_rate[:5], np.hstack([traj["v_planned"][:-1], traj["qdd_planned"][:-1]]))
    np.testing.assert_array_equal(t.next_state_rate[:5], np.hstack([traj["v_planned"][1:], traj["qdd_planned"][1:]]))
    np.testing.assert_allclose(t.action_rate[3], (traj["tau"][4] - traj["tau"][3]) / DT)
    np.testing.assert_allclose(t.action_rate[4], (traj["tau_next"] - traj["tau"][4]) / DT)  # last step
    np.testing.assert_array_equal(t.trajectory, [1] * 5 + [2] * 5)
    np.testing.assert_array_equal(t.step, list(range(5)) * 2)


def test_transitions_true_and_zero_order_hold(tmp_path, trajectories):
    dataset = load_dataset(write(tmp_path / "d.h5", trajectories))
    t = dataset.transitions([0], derivative_source="true", action_rate="zero_order_hold")
    traj = trajectories[0]
    assert not t.action_rate.any()
    np.testing.assert_array_equal(t.state_rate, np.hstack([traj["v_true"][:-1], traj["qdd"][:-1]]))
    np.testing.assert_array_equal(t.next_state_rate, np.hstack([traj["v_true"][1:], traj["qdd_end"]]))
    with pytest.raises(InputError, match="zero_order_hold"):
        dataset.transitions([0], derivative_source="planned", action_rate="zero_order_hold")
    with pytest.raises(InputError, match="out of range"):
        dataset.transitions([9])


def test_planned_source_needs_tracking_data(tmp_path):
    rng = np.random.default_rng(1)
    dataset = load_dataset(write(tmp_path / "e.h5", [make_trajectory(rng, planned=False)], "excitation", [0]))
    assert dataset.default_derivative_source == "true"
    with pytest.raises(InputError, match="derivative source 'planned' is not in this excitation dataset"):
        dataset.transitions(derivative_source="planned")
    with pytest.raises(InputError, match="derivative source 'smoothed' is not in this excitation dataset"):
        dataset.transitions(derivative_source="smoothed")


@pytest.mark.parametrize("corrupt, message", [
    (lambda t: t[0]["q"].__setitem__((2, 3), np.nan), "NaN"),
    (lambda t: t[1].__setitem__("v", t[1]["v"][:-1]), "shape"),
    (lambda t: t[3].__setitem__("tau_next", np.inf * np.ones(6)), "NaN or inf"),
])
def test_bad_arrays_rejected_and_no_file_left(tmp_path, trajectories, corrupt, message):
    corrupt(trajectories)
    with pytest.raises(InputError, match=message):
        write(tmp_path / "bad.h5", trajectories)
    assert list(tmp_path.iterdir()) == []


def test_a_trajectory_needs_every_array_and_no_other(trajectories):
    arrays = dict(trajectories[2])
    arrays.pop("tau")
    with pytest.raises(InputError, match=r"trajectory 000002: missing arrays \['tau'\]"):
        Trajectory.from_arrays("000002", arrays, "tracking")
    with pytest.raises(InputError, match=r"trajectory 000001: arrays \['torque'\] do not belong to tracking data"):
        Trajectory.from_arrays("000001", dict(trajectories[1], torque=trajectories[1]["tau"]), "tracking")
    loaded = Trajectory.from_arrays("000000", trajectories[0], "tracking")
    assert loaded.num_steps == 5 and sorted(loaded.arrays()) == sorted(trajectories[0])


def test_bad_metadata_rejected(tmp_path, trajectories):
    with pytest.raises(InputError, match="protocol"):
        write_dataset(tmp_path / "x.h5", trajectories, [0] * 4, dict(protocol="nope", sample_period=DT))
    with pytest.raises(InputError, match="sample_period"):
        write_dataset(tmp_path / "x.h5", trajectories, [0] * 4, dict(protocol="tracking", sample_period=-1))
    with pytest.raises(InputError, match="groups"):
        write_dataset(tmp_path / "x.h5", trajectories, [0] * 3, dict(protocol="tracking", sample_period=DT))
    assert list(tmp_path.iterdir()) == []


def test_truncated_file_and_foreign_files_rejected(tmp_path, trajectories):
    path = write(tmp_path / "t.h5", trajectories)
    data = path.read_bytes()
    (tmp_path / "cut.h5").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="truncated"):
        load_dataset(tmp_path / "cut.h5")
    (tmp_path / "text.h5").write_text("not hdf5")
    with pytest.raises(InputError, match="unreadable"):
        load_dataset(tmp_path / "text.h5")
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["x"] = np.zeros(3)
    with pytest.raises(InputError, match="not a stdm-drake dataset"):
        load_dataset(tmp_path / "other.h5")
    with pytest.raises(FileNotFoundError):
        load_dataset(tmp_path / "missing.h5")


def test_values_tampered_after_writing_are_caught(tmp_path, trajectories):
    path = write(tmp_path / "t.h5", trajectories)
    with h5py.File(path, "r+") as f:
        f["trajectories/000001/qdd"][2, 2] = np.nan
    with pytest.raises(InputError, match="000001: qdd contains NaN"):
        load_dataset(path)
    with h5py.File(path, "r+") as f:
        f.attrs["sample_period"] = 0.02
    with pytest.raises(InputError, match="sample period"):
        load_dataset(path)


def test_split_per_group_like_the_paper():
    groups = np.repeat(np.arange(4), 25)
    splits = {n: split_trajectories(groups, n, 5, 15, seed=0, per_group=True) for n in (1, 3, 5)}
    for n, split in splits.items():
        assert len(split.train) == 4 * n and len(split.val) == 20 and len(split.test) == 60
        for g in range(4):
            assert (groups[split.train] == g).sum() == n
        assert not set(split.train) & set(split.val) and not set(split.train) & set(split.test)
        assert not set(split.val) & set(split.test)
        np.testing.assert_array_equal(split.val, splits[1].val)  # shared across training-set sizes
        np.testing.assert_array_equal(split.test, splits[1].test)
    assert set(splits[1].train) <= set(splits[3].train) <= set(splits[5].train)
    again = split_trajectories(groups, 3, 5, 15, seed=0, per_group=True)
    np.testing.assert_array_equal(again.train, splits[3].train)
    assert not np.array_equal(split_trajectories(groups, 3, 5, 15, seed=1, per_group=True).train, again.train)


def test_split_whole_dataset_and_too_large():
    split = split_trajectories(np.zeros(200, int), 40, 40, 120, seed=0, per_group=False)
    assert (len(split.train), len(split.val), len(split.test)) == (40, 40, 120)
    rest = split_trajectories(np.zeros(200, int), 10, 40, None, seed=0, per_group=False)
    assert len(rest.test) == 150
    with pytest.raises(InputError, match="needs 30 trajectories from group 0"):
        split_trajectories(np.repeat(np.arange(4), 25), 10, 5, 15, seed=0, per_group=True)
