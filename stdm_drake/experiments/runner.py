"""Where training jobs run: the local process pool (default) or a Ray cluster (`--backend ray`).

Both backends take the same job list and give the same rows: a job is `run_job(job, cache)` of
`stdm_drake.experiments.jobs`, one torch thread, its seed fixed by the job, so a job's numbers do not
depend on where it ran. The cache of results keyed by configuration stays on the machine that runs
the command: a Ray task trains into a scratch folder on its node and returns the checkpoint and result
files, which the driver writes into the cache.

Datasets go into Ray's object store once (`ray.put`), and a node writes each to a local scratch file
the first time one of its tasks needs it (keyed by the file's SHA-256), so a dataset crosses the
network once per node, not once per job. A task whose worker process dies is retried (`max_retries`);
a task that raises fails the sweep with its own message.
"""
import dataclasses
import hashlib
import os
import pathlib
import sys
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
    config = RunnerConfig(backend=args.backend, workers=args.workers, ray_address=args.ray_address)
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


def _ray_job(job, dataset_content: bytes, dataset_sha256: str) -> tuple[list, dict]:
    """A training job on a Ray worker: the dataset from the object store, training into a scratch cache;
    returns (rows, {file name: bytes}) for the driver's cache."""
    import shutil

    from stdm_drake.experiments.jobs import run_job
    marker = os.environ.get(KILL_ONCE_VARIABLE)
    if marker and not os.path.exists(marker):  # fault injection for the retry test: die once, like a lost node
        pathlib.Path(marker).write_text(str(os.getpid()))
        os._exit(1)
    local = dataclasses.replace(job, dataset=str(node_local_dataset(dataset_content, dataset_sha256)))
    scratch = pathlib.Path(tempfile.mkdtemp(prefix="stdm-drake-job-"))
    try:
        rows = run_job(local, scratch)
        files = {path.name: path.read_bytes() for path in scratch.iterdir() if path.is_file()}
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    for row in rows:
        row.pop("reused", None)
    return rows, files


def run_jobs_on_ray(jobs: list, cache: pathlib.Path, config: RunnerConfig, progress: bool, order: list[int]) -> dict:
    """{job index: rows}; jobs already in the cache are read from it, the rest run as Ray tasks (submitted
    in `order`), their files written into `cache` by this process."""
    from tqdm import tqdm

    from stdm_drake.experiments.jobs import cached_rows
    from stdm_drake.files import atomic_path
    rows_of = {}
    missing = []
    for index in order:
        rows = cached_rows(jobs[index], cache)
        if rows is not None:
            rows_of[index] = rows
        else:
            missing.append(index)
    bar = tqdm(total=len(jobs), initial=len(rows_of), desc="train (ray)", unit="model", disable=not progress,
               file=sys.stderr)
    if missing:
        ray = connect(config)
        task = ray.remote(num_cpus=config.cpus_per_job, max_retries=config.max_retries)(_ray_job)
        datasets = {}
        for index in missing:
            path = jobs[index].dataset
            if path not in datasets:
                content = pathlib.Path(path).read_bytes()
                datasets[path] = (ray.put(content), hashlib.sha256(content).hexdigest())
        pending = {task.remote(jobs[index], *datasets[jobs[index].dataset]): index for index in missing}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            index = pending.pop(done[0])
            try:
                rows, files = ray.get(done[0])
            except ray.exceptions.RayTaskError as error:
                for ref in pending:
                    ray.cancel(ref)
                cause = error.cause if getattr(error, "cause", None) is not None else error
                message = " ".join(str(cause).split())[:400]
                if isinstance(cause, ModuleNotFoundError):
                    message = f"a Ray worker lacks a package ({message}); install stdm-drake on every node"
                raise InputError(f"training job {index} ({jobs[index].experiment} {jobs[index].model_type} seed "
                                 f"{jobs[index].seed}) failed on the cluster: {message}") from None
            for name, content in files.items():
                with atomic_path(cache / name) as temp:
                    temp.write_bytes(content)
            labels = {"experiment": jobs[index].experiment, "train_size": jobs[index].train_size}
            rows_of[index] = [row | labels | {"reused": False} for row in rows]
            bar.update()
    bar.close()
    return rows_of
