"""Where sweeps run: the local process pool (default) or a Ray cluster (`--backend ray`): the runner
settings, joining a cluster, a concurrent.futures-style pool over either backend, one-line task
errors, and datasets written once per node. Used by `train --seeds`, `sine-sum` and `reproduce`
(whose training jobs: `stdm_drake.experiments.runner`).

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
        if self.workers < 1:
            raise InputError(f"--workers must be >= 1, got {self.workers}")
        if not self.cpus_per_job > 0:
            raise InputError(f"cpus per job must be > 0, got {self.cpus_per_job}")
        if self.max_retries < 0:
            raise InputError(f"max_retries must be >= 0, got {self.max_retries}")


def add_runner_arguments(parser) -> None:
    parser.add_argument("--backend", choices=BACKENDS, default="local",
                        help="where training jobs run: local processes (default) or a Ray cluster")
    parser.add_argument("--ray-address",
                        help="Ray cluster to join with --backend ray (default: $RAY_ADDRESS, else a local Ray "
                             "instance with --workers CPUs)")


def runner_config_from_args(args) -> RunnerConfig:
    config = RunnerConfig(backend=args.backend, workers=getattr(args, "workers", 2), ray_address=args.ray_address)
    config.validate()
    if config.backend == "ray":
        connect(config)  # an unreachable cluster is an error before any work
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


def _check_reachable(address: str, timeout: float = 3.0) -> None:
    """InputError unless a TCP connection to the head's GCS port opens within `timeout` s (ray.init itself
    retries a wrong address for minutes)."""
    import socket
    host, _, port = address.removeprefix("ray://").rpartition(":")
    try:
        with socket.create_connection((host or "127.0.0.1", int(port)), timeout=timeout):
            return
    except ValueError:
        raise InputError(f"--ray-address must be HOST:PORT (the head's GCS port, 6379 by default), got {address!r}") \
            from None
    except OSError as error:
        raise InputError(f"cannot reach the Ray cluster at {address}: {error.strerror or error} (is `ray start "
                         "--head` running there?)") from None


class RayPool:
    """The part of concurrent.futures.Executor the studies use, on Ray: submit(function, *arguments) ->
    a concurrent.futures.Future (ObjectRef.future()), so `concurrent.futures.wait` works unchanged. The
    function must be importable on the workers (a module-level function of stdm_drake)."""

    def __init__(self, ray, config: RunnerConfig):
        self.ray, self.config, self._remote = ray, config, {}

    def submit(self, function, *arguments):
        if function not in self._remote:
            self._remote[function] = self.ray.remote(num_cpus=self.config.cpus_per_job,
                                                     max_retries=self.config.max_retries)(function)
        return self._remote[function].remote(*arguments).future()

    def share(self, value):
        """`value` in the object store once (an ObjectRef: tasks given it as an argument get the value)."""
        return self.ray.put(value)


def shared(pool, value):
    """What to pass to pool.submit for a large `value` every task reads: on Ray, one copy in the object
    store (sent to each node once); locally, the value itself."""
    return pool.share(value) if isinstance(pool, RayPool) else value


@contextlib.contextmanager
def job_pool(config: RunnerConfig):
    """A pool with submit(function, *arguments) -> Future: `config.workers` spawned local processes, or Ray."""
    if config.backend == "ray":
        yield RayPool(connect(config), config)
        return
    import concurrent.futures
    import multiprocessing
    context = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(config.workers, mp_context=context) as pool:
        yield pool


def task_error(error: BaseException, what: str) -> InputError:
    """A one-line InputError for a failed task (Ray wraps the task's exception; the local pool re-raises it)."""
    cause = getattr(error, "cause", None) or error
    message = " ".join(str(cause).split())[:400] or type(cause).__name__
    if isinstance(cause, ModuleNotFoundError):
        message = f"a worker lacks a package ({message}); install stdm-drake on every node"
    return InputError(f"{what} failed: {message}")


def node_local_dataset(content: bytes, sha256: str) -> pathlib.Path:
    """The dataset `content` as a file in this node's scratch folder, written once per node (atomic)."""
    folder = pathlib.Path(tempfile.gettempdir()) / "stdm-drake-ray" / "datasets"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{sha256}.h5"
    if not path.exists():
        from stdm_drake.files import atomic_path
        with atomic_path(path) as temp:
            temp.write_bytes(content)
    return path
