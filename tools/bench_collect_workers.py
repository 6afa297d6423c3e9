"""Benchmark: `stdm-drake collect` end to end with 1 worker and with 2, at several sizes (issue 57: the default of
2 workers made a small collect slower than 1).

Each case is the command as a user runs it (a new process: imports, planning, worker start-up, simulation,
writing the file), default tracking plans of the UR-10 (100 samples at 10 ms, plant step 1 ms, so 100,000 plant
steps per 100 plans) and default excitation trajectories; the sizes and the worker counts take turns in each
round, and the median over the rounds is reported. The two workers pay off only once a job's simulation outlasts
the start-up of a second process: `collection.collect.default_workers` takes its threshold (in plant steps) from
this run.

    python tools/bench_collect_workers.py [--rounds 3] [--write]

With --write: BENCHMARKS.md's subsection and docs/results/benchmarks/bench_collect_workers.json.
"""
from __future__ import annotations

import argparse
import pathlib
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
from benchmark_report import machine_description, start_benchmark, write_benchmark_section  # noqa: E402

CASES = [("tracking", 4), ("tracking", 16), ("tracking", 48), ("tracking", 100), ("excitation", 50),
         ("excitation", 200)]
STEPS = {"tracking": 100, "excitation": 50}   # samples per trajectory (the shipped protocol files)
SUBSTEPS = 10                                 # plant steps per sample (10 ms / 1 ms)


def run_once(protocol: str, count: int, workers: int, folder: pathlib.Path) -> float:
    """Wall seconds of one `stdm-drake collect` process."""
    output = folder / f"{protocol}_{count}_{workers}.h5"
    command = [sys.executable, "-m", "stdm_drake.cli", "collect", "--protocol", protocol, "--count", str(count),
               "--workers", str(workers), "--quiet", "--force", "-o", str(output)]
    start = time.perf_counter()
    subprocess.run(command, check=True, capture_output=True, env={"DRAKE_ALLOW_NETWORK": "meshcat",
                                                                  "PATH": "/usr/bin:/bin"})
    return time.perf_counter() - start


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--write", action="store_true", help="update BENCHMARKS.md and the results file")
    args, origin = start_benchmark(parser, argv)
    seconds = {(protocol, count, workers): [] for protocol, count in CASES for workers in (1, 2)}
    with tempfile.TemporaryDirectory() as folder:
        for _ in range(args.rounds):
            for protocol, count in CASES:
                for workers in (1, 2):
                    seconds[protocol, count, workers].append(run_once(protocol, count, workers,
                                                                      pathlib.Path(folder)))
    lines = [f"Machine: {machine_description()}.", "",
             "`stdm-drake collect --protocol P --count N --workers W --quiet` end to end (a new process each: "
             "imports, planning, worker start-up, simulation, the file), the UR-10's shipped protocols (tracking: "
             "100 samples, excitation: 50, at 10 ms, plant step 1 ms); median wall seconds over "
             f"{args.rounds} rounds, the cases taking turns.", "",
             "| protocol | trajectories | plant steps | 1 worker (s) | 2 workers (s) | 1 / 2 |", "|---|---|---|---|---|---|"]
    for protocol, count in CASES:
        one = statistics.median(seconds[protocol, count, 1])
        two = statistics.median(seconds[protocol, count, 2])
        lines.append(f"| {protocol} | {count} | {count * STEPS[protocol] * SUBSTEPS} | {one:.2f} | {two:.2f} | "
                     f"{one / two:.2f}x |")
    report = "\n".join(lines)
    print(report)
    if args.write:
        write_benchmark_section("Data collection", "Collect's worker count (tools/bench_collect_workers.py)", report,
                                origin)
        print("updated BENCHMARKS.md and docs/results/benchmarks/bench_collect_workers.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
