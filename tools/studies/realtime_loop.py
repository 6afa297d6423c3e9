"""The loop at the robot's rate: data, the default model and the MPC at the robot's control period, beside 10 ms.

The closed loop at the robot's own rate (docs/realtime.md, each design fixed before its run): data, the default
model and the MPC at the UR-10's 2 ms control period (`--robot ur10`, the default) or the Franka Panda's 1 ms
(`--robot panda`), beside the same at 10 ms on the same plans.

For each period: `collect --protocol tracking --config SPEC --count 30 --seed 0 --sample-period P` (SPEC:
the UR-10's trajectories/tracking.yaml, the Panda's tracking spec derived from its description
(`plan.derived_tracking_spec`, plans of 1 s), with 1 s / P steps: the same 1 s plans at both periods), `train
DATA --seeds 0 --train 4 --val 1 --test 2 --epochs 150` (per initial pose: 16 / 4 / 8 plans; the default model),
`mpc DATA --model D=CHECKPOINT --plans 5` (default settings; the plant as model runs too). With --control-data
the README's control recipe collects (dithered PID, ideal sensor; the Panda's PID and dither sized from its
inertia, `controllers/pid_dither_sized.yaml`). Writes docs/results/realtime/loop.json (--write; --result names
another file) and prints the verdict the design fixes.

    python tools/study.py realtime-loop [--robot ur10|panda] [--folder DIR] [--control-data] [--write | --result NAME]
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
# robot -> (its config, its control period's label and period, the control recipe's controller)
ROBOTS = {"ur10": (ROOT / "models" / "ur10.yaml", "2 ms", 0.002, ROOT / "controllers" / "pid_dither.yaml"),
          "panda": (ROOT / "models" / "panda.yaml", "1 ms", 0.001, ROOT / "controllers" / "pid_dither_sized.yaml")}
SLOW = ("10 ms", 0.01)


def tracking_spec(robot_name: str, path: pathlib.Path, steps: int) -> None:
    """Write the 1 s plans' tracking spec at `steps` steps: the UR-10's shipped file, or the spec derived from the
    robot's description (plans of 1 s: 100 steps at 10 ms) as YAML."""
    if robot_name == "ur10":
        path.write_text((ROOT / "trajectories" / "tracking.yaml").read_text().replace(
            "    num_steps: 100\n", f"    num_steps: {steps}\n"))
        assert f"num_steps: {steps}" in path.read_text()
        return
    import dataclasses
    import yaml
    from stdm_drake.collection.plan import derived_tracking_spec
    from stdm_drake.robots.robot import load_robot
    spec = derived_tracking_spec(load_robot(ROBOTS[robot_name][0]), sample_period=0.01)
    sampling = dataclasses.asdict(spec.sampling)
    sampling["num_steps"] = steps
    body = yaml.safe_dump(dict(sampling=sampling), sort_keys=False)
    planner = yaml.safe_dump(dataclasses.asdict(spec.planner), sort_keys=False)
    path.write_text(f"protocol: !Tracking\n" + "".join(f"  {line}\n" for line in body.splitlines())
                    + f"  planner: !{type(spec.planner).__name__}\n"
                    + "".join(f"    {line}\n" for line in planner.splitlines()))


def run_period(folder: pathlib.Path, period: float, control_data: bool, robot_name: str = "ur10") -> dict:
    """collect, train, mpc at one sample period; the mpc.json runs per model. control_data: the README's control
    recipe's data (dithered torque, ideal sensor) instead of the default tracker and sensor (the library's
    collect, train and mpc: `collect_job`, `train_job`, `run_mpc_study`)."""
    from stdm_drake.closed_loop.study import MpcStudy, run_mpc_study
    from stdm_drake.collection.collect_job import CollectJob, collect_job
    from stdm_drake.learning.settings import TrainSettings
    from stdm_drake.learning.train_job import TrainJob, train_job
    folder.mkdir(parents=True, exist_ok=True)
    data = folder / "tracking.h5"
    robot, _, _, controller = ROBOTS[robot_name]
    if not data.exists():    # the robot's plans (1 s each) at this period
        spec = folder / "tracking.yaml"
        tracking_spec(robot_name, spec, round(1.0 / period))
        recipe = (dict(controller=controller, sensor=ROOT / "controllers" / "sensor_ideal.yaml")
                  if control_data else {})
        collect_job(CollectJob(output=data, protocol="tracking", config=spec, **recipe, count=30, seed=0,
                               robot=robot, sample_period=period, progress=False))
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


def verdict(results: dict, label: str = "2 ms") -> tuple[str, list[str]]:
    """The design's verdict on the loop at the robot's period (`label`, "2 ms" or "1 ms") and the tracking lines."""
    runs = results[label]["runs"]
    period_ms = float(label.split()[0])
    worst = max(run["solve_ms_p95"] for run in runs)
    broken = [run for run in runs if run["limit_violations"] or run["fallbacks"]]
    if broken:
        outcome = f"failed: {len(broken)} run(s) left the limits or fell back"
    elif worst < period_ms:
        outcome = f"real time at {label} (worst plan p95 {worst:.2f} ms)"
    else:
        outcome = (f"not real time at {label} (worst plan p95 {worst:.2f} ms, {worst / period_ms:.2f}x the "
                   "period)")
    lines = []
    for model in dict.fromkeys(run["model"] for run in runs):
        fast = {run["trajectory"]: run["q_mse_rad2"] for run in runs if run["model"] == model}
        slow = {run["trajectory"]: run["q_mse_rad2"] for run in results[SLOW[0]]["runs"] if run["model"] == model}
        shared = sorted(set(fast) & set(slow))
        if len(shared) < 2:
            lines.append(f"{model}: fewer than two shared plans, no ratio")
            continue
        logs = np.log([fast[i] / slow[i] for i in shared])
        half = stats.t.ppf(0.975, len(logs) - 1) * logs.std(ddof=1) / np.sqrt(len(logs))
        lines.append(f"{model}: tracking q MSE {label} / 10 ms = {np.exp(logs.mean()):.3g}x "
                     f"[{np.exp(logs.mean() - half):.3g}, {np.exp(logs.mean() + half):.3g}] over {len(shared)} plans "
                     f"({label} mean {np.mean([fast[i] for i in shared]):.3g}, 10 ms "
                     f"{np.mean([slow[i] for i in shared]):.3g} rad²)")
    return outcome, lines


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", choices=sorted(ROBOTS), default="ur10",
                        help="the UR-10 at its 2 ms period (the default) or the Franka Panda at its 1 ms")
    parser.add_argument("--folder", type=pathlib.Path, help="working folder (kept; default a temporary one)")
    parser.add_argument("--control-data", action="store_true",
                        help="run 2: collect as the README's control recipe (dithered PID, ideal sensor)")
    parser.add_argument("--write", action="store_true",
                        help="write docs/results/realtime/loop.json (with --control-data: loop_control_data.json)")
    parser.add_argument("--result", help="write docs/results/realtime/RESULT (a later run's own file: run 3, "
                                         "loop_compiled_step.json; implies --write)")


def run(args: argparse.Namespace) -> int:
    folder = args.folder or pathlib.Path(tempfile.mkdtemp(prefix="realtime_loop_"))
    _, label, period, _ = ROBOTS[args.robot]
    periods = {label: period, SLOW[0]: SLOW[1]}
    results = {name: run_period(folder / name.replace(" ", ""), value, args.control_data, args.robot)
               for name, value in periods.items()}
    outcome, lines = verdict(results, label)
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
        from stdm_drake.files import write_text_atomic
        target = ROOT / "docs" / "results" / "realtime"
        target.mkdir(parents=True, exist_ok=True)
        name = args.result or ("loop_control_data.json" if args.control_data else "loop.json")
        write_text_atomic(target / name, json.dumps(dict(
            written_by="tools/study.py realtime-loop", provenance=args.provenance, verdict=outcome, tracking=lines,
            control_step=implementations,
            robot=args.robot,
            periods={label: dict(sample_period=periods[label], exit_status=result["exit_status"],
                                 summary=result["summary"],
                                 runs=[{key: value for key, value in run.items() if key != "q_error"}
                                       for run in result["runs"]]) for label, result in results.items()}), indent=1))
        print(f"wrote {target / name}")
    return 0
