"""`reproduce`'s training jobs on Ray: the same job list and cache as the local pool
(`stdm_drake.experiments.jobs.run_jobs`, which hands this module its job runner and cache lookup), the
same rows.

The cache of results keyed by configuration stays on the machine that runs the command: a Ray task
trains into a scratch folder on its node and returns the checkpoint and result files, which the driver
writes into the cache. Datasets go into Ray's object store once (`ray.put`), and a node writes each to
a local scratch file the first time one of its tasks needs it (keyed by the file's SHA-256), so a
dataset crosses the network once per node, not once per job.
"""
import dataclasses
import hashlib
import os
import pathlib
import sys
import tempfile

from stdm_drake.cluster import KILL_ONCE_VARIABLE, RunnerConfig, connect, node_local_dataset, task_error


def _ray_job(run_job, job, dataset_content: bytes, dataset_sha256: str) -> tuple[list, dict]:
    """A training job on a Ray worker: `run_job(job, cache folder) -> rows` with the dataset from the
    object store, training into a scratch cache; returns (rows, {file name: bytes}) for the driver's cache."""
    import shutil

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


def run_jobs_on_ray(jobs: list, cache: pathlib.Path, config: RunnerConfig, progress: bool, order: list[int], *,
                    run_job, cached_rows) -> dict:
    """{job index: rows}; jobs for which `cached_rows(job, cache)` has rows are read from the cache, the rest
    run as Ray tasks of `run_job(job, folder) -> rows` (a module-level function; submitted in `order`),
    their files written into `cache` by this process."""
    from tqdm import tqdm

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
        pending = {task.remote(run_job, jobs[index], *datasets[jobs[index].dataset]): index for index in missing}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            index = pending.pop(done[0])
            try:
                rows, files = ray.get(done[0])
            except ray.exceptions.RayTaskError as error:
                for ref in pending:
                    ray.cancel(ref)
                raise task_error(error, f"training job {index} ({jobs[index].experiment} {jobs[index].model_type} "
                                        f"seed {jobs[index].seed}) on the cluster") from None
            for name, content in files.items():
                with atomic_path(cache / name) as temp:
                    temp.write_bytes(content)
            labels = {"experiment": jobs[index].experiment, "train_size": jobs[index].train_size}
            rows_of[index] = [row | labels | {"reused": False} for row in rows]
            bar.update()
    bar.close()
    return rows_of
