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


def test_a_port_that_answers_but_is_no_ray_head_is_one_line_at_once():
    """The newcomer pass: --ray-address at a port that accepts connections but is no Ray head (a web server, any
    service) gave 20 s of Ray's own log lines before the error. The address check now asks for a gRPC server's
    answer to HTTP/2's preface first: a server that answers otherwise, or not at all, is refused in one line."""
    import socket
    import threading
    from stdm_drake.cluster import _check_reachable
    from stdm_drake.errors import InputError

    for reply in (b"HTTP/1.1 400 Bad Request\r\n\r\n", None):
        server = socket.create_server(("127.0.0.1", 0))

        def serve(server=server, reply=reply):
            connection, _ = server.accept()
            with connection:
                connection.recv(64)
                if reply is not None:
                    connection.sendall(reply)
                else:
                    connection.recv(64)   # (silent until the client gives up)

        thread = threading.Thread(target=serve, daemon=True)
        thread.start()
        with server, pytest.raises(InputError, match="the port answers, but not as a Ray head"):
            _check_reachable(f"127.0.0.1:{server.getsockname()[1]}", timeout=0.5)
        thread.join(5)
