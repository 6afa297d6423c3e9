"""The 2 ms loop: data, the default model and the MPC at a 2 ms control period on the UR-10, beside 10 ms.

The 2 ms closed loop (docs/realtime.md, design fixed before the run): data, the default model and the
MPC at a 2 ms control period on the UR-10, beside the same at 10 ms on the same plans.

For each period: `collect --protocol tracking --config SPEC --count 30 --seed 0 --sample-period P` (SPEC:
trajectories/tracking.yaml with 1 s / P steps, the same 1 s plans), `train DATA --seeds 0
--train 4 --val 1 --test 2 --epochs 150` (per initial pose: 16 / 4 / 8 plans; the default model), `mpc DATA --model D=CHECKPOINT --plans 5` (default
settings; the plant as model runs too). Writes docs/results/realtime/loop.json (--write) and prints the
verdict the design fixes.

    python tools/study.py realtime-loop [--folder DIR] [--control-data] [--write]
"""
import argparse
import json
import os
import pathlib
import sys
import tempfile

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):   # one thread (before numpy loads:
    os.environ.setdefault(_variable, "1")                                         # the launcher imports this first)

import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[2]
PERIODS = {"2 ms": 0.002, "10 ms": 0.01}


def run_period(folder: pathlib.Path, period: float, control_data: bool) -> dict:
    """collect, train, mpc at one sample period; the mpc.json runs per model. control_data: the README's control
    recipe's data (dithered torque, ideal sensor) instead of the default tracker and sensor (the library's
    collect, train and mpc: `collect_job`, `train_job`, `run_mpc_study`)."""
    from stdm_drake.closed_loop.study import MpcStudy, run_mpc_study
    from stdm_drake.collection.collect_job import CollectJob, collect_job
    from stdm_drake.learning.settings import TrainSettings
    from stdm_drake.learning.train_job import TrainJob, train_job
    folder.mkdir(parents=True, exist_ok=True)
    data = folder / "tracking.h5"
    if not data.exists():    # the shipped plans (1 s each) at this period: trajectories/tracking.yaml's steps scaled
        steps = round(1.0 / period)
        spec = folder / "tracking.yaml"
        spec.write_text((ROOT / "trajectories" / "tracking.yaml").read_text().replace(
            "    num_steps: 100\n", f"    num_steps: {steps}\n"))
        assert f"num_steps: {steps}" in spec.read_text()
        recipe = (dict(controller=ROOT / "controllers" / "pid_dither.yaml",
                       sensor=ROOT / "controllers" / "sensor_ideal.yaml") if control_data else {})
        collect_job(CollectJob(output=data, protocol="tracking", config=spec, **recipe, count=30, seed=0,
                               sample_period=period, progress=False))
    checkpoint = folder / "D" / "seed0" / "checkpoint.pt"
    if not checkpoint.exists():
        given = dict(seeds=[0], train=4, val=1, test=2, epochs=150)
        train_job(TrainJob(dataset=data, output=folder / "D", settings=TrainSettings(**given), progress=False,
                           given=frozenset(given)))
    study = run_mpc_study(MpcStudy(dataset=data, models=[("D", checkpoint)], plans=5, output=folder / "mpc",
                                   progress=False, force=True))   # (`mpc`'s defaults: the plant as model too)
    for failure in study.failures:
        print(f"realtime-loop, {period:g} s: mpc: {failure}", file=sys.stderr)
    code = 2 if study.failures else 0   # (mpc's exit status)
    report = json.loads((folder / "mpc" / "mpc.json").read_text())
    return dict(exit_status=code, runs=report["runs"], summary=report["summary"])


def verdict(results: dict) -> tuple[str, list[str]]:
    """The design's verdict on the 2 ms loop and the tracking lines."""
    runs = results["2 ms"]["runs"]
    worst = max(run["solve_ms_p95"] for run in runs)
    broken = [run for run in runs if run["limit_violations"] or run["fallbacks"]]
    if broken:
        outcome = f"failed: {len(broken)} run(s) left the limits or fell back"
    elif worst < 2.0:
        outcome = f"real time at 2 ms (worst plan p95 {worst:.2f} ms)"
    else:
        outcome = f"not real time at 2 ms (worst plan p95 {worst:.2f} ms, {worst / 2.0:.2f}x the period)"
    lines = []
    for model in dict.fromkeys(run["model"] for run in runs):
        fast = {run["trajectory"]: run["q_mse_rad2"] for run in runs if run["model"] == model}
        slow = {run["trajectory"]: run["q_mse_rad2"] for run in results["10 ms"]["runs"] if run["model"] == model}
        shared = sorted(set(fast) & set(slow))
        if len(shared) < 2:
            lines.append(f"{model}: fewer than two shared plans, no ratio")
            continue
        logs = np.log([fast[i] / slow[i] for i in shared])
        half = stats.t.ppf(0.975, len(logs) - 1) * logs.std(ddof=1) / np.sqrt(len(logs))
        lines.append(f"{model}: tracking q MSE 2 ms / 10 ms = {np.exp(logs.mean()):.3g}x "
                     f"[{np.exp(logs.mean() - half):.3g}, {np.exp(logs.mean() + half):.3g}] over {len(shared)} plans "
                     f"(2 ms mean {np.mean([fast[i] for i in shared]):.3g}, 10 ms {np.mean([slow[i] for i in shared]):.3g} rad²)")
    return outcome, lines


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--folder", type=pathlib.Path, help="working folder (kept; default a temporary one)")
    parser.add_argument("--control-data", action="store_true",
                        help="run 2: collect as the README's control recipe (dithered PID, ideal sensor)")
    parser.add_argument("--write", action="store_true",
                        help="write docs/results/realtime/loop.json (with --control-data: loop_control_data.json)")
    parser.add_argument("--result", help="write docs/results/realtime/RESULT (a later run's own file: run 3, "
                                         "loop_compiled_step.json; implies --write)")


def run(args: argparse.Namespace) -> int:
    from benchmark_report import provenance
    origin = provenance()      # (at the start: the code this run imports)
    folder = args.folder or pathlib.Path(tempfile.mkdtemp(prefix="realtime_loop_"))
    results = {label: run_period(folder / label.replace(" ", ""), period, args.control_data)
               for label, period in PERIODS.items()}
    outcome, lines = verdict(results)
    for label, result in results.items():
        for row in result["summary"]:
            print(f"{label}: {row['model']}: solve {row['solve_ms_mean']:.2f} ms mean, {row['solve_ms_p95']:.2f} ms p95 "
                  f"(worst plan), q MSE {row['q_mse_rad2']:.3g} rad², limit violations {row['limit_violations']}, "
                  f"fallbacks {row['fallbacks']}")
    print("verdict:", outcome)
    print("\n".join(lines))
    implementations = sorted({run.get("implementation", "") for result in results.values() for run in result["runs"]})
    print("control step:", ", ".join(implementations))
    if args.write or args.result:
        from benchmark_report import machine_description, provenance   # (tools/ is on the path)
        from stdm_drake.files import write_text_atomic
        target = ROOT / "docs" / "results" / "realtime"
        target.mkdir(parents=True, exist_ok=True)
        name = args.result or ("loop_control_data.json" if args.control_data else "loop.json")
        write_text_atomic(target / name, json.dumps(dict(
            verdict=outcome, tracking=lines, machine=machine_description(threads=1), provenance=origin,
            control_step=implementations,
            command=" ".join(["python tools/study.py realtime-loop", *sys.argv[2:]]),
            periods={label: dict(sample_period=PERIODS[label], exit_status=result["exit_status"],
                                 summary=result["summary"],
                                 runs=[{key: value for key, value in run.items() if key != "q_error"}
                                       for run in result["runs"]]) for label, result in results.items()}), indent=1))
        print(f"wrote {target / name}")
    return 0
