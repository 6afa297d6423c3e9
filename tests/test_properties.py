"""Property-based tests (Hypothesis) of what reads user input: the dataset and checkpoint loaders on
corrupted files and arrays, the YAML config loaders on arbitrary documents, and the command line on arbitrary
numbers. The property: every input either loads or is refused with InputError (one line); nothing
else escapes, and nothing is written where it should not be."""
import dataclasses
import pathlib
import shutil

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings, strategies as st

from stdm_drake.errors import InputError

# derandomize: every run explores the same examples, so a CI failure reproduces anywhere (the explicit
# examples below are cases random runs found)
SETTINGS = settings(max_examples=60, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.function_scoped_fixture])

scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8))
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=8),
                                                         st.dictionaries(st.text(max_size=6), inner, max_size=4)),
                      max_leaves=12)


def corrupted(content: bytes, cut: float, flips) -> bytes:
    """`content` cut to the fraction `cut` (1: whole), then bytes set at fractions of its length."""
    data = bytearray(content[:max(1, int(cut * len(content)))] if cut < 1.0 else content)
    for where, byte in flips:
        data[min(int(where * len(data)), len(data) - 1)] = byte
    return bytes(data)


def one_line(error: Exception) -> bool:
    return "\n" not in str(error) and str(error).strip() != ""


@pytest.fixture(scope="module")
def dataset_bytes(excitation_dataset):
    return pathlib.Path(excitation_dataset).read_bytes()


@SETTINGS
@given(cut=st.floats(0.0, 1.0), flips=st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(0, 255)), max_size=6))
def test_a_corrupted_dataset_file_loads_or_is_refused(tmp_path, dataset_bytes, cut, flips):
    from stdm_drake.data.dataset import load_dataset
    path = tmp_path / "corrupt.h5"
    path.write_bytes(corrupted(dataset_bytes, cut, flips))
    try:
        dataset = load_dataset(path)
    except InputError as error:
        assert one_line(error), str(error)
        return
    for index in range(dataset.num_trajectories):          # what loads is finite, well-shaped robot data
        traj = dataset.trajectory(index)
        assert np.all(np.isfinite(traj.q)) and traj.q.shape[0] == traj.tau.shape[0] + 1


@pytest.fixture(scope="module")
def checkpoint_bytes(excitation_dataset, tmp_path_factory):
    from stdm_drake.cli import main
    out = tmp_path_factory.mktemp("ck")
    assert main(["train", str(excitation_dataset), "--model", "D", "--epochs", "1", "--train", "2", "--val", "1",
                 "--quiet", "-o", str(out / "d")]) == 0
    return (out / "d" / "seed0" / "checkpoint.pt").read_bytes()


@SETTINGS
@given(cut=st.floats(0.0, 1.0), flips=st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(0, 255)), max_size=6))
def test_a_corrupted_checkpoint_loads_or_is_refused(tmp_path, checkpoint_bytes, cut, flips):
    """Never code execution (weights_only) and never another exception: InputError or a finite model."""
    import torch
    from stdm_drake.learning.checkpoint import load_checkpoint
    path = tmp_path / "corrupt.pt"
    path.write_bytes(corrupted(checkpoint_bytes, cut, flips))
    try:
        checkpoint = load_checkpoint(path)
    except InputError as error:
        assert one_line(error), str(error)
        return
    assert all(torch.isfinite(value).all() for value in checkpoint.model.state_dict().values())


arrays = st.one_of(
    st.builds(lambda shape, fill: np.full(shape, fill), st.tuples(st.integers(0, 60), st.integers(0, 8)),
              st.floats(allow_nan=True, allow_infinity=True, width=64)),
    st.builds(lambda n: np.array(["0.1"] * n, dtype="S8"), st.integers(1, 5)),
    st.builds(lambda n: np.arange(n, dtype=np.int64), st.integers(0, 60)),
)


@SETTINGS
@given(key=st.sampled_from(["q", "v", "tau", "tau_next", "q_true", "v_true", "qdd", "qdd_end"]), value=arrays)
def test_a_dataset_with_a_replaced_array_loads_or_is_refused(tmp_path, excitation_dataset, key, value):
    from stdm_drake.data.dataset import load_dataset
    path = tmp_path / "edited.h5"
    shutil.copy(excitation_dataset, path)
    with h5py.File(path, "r+") as f:
        group = f["trajectories"][sorted(f["trajectories"])[0]]
        del group[key]
        group[key] = value
    try:
        dataset = load_dataset(path)
    except InputError as error:
        assert one_line(error), str(error)
        return
    traj = dataset.trajectory(0)
    assert np.all(np.isfinite(getattr(traj, key))) and np.max(np.abs(getattr(traj, key)), initial=0.0) < 1e7


def schemas():
    from stdm_drake.closed_loop.mpc import MpcConfig
    from stdm_drake.collection.excitation import Excitation
    from stdm_drake.robots.control import Pid, SensorConfig
    from stdm_drake.collection.plan import Tracking
    from stdm_drake.learning.settings import TrainSettings
    from stdm_drake.robots.robot import RobotConfig
    return [Excitation, Pid, SensorConfig, Tracking, TrainSettings, RobotConfig, MpcConfig]


@pytest.mark.slow
@SETTINGS
@given(schema_index=st.integers(0, 6), document=st.dictionaries(st.text(max_size=10), values, max_size=5),
       use_fields=st.booleans(), data=st.data())
def test_a_yaml_config_loads_or_is_refused(tmp_path, schema_index, document, use_fields, data):
    """Arbitrary documents, and documents over the schema's own keys with arbitrary values."""
    import yaml
    from stdm_drake.config import load_yaml_config
    schema = schemas()[schema_index]
    if use_fields:
        names = [field.name for field in dataclasses.fields(schema)]
        document = {data.draw(st.sampled_from(names)): value for value in document.values()}
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(document, allow_unicode=True))
    try:
        config = load_yaml_config(path, schema)
        if schema.__name__ == "RobotConfig":
            from stdm_drake.robots.robot import Robot
            Robot(config, tmp_path)
    except InputError as error:
        assert one_line(error), str(error)


@pytest.mark.slow
@SETTINGS
@given(count=st.integers(-5, 10**6), workers=st.integers(-3, 64), seed=st.integers(-2**40, 2**40),
       period=st.one_of(st.sampled_from([0.01, 0.004, 0.0105]), st.floats(allow_nan=True, allow_infinity=True),
                        st.just(1.797693134862316e+305)),
       step=st.one_of(st.just(0.001), st.floats(allow_nan=True, allow_infinity=True)))
@example(count=0, workers=1, seed=0, period=0.01, step=0.001)     # each check alone (the others valid)
@example(count=1, workers=0, seed=0, period=0.01, step=0.001)
@example(count=1, workers=1, seed=-1, period=0.01, step=0.001)
@example(count=1, workers=1, seed=0, period=0.0105, step=0.001)
@example(count=1, workers=1, seed=0, period=0.01, step=0.0)
@example(count=2, workers=1, seed=3, period=0.01, step=0.001)     # all valid: the work is reached
def test_collect_numbers_are_checked_before_any_work(tmp_path, capsys, monkeypatch, count, workers, seed, period,
                                                     step):
    """With an output that would be accepted, the simulation is reached exactly when every number is
    valid (count in 1..100000, workers >= 1; seed >= 0; period and plant step finite > 0, the period a whole
    multiple of the step, at most 10000 of them, the shipped excitation's highest frequency, 10 rad/s, within the
    period's Nyquist frequency pi / period); otherwise exit 2 with one line and no file."""
    import math

    from stdm_drake.cli import main
    from stdm_drake.collection import collect_job

    class ReachedTheWork(Exception):
        """Raised where the simulation would start."""

    def no_simulation(*args, **kwargs):
        raise ReachedTheWork

    monkeypatch.setattr(collect_job, "collect", no_simulation)
    capsys.readouterr()
    output = tmp_path / "data.h5"
    argv = ["collect", "--protocol", "excitation", "--count", str(count), "--workers", str(workers), "--seed",
            str(seed), "--sample-period", repr(period), "--plant-time-step", repr(step), "--quiet", "-o", str(output)]
    ratio = period / step if math.isfinite(period) and math.isfinite(step) and step > 0 else math.nan
    valid = (1 <= count <= 100_000 and workers >= 1 and seed >= 0 and math.isfinite(period) and period > 0
             and math.isfinite(step) and step > 0 and ratio <= 10_000 and abs(ratio - round(ratio)) <= 1e-9
             and round(ratio) >= 1 and 10.0 <= math.pi / period)
    try:
        status = main(argv)
    except ReachedTheWork:
        assert valid, (count, workers, seed, period, step)
    else:
        assert not valid and status == 2, (count, workers, seed, period, step, status)
        error = capsys.readouterr().err
        assert error.count("\n") == 1, error
    assert not output.exists()


@SETTINGS
@example(flag="--split-seed", value="-1")
@example(flag="--epochs", value="-3")
@example(flag="--lr", value="nan")
@given(flag=st.sampled_from(["--epochs", "--patience", "--batch-size", "--lr", "--alpha", "--hidden-width",
                             "--hidden-layers", "--ensemble-size", "--train", "--val", "--test", "--threads",
                             "--weight-decay", "--checkpoint-every", "--min-lr", "--split-seed"]),
       value=st.one_of(st.integers(-10**9, 10**9).map(str), st.floats(allow_nan=True, allow_infinity=True).map(repr),
                       st.text(max_size=6)))
def test_train_flags_are_checked_before_the_dataset_is_read(tmp_path, capsys, flag, value):
    """Any value of any numeric flag, with an output that would be accepted and a missing dataset: exit 2
    with one line and no output. A value that is not a number, not finite or negative is refused by the
    flag checks before the dataset is opened (the error does not name the dataset); a valid one gets as
    far as the missing dataset."""
    import math

    from stdm_drake.cli import main
    capsys.readouterr()
    output = tmp_path / "run"
    assert main(["train", str(tmp_path / "missing.h5"), flag, value, "--quiet", "-o", str(output)]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1, error
    try:
        number = float(value)
    except ValueError:
        number = math.nan
    if not math.isfinite(number) or number < 0:
        assert "missing.h5" not in error, (flag, value, error)
    assert not output.exists() or not any(output.iterdir())
