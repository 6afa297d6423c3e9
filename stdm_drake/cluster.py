"""Where sweeps run: the local process pool (default) or a Ray cluster (`--backend ray`): the runner
settings, joining a cluster, the one concurrent.futures-style pool over this process, local processes
or Ray (`job_pool`), one-line task errors, and datasets written once per node. Used by `collect`,
`train --seeds`, `sine-sum`, `reproduce` (training jobs and MPC runs) and the studies in tools/.

A task runs with one torch thread and its own seed, so its numbers do not depend on where it ran. A
task whose worker process dies is retried (`max_retries`); a task that raises fails the sweep with its
own message.
"""
import contextlib
import dataclasses
import os
import pathlib
import tempfile

from stdm_drake.errors import InputError
from stdm_drake.interrupts import group_signals_blocked, protected, mark_worker, ignore_interrupts_in_worker
from stdm_drake.files import atomic_path

MAX_WORKERS = 256   # worker processes (each a Python with PyTorch or Drake, 0.2-0.5 GB: 256 is past any one machine)


def check_workers(workers: int) -> None:
    """InputError (one line) unless 1 <= workers <= MAX_WORKERS (--workers of every command)."""
    if not 1 <= workers <= MAX_WORKERS:
        raise InputError(f"--workers must be in 1..{MAX_WORKERS}, got {workers}")


BACKENDS = ("local", "ray")
# Fault injection (tests): a worker that sees this variable, naming a file that does not exist yet, creates
# the file and dies at once, as a worker on a lost node would; Ray must rerun its job.
KILL_ONCE_VARIABLE = "STDM_DRAKE_TEST_KILL_WORKER_ONCE"
RAY_INSTALL_HINT = 'pip install -e ".[ray]"  (or: pip install "ray[default]")'


@dataclasses.dataclass
class RunnerConfig:
    """backend: "local" or "ray"; workers: local processes (local) or, for a local Ray instance started
    by the command, its CPU count; ray_address: a running cluster ("host:port", or "auto"), default the
    RAY_ADDRESS environment variable, else a local instance; cpus_per_job: Ray CPUs each job reserves;
    max_retries: times Ray reruns a job whose worker died."""
    backend: str = "local"
    workers: int = 2
    ray_address: str | None = None
    cpus_per_job: float = 1.0
    max_retries: int = 2

    def validate(self) -> None:
        if self.backend not in BACKENDS:
            raise InputError(f"--backend must be one of {', '.join(BACKENDS)}, got {self.backend!r}")
        check_workers(self.workers)
        if not self.cpus_per_job > 0:
            raise InputError(f"cpus per job must be > 0, got {self.cpus_per_job}")
        if self.max_retries < 0:
            raise InputError(f"max_retries must be >= 0, got {self.max_retries}")
        if self.ray_address and self.backend != "ray":
            raise InputError(f"--ray-address joins a Ray cluster with --backend ray; the {self.backend} backend "
                             "would ignore it")


DEFAULT_RAY_CPUS = 2   # a local Ray instance's CPUs for a command without --workers (train)


def add_runner_arguments(parser) -> None:
    """--backend and --ray-address (a local Ray instance gets the command's --workers CPUs, if it has that
    option, else DEFAULT_RAY_CPUS)."""
    workers = any(action.dest == "workers" for action in parser._actions)
    parser.add_argument("--backend", choices=BACKENDS, default="local",
                        help="where training jobs run: local processes (default) or a Ray cluster")
    parser.add_argument("--ray-address",
                        help="Ray cluster to join with --backend ray (default: $RAY_ADDRESS, else a local Ray "
                             f"instance with {'--workers' if workers else DEFAULT_RAY_CPUS} CPUs)")


def runner_config_from_args(args, *, connect_now: bool = True) -> RunnerConfig:
    """The runner of --backend, --workers and --ray-address, validated; with connect_now a cluster is joined
    at once (an unreachable one is an error before any work), else the job joins it after its own checks."""
    config = RunnerConfig(backend=args.backend, workers=getattr(args, "workers", DEFAULT_RAY_CPUS),
                          ray_address=args.ray_address)
    config.validate()
    if connect_now and config.backend == "ray":
        connect(config)
    return config


def import_ray():
    try:
        import ray
    except ImportError:
        raise InputError(f"--backend ray needs Ray, which is not installed: {RAY_INSTALL_HINT}") from None
    return ray


def connect(config: RunnerConfig):
    """ray.init for `config` (joins the cluster, or starts a local instance); InputError, one line, when
    the cluster cannot be reached. Returns the ray module."""
    ray = import_ray()
    if ray.is_initialized():
        return ray
    address = config.ray_address or os.environ.get("RAY_ADDRESS")
    if address and address != "auto":
        _check_reachable(address)
    try:
        if address:
            ray.init(address=address, logging_level="ERROR", log_to_driver=False)
        else:
            ray.init(num_cpus=config.workers, include_dashboard=False, logging_level="ERROR", log_to_driver=False)
    except Exception as error:  # Ray raises ConnectionError, RuntimeError, AuthenticationError, ...
        text = " ".join(str(error).split())[:300]
        hint = " (a cluster with token authentication needs its token: RAY_AUTH_MODE=token and RAY_AUTH_TOKEN)" \
            if "auth" in text.lower() else ""
        raise InputError(f"cannot join the Ray cluster at {address or 'a new local instance'}: {text}{hint}") from None
    return ray


HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])   # and an empty SETTINGS frame


def _check_reachable(address: str, timeout: float = 3.0) -> None:
    """InputError unless a TCP connection to the head's GCS port opens within `timeout` s and, without TLS
    (RAY_USE_TLS), the port answers HTTP/2's connection preface with a SETTINGS frame as a gRPC server does: ray.init
    itself retries a wrong address for minutes, and a port that answers but is no Ray head for 20 s of Ray's log lines
    (the newcomer pass)."""
    import socket
    host, _, port = address.removeprefix("ray://").rpartition(":")
    plain = os.environ.get("RAY_USE_TLS", "0").lower() in ("0", "false", "")   # (with TLS Ray's own check answers)
    answer = b""
    try:
        with socket.create_connection((host or "127.0.0.1", int(port)), timeout=timeout) as connection:
            if plain:
                connection.sendall(HTTP2_PREFACE)
                with contextlib.suppress(OSError):
                    while len(answer) < 9 and (chunk := connection.recv(9 - len(answer))):
                        answer += chunk
    except ValueError:
        raise InputError(f"--ray-address must be HOST:PORT (the head's GCS port, 6379 by default), got {address!r}") \
            from None
    except OSError as error:
        raise InputError(f"cannot reach the Ray cluster at {address}: {error.strerror or error} (is `ray start "
                         "--head` running there?)") from None
    if plain and (len(answer) < 4 or answer[3] != 4):   # (a frame header: 3 bytes length, 1 byte type; SETTINGS 4)
        raise InputError(f"cannot join the Ray cluster at {address}: the port answers, but not as a Ray head (no gRPC "
                         f"reply within {timeout:g} s; `ray start --head` prints the address to join)")


class InProcessPool:
    """One worker: this process. submit runs the call at once and returns its finished Future (an
    exception is kept in it, as a process pool's would be); map is the built-in map."""

    def submit(self, function, *arguments):
        import concurrent.futures
        future = concurrent.futures.Future()
        try:
            future.set_result(function(*arguments))
        except Exception as error:  # noqa: BLE001 (re-raised by future.result(), as in a process pool)
            future.set_exception(error)
        return future

    def map(self, function, iterable, chunksize: int = 1):
        return map(function, iterable)

    def completed(self, calls):
        """(position, finished Future) of each (function, arguments) in `calls`, one at a time, in order."""
        for position, (function, arguments) in enumerate(calls):
            yield position, self.submit(function, *arguments)


class ProcessPool:
    """Spawned local processes (concurrent.futures.ProcessPoolExecutor), each set up once by the
    pool's initializer."""

    def __init__(self, workers: int, initializer=None, initargs=()):
        import concurrent.futures
        import multiprocessing
        _start_resource_tracker()
        self.executor = concurrent.futures.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                                               initializer=_start_worker,
                                                               initargs=(initializer, initargs))

    def stop(self) -> None:
        """End at once (Ctrl-C, SIGTERM): pending tasks cancelled, the workers terminated and reaped."""
        processes = list((self.executor._processes or {}).values())
        manager = self.executor._executor_manager_thread   # (shutdown forgets it)
        _quiet_about_cancelled_futures()
        self.executor.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.terminate()
        for process in processes:
            process.join(timeout=10)
            if process.is_alive():
                process.kill()
                process.join()
        # The executor's thread closes its wake-up pipe as it ends; Python's exit hook for executors writes to
        # that pipe after checking it is open, unlocked (3.11), so a thread still ending then printed "Exception
        # ignored in threading._shutdown ... Bad file descriptor" after the command's one line. Ended here first.
        if manager is not None:
            manager.join(timeout=10)

    def submit(self, function, *arguments):
        # The executor starts its workers inside submit: blocked signals reach none of them while they start, and
        # `protected` holds a signal another thread took until every started worker has been handed its start-up
        # data (cut in the middle, the worker printed an EOFError traceback)
        with group_signals_blocked(), protected():
            return self.executor.submit(function, *arguments)

    def map(self, function, iterable, chunksize: int = 1):
        with group_signals_blocked(), protected():
            return self.executor.map(function, iterable, chunksize=chunksize)

    def completed(self, calls):
        """(position, Future) of each (function, arguments) in `calls`, all submitted at once, as they finish."""
        import concurrent.futures
        futures = {self.submit(function, *arguments): position for position, (function, arguments) in enumerate(calls)}
        for future in concurrent.futures.as_completed(futures):
            yield futures[future], future


def _quiet_about_cancelled_futures() -> None:
    """The executor's own thread marks the futures of a pool whose workers were terminated as broken; on Python
    3.11 it raises InvalidStateError for one already cancelled (by `shutdown(cancel_futures=True)` or an
    interrupted `map`), a traceback after the command's one-line ending. Python 3.12 ignores that error there;
    so does this hook, for that thread only."""
    import threading
    from concurrent.futures import InvalidStateError, process
    previous = threading.excepthook
    if getattr(previous, "quiet_about_cancelled_futures", False):
        return

    def hook(args):
        if not (issubclass(args.exc_type, InvalidStateError)
                and isinstance(args.thread, process._ExecutorManagerThread)):
            previous(args)

    hook.quiet_about_cancelled_futures = True
    threading.excepthook = hook


_RAY_INITIALIZED: set = set()


def _ray_task(setup, function, *arguments):
    """A task on a Ray worker: the pool's initializer once per worker process (setup: (key, initializer,
    initargs) or None), then function(*arguments)."""
    marker = os.environ.get(KILL_ONCE_VARIABLE)
    if marker and not os.path.exists(marker):  # fault injection for the retry test: die once, like a lost node
        pathlib.Path(marker).write_text(str(os.getpid()))
        os._exit(1)
    mark_worker()
    if setup is not None and setup[0] not in _RAY_INITIALIZED:
        setup[1](*setup[2])
        _RAY_INITIALIZED.add(setup[0])
    return function(*arguments)


class RayPool:
    """The same pool on Ray: submit(function, *arguments) -> a concurrent.futures.Future
    (ObjectRef.future()), so `concurrent.futures.wait` and `as_completed` work unchanged; map in order.
    The function must be importable on the workers (a module-level function of stdm_drake)."""

    def __init__(self, ray, config: RunnerConfig, initializer=None, initargs=()):
        import uuid
        self.ray, self.config = ray, config
        self.setup = (uuid.uuid4().hex, initializer, initargs) if initializer is not None else None
        self.task = ray.remote(num_cpus=config.cpus_per_job, max_retries=config.max_retries)(_ray_task)

    def submit(self, function, *arguments):
        return self.task.remote(self.setup, function, *arguments).future()

    def map(self, function, iterable, chunksize: int = 1):
        return [future.result() for future in [self.submit(function, item) for item in iterable]]

    def completed(self, calls):
        """(position, Future) of each (function, arguments) in `calls`, all submitted at once, as they finish;
        the tasks still pending are cancelled when the caller stops early (an error)."""
        refs = {self.task.remote(self.setup, function, *arguments): position
                for position, (function, arguments) in enumerate(calls)}
        try:
            while refs:
                done, _ = self.ray.wait(list(refs), num_returns=1)
                yield refs.pop(done[0]), done[0].future()
        finally:
            for ref in refs:
                self.ray.cancel(ref)

    def share(self, value):
        """`value` in the object store once (an ObjectRef: tasks given it as an argument get the value)."""
        return self.ray.put(value)


def shared(pool, value):
    """What to pass to pool.submit for a large `value` every task reads: on Ray, one copy in the object
    store (sent to each node once); locally, the value itself."""
    return pool.share(value) if isinstance(pool, RayPool) else value


@contextlib.contextmanager
def job_pool(config: RunnerConfig, initializer=None, initargs=()):
    """The one pool every sweep uses (collection, training jobs, train's seeds, MPC runs, studies):
    submit(function, *arguments) -> Future, map(function, iterable, chunksize) -> results in order and
    completed([(function, arguments), ...]) -> (position, Future) as each finishes, on
    this process (local, 1 worker), `config.workers` spawned processes (local), or Ray. initializer
    (initargs) sets up each worker process once, this process too when it is the worker. On an error
    the tasks not yet started are cancelled."""
    if config.backend == "ray":
        yield RayPool(connect(config), config, initializer, initargs)
        return
    if config.workers == 1:
        if initializer is not None:
            initializer(*initargs)
        yield InProcessPool()
        return
    import concurrent.futures.process
    pool = ProcessPool(config.workers, initializer, initargs)
    try:
        yield pool
    except KeyboardInterrupt:   # Ctrl-C or SIGTERM: stop now, nothing left running (a second Ctrl-C waits)
        with protected():
            pool.stop()
        raise
    except concurrent.futures.process.BrokenProcessPool:
        pool.stop()
        raise InputError("a worker process ended abruptly (killed, or out of memory?); the run stopped, its "
                         "finished files are kept") from None
    except BaseException:
        pool.executor.shutdown(wait=True, cancel_futures=True)
        raise
    pool.executor.shutdown(wait=True)


def _start_resource_tracker() -> None:
    """Start multiprocessing's resource tracker (one per program) with Ctrl-C and SIGHUP blocked for good
    (`interrupts.group_signals_blocked`; it ignores SIGINT and SIGTERM itself): a closing terminal's SIGHUP to
    the process group would kill it while the pool's semaphores still need it (the parent stops the pool). Its
    warning that it cleans up after a program killed with SIGKILL (a Python warning line after the kill) is
    turned off: it passes the interpreter's -W options on."""
    import sys
    from multiprocessing import resource_tracker

    quiet = "ignore:resource_tracker:UserWarning"
    sys.warnoptions.append(quiet)
    try:
        with group_signals_blocked():
            resource_tracker.ensure_running()
    finally:
        sys.warnoptions.remove(quiet)


def _start_worker(initializer, initargs) -> None:
    """A local worker process's start: signals left to the parent (`interrupts.ignore_interrupts_in_worker`),
    Drake's warnings left to the parent too (it parses every description a worker builds a plant of, and shows
    each warning once: `cli.drake_warnings_once`; a worker's errors still reach stderr), then the pool's own
    initializer."""
    import logging
    ignore_interrupts_in_worker()
    logging.getLogger("drake").addFilter(lambda record: record.levelno >= logging.ERROR)
    if initializer is not None:
        initializer(*initargs)


def task_error(error: BaseException, what: str) -> InputError:
    """A one-line InputError for a failed task (Ray wraps the task's exception; the local pool re-raises it)."""
    cause = getattr(error, "cause", None) or error
    message = " ".join(str(cause).split())[:400] or type(cause).__name__
    if isinstance(cause, ModuleNotFoundError):
        message = f"a worker lacks a package ({message}); install stdm-drake on every node"
    return InputError(f"{what} failed: {message}")


def shared_file(pool, path) -> tuple:
    """(content, sha256) to pass, as top-level task arguments, for a file every task on `pool` reads: on
    Ray its bytes in the object store once (Ray hands the task the bytes) and their SHA-256; locally
    (None, None), and the task reads `path` itself (`file_on_this_node`)."""
    if not isinstance(pool, RayPool):
        return None, None
    import hashlib
    content = pathlib.Path(path).read_bytes()
    return pool.share(content), hashlib.sha256(content).hexdigest()


def file_on_this_node(path, content: bytes | None, sha256: str | None) -> str:
    """Where a task finds the file `shared_file` sent: `path` itself locally (content None), on a Ray
    node this node's copy of the bytes (`node_local_dataset`)."""
    return str(path) if content is None else str(node_local_dataset(content, sha256))


def node_local_dataset(content: bytes, sha256: str) -> pathlib.Path:
    """The dataset `content` as a file in this node's scratch folder, written once per node (atomic)."""
    folder = pathlib.Path(tempfile.gettempdir()) / "stdm-drake-ray" / "datasets"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{sha256}.h5"
    if not path.exists():
        with atomic_path(path) as temp:
            temp.write_bytes(content)
    return path
