"""Benchmark: the same training sweep on the local process pool and on a local Ray cluster, in one run.

The sweep: `--jobs` small training jobs (3x100 tanh networks, 200 epochs, alternating D / DD, different
seeds) on one excitation dataset collected here (20 trajectories). Each backend runs it with 1 and with
2 workers (Ray: a head started here on loopback with that many CPUs), into an empty cache each time.
Reported: wall time, per-job overhead against the 1-worker local pool (wall / jobs difference), and the
1 -> 2 worker scaling; the results must be equal across all four runs (checked).

    python tools/bench_ray.py [--jobs 12] [--write]

--write replaces this benchmark's subsection of BENCHMARKS.md (under "## Experiments").
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import pathlib
import secrets
import socket
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
AUTH = {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(32)}
os.environ.update(AUTH)  # before Ray is imported (it reads the mode then)

from benchmark_report import machine_description, start_benchmark, write_benchmark_section  # noqa: E402

SECTION = "Experiments"
RAY = os.path.join(os.path.dirname(sys.executable), "ray")
TIMING = ("train_seconds", "rollout_ms", "reused")


def sweep(folder: pathlib.Path, count: int):
    from stdm_drake.cli import main
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.experiments.jobs import TrainJob
    data = folder / "data.h5"
    assert main(["collect", "--protocol", "excitation", "--count", "20", "--workers", "1", "--quiet", "-o", str(data)]) == 0
    dataset = load_dataset(data)
    common = dict(experiment="sim", dataset=str(data), dataset_sha256=dataset.sha256, train=tuple(range(12)),
                  val=(12, 13, 14), test=tuple(range(15, 20)), activation="tanh", ensemble_size=1, max_epochs=200,
                  patience=200, horizon=10, multistep=False, train_size=12)
    return [TrainJob(model_type="DD" if index % 2 else "D", seed=index, **common) for index in range(count)]


def timed(jobs, cache, workers, runner=None):
    from stdm_drake.experiments.jobs import run_jobs
    started = time.perf_counter()
    rows = run_jobs(jobs, cache, workers, progress=False, runner=runner)
    return time.perf_counter() - started, [{k: v for k, v in dataclasses.asdict(row).items() if k not in TIMING}
                                                for row in rows]


def ray_head(cpus: int) -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    subprocess.run([RAY, "start", "--head", "--node-ip-address=127.0.0.1", f"--port={port}", f"--num-cpus={cpus}",
                    "--include-dashboard=false", "--disable-usage-stats"], env=dict(os.environ, **AUTH), check=True,
                   capture_output=True, timeout=120)
    return f"127.0.0.1:{port}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=12)
    parser.add_argument("--write", action="store_true", help="replace this benchmark's section of BENCHMARKS.md")
    args, origin = start_benchmark(parser)
    import ray

    from stdm_drake.cluster import RunnerConfig
    with tempfile.TemporaryDirectory() as temp:
        folder = pathlib.Path(temp)
        jobs = sweep(folder, args.jobs)
        runs, reference = [], None
        for backend in ("local", "ray"):
            for workers in (1, 2):
                runner = None
                if backend == "ray":
                    address = ray_head(workers)
                    started = time.perf_counter()
                    runner = RunnerConfig(backend="ray", workers=workers, ray_address=address)
                    from stdm_drake.cluster import connect
                    connect(runner)
                    connect_seconds = time.perf_counter() - started
                seconds, rows = timed(jobs, folder / f"cache-{backend}-{workers}", workers, runner)
                if backend == "ray":
                    ray.shutdown()
                    subprocess.run([RAY, "stop", "--force"], capture_output=True, timeout=120)
                reference = reference or rows
                assert rows == reference, f"{backend} with {workers} workers gave other results"
                runs.append((backend, workers, seconds, connect_seconds if backend == "ray" else 0.0))
                print(f"{backend} x{workers}: {seconds:.1f} s", file=sys.stderr)
    base = runs[0][2]
    lines = [f"{args.jobs} training jobs (3x100 tanh, 200 epochs, D and DD alternating, 12 training trajectories each) "
             "on a 20-trajectory excitation dataset; an empty cache per run; the results of all four runs are "
             "equal (checked). Ray: a head started on loopback with that many CPUs, joined with token "
             "authentication; its connection time is listed apart and not in the wall time.", "",
             "| backend | workers | wall s | per job s | overhead per job vs local x1 (s) | speed-up 1 -> 2 | connect s |",
             "|---|---|---|---|---|---|---|"]
    for backend, workers, seconds, connect_seconds in runs:
        one = next(s for b, w, s, _ in runs if b == backend and w == 1)
        lines.append(f"| {backend} | {workers} | {seconds:.1f} | {seconds / args.jobs:.2f} | "
                     f"{(seconds * workers - base) / args.jobs:+.2f} | {one / seconds:.2f}x | "
                     f"{connect_seconds:.1f} |" if backend == "ray" else
                     f"| {backend} | {workers} | {seconds:.1f} | {seconds / args.jobs:.2f} | "
                     f"{(seconds * workers - base) / args.jobs:+.2f} | {one / seconds:.2f}x | |")
    lines += ["", "Overhead per job = (wall x workers - local 1-worker wall) / jobs: the CPU time a job costs beyond "
              "training it in one local process (process start-up, dataset transfer, result shipping).", "",
              f"Machine: {machine_description()}.",]
    body = "\n".join(lines)
    print(body)
    if args.write:
        write_benchmark_section(SECTION, "Training sweep: local pool vs Ray (tools/bench_ray.py)", body, origin)


if __name__ == "__main__":
    main()
