"""The one pool (`cluster.job_pool`): the same answers in this process and in spawned processes, each
worker set up once by the initializer, results in order from map and by position from completed, and a
task's error raised where the results are read."""
import os

import pytest

from stdm_drake.cluster import InProcessPool, ProcessPool, RunnerConfig, job_pool

_SETUP = {}


def remember(value):
    _SETUP["value"] = value
    _SETUP["calls"] = _SETUP.get("calls", 0) + 1


def task(x):
    if x < 0:
        raise ValueError(f"negative input {x}")
    return x * x, _SETUP.get("value"), _SETUP.get("calls"), os.getpid()


@pytest.mark.parametrize("workers", [1, 2])
def test_map_and_completed_agree_in_order_and_by_position(workers):
    with job_pool(RunnerConfig(workers=workers), initializer=remember, initargs=("ready",)) as pool:
        assert isinstance(pool, InProcessPool if workers == 1 else ProcessPool)
        mapped = list(pool.map(task, range(6), chunksize=2))
        completed = dict((position, future.result()) for position, future in
                         pool.completed([(task, (x,)) for x in range(6)]))
    assert [row[0] for row in mapped] == [x * x for x in range(6)]
    assert [completed[position][0] for position in range(6)] == [x * x for x in range(6)]
    assert all(row[1] == "ready" and row[2] == 1 for row in mapped + list(completed.values()))  # set up once each
    pids = {row[3] for row in mapped}
    assert (pids == {os.getpid()}) if workers == 1 else (os.getpid() not in pids)


@pytest.mark.parametrize("workers", [1, 2])
def test_a_tasks_error_is_raised_when_its_result_is_read(workers):
    with job_pool(RunnerConfig(workers=workers)) as pool:
        future = pool.submit(task, -1)
        with pytest.raises(ValueError, match="negative input -1"):
            future.result()
        assert pool.submit(task, 3).result()[0] == 9   # the pool still works


def test_an_error_in_the_caller_cancels_the_tasks_not_started():
    with pytest.raises(RuntimeError, match="stop"):
        with job_pool(RunnerConfig(workers=2)) as pool:
            futures = [pool.submit(task, x) for x in range(200)]
            raise RuntimeError("stop")
    assert any(future.cancelled() for future in futures)


def test_a_command_leaves_out_drakes_info_lines_and_restores_its_logger():
    """Held-out run 31: `identify --quiet` printed "INFO:drake:Clarabel returns InsufficientProgress", a solver's
    progress line. While a command runs Drake's logger passes warnings and errors only; afterwards it is as it was."""
    import logging
    from stdm_drake.cli import drake_warnings_once
    logger = logging.getLogger("drake")
    before = logger.level
    with drake_warnings_once("identify"):
        assert not logger.isEnabledFor(logging.INFO) and logger.isEnabledFor(logging.WARNING)
    assert logger.level == before
