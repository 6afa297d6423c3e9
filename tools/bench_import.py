"""Benchmark: `stdm-drake import` of one hour of a UR arm's RTDE log at 500 Hz (1.8 M rows), on one core.

The log: the project's simulator writes 4 tracked plans of the UR-10 at 500 Hz as an RTDE recording (space
delimited, the fields `stdm_drake.data.logs.simulated.write_rtde_csv` writes: timestamp, the plan, target_moment,
actual_q, actual_qd, actual_current and the three mode fields: 46 columns), tiled with shifted timestamps to
`--rows` rows (1 s without rows between repetitions of the four plans). Each case runs in its own process
pinned to one core; time and peak memory (max RSS) of:

  import      the command itself (streaming in blocks of 65536 lines, each piece written as it closes)
  loadtxt     the baseline: numpy.loadtxt of the same columns of the whole file in one call (parsing only, no
              splitting, resampling or writing: what reading the file at once costs)

    python tools/bench_import.py [--rows 1800000] [--folder /tmp/bench_import] [--write]
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))
os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")

from benchmark_report import machine_description, start_benchmark, write_benchmark_section  # noqa: E402

GOAL_SECONDS = 60.0

CASE = """
import json, os, resource, sys, time
os.sched_setaffinity(0, {{min(os.sched_getaffinity(0))}})
started = time.perf_counter()
{body}
print(json.dumps(dict(seconds=time.perf_counter() - started,
                      peak_mib=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)))
"""
IMPORT = """
from stdm_drake.cli import main
assert main(["import", {log!r}, "-o", {out!r}, "--quiet", "--force"]) == 0
"""
LOADTXT = """
import numpy as np
names = open({log!r}).readline().split()
use = [i for i, name in enumerate(names) if name == "timestamp" or name.startswith(("actual_q", "target_"))]
values = np.loadtxt({log!r}, skiprows=1, usecols=use)
print(values.shape, file=sys.stderr)
"""


def short_log(folder: pathlib.Path) -> pathlib.Path:
    """4 plans of 1 s at 500 Hz as an RTDE recording (collected once)."""
    from stdm_drake.cli import main
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.data.logs import simulated
    from stdm_drake.paths import TRAJECTORIES_DIR
    data_path, log = folder / "sim500.h5", folder / "short.csv"
    if not log.exists():
        spec = folder / "tracking_500hz.yaml"
        spec.write_text((TRAJECTORIES_DIR / "tracking.yaml").read_text().replace("num_steps: 100", "num_steps: 500"))
        assert main(["collect", "--protocol", "tracking", "--config", str(spec), "--count", "4", "--seed", "3",
                     "--sample-period", "0.002", "--workers", "1", "--quiet", "--force", "-o", str(data_path)]) == 0
        simulated.write_rtde_csv(load_dataset(data_path), log)
    return log


def tiled_log(short: pathlib.Path, rows: int, path: pathlib.Path) -> pathlib.Path:
    """`short`'s rows repeated (timestamps shifted by its span plus 1 s each time) to `rows` rows."""
    lines = short.read_text().splitlines(keepends=True)
    header, body = lines[0], lines[1:]
    stamps = [float(line.split(" ", 1)[0]) for line in body]
    rests = [line.split(" ", 1)[1] for line in body]
    span = stamps[-1] - stamps[0] + 1.0
    written = 0
    with open(path, "w") as file:
        file.write(header)
        repetition = 0
        while written < rows:
            offset = repetition * span
            take = min(len(body), rows - written)
            file.write("".join(f"{stamps[i] + offset!r} {rests[i]}" for i in range(take)))
            written += take
            repetition += 1
    return path


def run_case(body: str) -> dict:
    result = subprocess.run([sys.executable, "-c", CASE.format(body=body)], capture_output=True, text=True,
                            env=dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(ROOT)), timeout=3600)
    if result.returncode != 0:
        raise RuntimeError(result.stderr[-2000:])
    return json.loads(result.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=1_800_000, help="rows of the log (default: an hour at 500 Hz)")
    parser.add_argument("--folder", type=pathlib.Path, default=pathlib.Path("/tmp/bench_import"))
    parser.add_argument("--write", action="store_true", help="update BENCHMARKS.md")
    args, origin = start_benchmark(parser, argv)
    args.folder.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    log = tiled_log(short_log(args.folder), args.rows, args.folder / "hour.csv")
    size = log.stat().st_size / 2**20
    print(f"log: {args.rows} rows, {size:.0f} MiB, written in {time.perf_counter() - started:.0f} s", flush=True)
    imported = run_case(IMPORT.format(log=str(log), out=str(args.folder / "hour.h5")))
    print(f"import: {imported['seconds']:.1f} s, peak {imported['peak_mib']:.0f} MiB", flush=True)
    baseline = run_case(LOADTXT.format(log=str(log)))
    print(f"loadtxt (baseline): {baseline['seconds']:.1f} s, peak {baseline['peak_mib']:.0f} MiB", flush=True)
    from stdm_drake.data.dataset import load_dataset
    data = load_dataset(args.folder / "hour.h5")
    record = data.metadata.record["import"]["trajectories"]
    report = "\n".join([
        f"Machine: {machine_description()}; each case in its own process pinned to one core.",
        "",
        f"An RTDE recording of {args.rows:,} rows (one hour at 500 Hz; 46 fields, space delimited, {size:.0f} MiB) of "
        f"the simulated UR-10; the import wrote {data.num_trajectories} trajectories ({record['gaps']} gaps). "
        f"Goal: import <= {GOAL_SECONDS:g} s on one core, memory bounded (not growing with the log).", "",
        "| case | s | peak memory (MiB) |", "|---|---|---|",
        f"| `stdm-drake import` (streaming: parse, split, resample, check, write) | {imported['seconds']:.1f} | "
        f"{imported['peak_mib']:.0f} |",
        f"| numpy.loadtxt of the used columns at once (baseline: parsing only) | {baseline['seconds']:.1f} | "
        f"{baseline['peak_mib']:.0f} |", ""])
    print(report)
    if args.write:
        write_benchmark_section("Real logs", "Import of an hour of RTDE log (tools/bench_import.py)", report, origin)
    return 0 if imported["seconds"] <= GOAL_SECONDS else 1


if __name__ == "__main__":
    sys.exit(main())
