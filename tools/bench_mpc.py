"""Benchmark: MPC control-step time and tracking, the compiled control step against the numpy reference (or an
earlier commit), in one run.

Every controller tracks the same held-out tracked plans in closed loop with the UR-10 plant (1 ms step,
10 ms control period, horizon 20, controllers/mpc.yaml, one thread). Models: the plant as model, an
identified robot, the paper's black boxes DD and PE, and the default physics-structured D (next velocity
from the nominal acceleration). Each runs twice:

- "now": this checkout's default, the compiled control step (`Rti(implementation="compiled")`: the real-time
  iteration, the models' linearization and the constrained QP in C++, stdm_drake/core/);
- "baseline": by default (`--baseline numpy`) the numpy reference of the same checkout in the same process
  (`Rti(implementation="numpy")`); or a git revision, checked out into a temporary git worktree and run in a
  child process on the same data, checkpoints and plans (e.g. a3cd989: the project before issue 39).

Goals (issue 54): mean control step <= 0.3 ms and p95 <= 0.5 ms for the plant as model, DD and the default D;
mean <= 0.6 ms for PE (a 5-member ensemble); each model's tracking q MSE within 2 % of its baseline's. A row is
"met" only when its time goals and its tracking goal all hold.

With `--jacobian-refresh all 5 2` (the multi-level iteration, docs/realtime.md's design) both run once per K
(`Rti(jacobian_refresh=K)`, the numpy reference with the same K as its baseline) and a row is "met" where its time
goals hold and its q MSE is within 2 % of the exact step's (K = all, compiled) in the same run, no limit crossed;
the smallest K meeting both is named per model.

Usage: python tools/bench_mpc.py [--dataset D.h5 --checkpoint C.pt ... --identified I.yaml] [--plans 3]
       [--jacobian-refresh all 5 2] [--write]
Without them it collects the identification dataset (100 tracked plans, dithered PID, ideal sensor),
trains DD and PE (the paper's structure, DD with the true held-torque derivative targets and α 1e-3, as
the committed runs) and a default D on 20 plans (seed 0), and identifies the robot, in a temporary folder.
"""
import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile

os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")
for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):   # one thread (before numpy loads)
    os.environ.setdefault(_variable, "1")
ROOT = pathlib.Path(__file__).resolve().parents[1]
BASELINE = "numpy"
TYPES = {"DD": "learned (DD)", "PE": "learned (PE)", "D": "learned (D, default)"}
# issue 54's goals per model: (mean, p95) ms of a control step (None: none stated)
GOALS = {"plant": (0.3, 0.5), TYPES["D"]: (0.3, 0.5), TYPES["DD"]: (0.3, 0.5), TYPES["PE"]: (0.6, None)}


def closed_loops(code_root: pathlib.Path, dataset_path, checkpoints, identified, plans: int,
                 implementation: str | None = None, jacobian_refresh=None, exact: bool = True) -> list[dict]:
    """The `summarize` rows of every model's closed loop with the stdm_drake found at code_root (this
    checkout, or the baseline's worktree): plant, identified robot, then the checkpoints; implementation: the
    real-time iteration's ("compiled", "numpy"; None: the code's default); jacobian_refresh: its K (None: the
    settings file's); exact: also the simulator's plant with exact Jacobians (the tracking reference)."""
    sys.path.insert(0, str(code_root))
    import torch
    torch.set_num_threads(1)
    from stdm_drake.closed_loop.comparison import compare_controllers, held_out_references, summarize
    from stdm_drake.closed_loop.mpc import load_mpc_config
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.identification.identified import load_identified
    from stdm_drake.learning.learned_model import LearnedModel
    from stdm_drake.dynamics.physics import PlantModel
    from stdm_drake.robots.robot import UR10_CONFIG, load_robot
    assert pathlib.Path(sys.modules["stdm_drake"].__file__).resolve().is_relative_to(code_root.resolve())
    dataset, ur10 = load_dataset(dataset_path), load_robot(UR10_CONFIG)
    learned = [LearnedModel(path, robot=ur10) for path in checkpoints]
    for model in learned:
        model.name = TYPES.get(model.checkpoint.metadata.model_type, model.name)
    plant = PlantModel(dataset.sample_period, robot=ur10)
    robot = load_identified(identified).model(ur10, name="identified")
    extra = []
    if hasattr(plant, "for_control"):      # (this checkout: the plant models for control step by RK4)
        # the tracking reference: the simulator's own plant with its own exact Jacobians (central differences of
        # its step: about 0.3 s per control step, so a reference for tracking, not for time)
        extra = [PlantModel(dataset.sample_period, robot=ur10, name="plant (simulator, exact Jacobians)")]
        plant, robot = plant.for_control(), robot.for_control()
    references = held_out_references(dataset, [model.checkpoint for model in learned], plans)
    config = load_mpc_config()
    import dataclasses
    if implementation is not None:
        config = dataclasses.replace(config, optimizer=dataclasses.replace(config.optimizer, implementation=implementation))
        if implementation == "numpy":
            extra = []      # (the tracking reference runs once, in the compiled run)
    if jacobian_refresh is not None:
        config = dataclasses.replace(config, optimizer=dataclasses.replace(config.optimizer,
                                                                           jacobian_refresh=jacobian_refresh))
    if not exact:
        extra = []
    results = compare_controllers([plant, robot, *learned, *extra], references, config, progress=False,
                                  robot=ur10)
    return summarize(results, dataset.sample_period)


def prepare(folder: pathlib.Path):
    """(dataset, checkpoints, identified robot) made with this checkout's command line."""
    sys.path.insert(0, str(ROOT))
    from stdm_drake.cli import main as cli
    from stdm_drake.experiments.jobs import IDENTIFICATION_SETTINGS
    dataset = folder / "identification.h5"
    assert cli(["collect", "--protocol", "tracking", "--controller", str(IDENTIFICATION_SETTINGS["controller"]),
                "--sensor", str(IDENTIFICATION_SETTINGS["sensor"]), "--quiet", "-o", str(dataset)]) == 0
    checkpoints = []
    for kind, options in (("DD", ["--predicts", "state", "--inputs", "raw", "--derivative-source", "true",
                                  "--action-rate", "zero_order_hold", "--alpha", "1e-3"]),
                          ("PE", ["--predicts", "state", "--inputs", "raw"]), ("D", [])):
        assert cli(["train", str(dataset), "--model", kind, *options, "--train", "20", "--val", "3", "--test", "2",
                    "--seeds", "0", "--quiet", "-o", str(folder / kind)]) == 0
        checkpoints.append(folder / kind / "seed0" / "checkpoint.pt")
    identified = folder / "identified.yaml"
    assert cli(["identify", str(dataset), "--train", "20", "--val", "3", "--test", "2", "--quiet",
                "-o", str(identified)]) == 0
    return dataset, checkpoints, identified


def baseline_rows(revision: str, dataset, checkpoints, identified, plans: int) -> list[dict]:
    """The baseline commit's rows: a git worktree of it, the closed loops run by a child process there."""
    folder = pathlib.Path(tempfile.mkdtemp(prefix="bench_mpc_baseline_"))
    worktree, output = folder / "code", folder / "rows.json"
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(worktree), revision], check=True,
                   capture_output=True)
    try:
        command = [sys.executable, str(pathlib.Path(__file__).resolve()), "--child", str(worktree), str(output),
                   "--dataset", str(dataset), "--identified", str(identified), "--plans", str(plans)]
        for path in checkpoints:
            command += ["--checkpoint", str(path)]
        subprocess.run(command, check=True, cwd=worktree)
        return json.loads(output.read_text())
    finally:
        subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(worktree)], check=False,
                       capture_output=True)


def report(now: list[dict], baseline: list[dict], plans: int, revision: str) -> str:
    before = {row["model"]: row for row in baseline}
    header = ("| model | baseline mean (ms) | baseline p95 (ms) | now mean (ms) | now p95 (ms) | speed-up | "
              "goal mean / p95 (ms) | baseline q MSE (rad²) | now q MSE (rad²) | q MSE now / baseline | "
              "limit violations now | met |")
    lines = [header, "|" + "---|" * (header.count("|") - 1)]
    for row in now:
        old = before.get(row["model"])
        goal = GOALS.get(row["model"])
        met = None
        if goal is not None:
            mean_goal, p95_goal = goal
            tracking = old is not None and abs(row["q_mse_rad2"] / old["q_mse_rad2"] - 1.0) <= 0.02
            met = (row["solve_ms_mean"] <= mean_goal and (p95_goal is None or row["solve_ms_p95"] <= p95_goal)
                   and tracking and row["limit_violations"] == 0)
        lines.append("| " + " | ".join([
            row["model"], f"{old['solve_ms_mean']:.3f}" if old else "", f"{old['solve_ms_p95']:.3f}" if old else "",
            f"{row['solve_ms_mean']:.3f}", f"{row['solve_ms_p95']:.3f}",
            f"{old['solve_ms_mean'] / row['solve_ms_mean']:.1f}x" if old else "",
            (f"{goal[0]:g} / {goal[1]:g}" if goal[1] else f"{goal[0]:g} / -") if goal else "",
            f"{old['q_mse_rad2']:.4g}" if old else "", f"{row['q_mse_rad2']:.4g}",
            f"{row['q_mse_rad2'] / old['q_mse_rad2']:.4f}" if old else "", str(row["limit_violations"]),
            ("yes" if met else "no") if goal else ""]) + " |")
    exact = next((row for row in now if row["model"].startswith("plant (simulator")), None)
    notes = []
    if exact is not None and "plant" in before:
        notes = ["", f"Tracking reference: the simulator's own plant with its exact Jacobians tracks at "
                     f"{exact['q_mse_rad2']:.4g} rad² ({exact['q_mse_rad2'] / before['plant']['q_mse_rad2']:.3f}x the "
                     f"baseline's plant model, the RK4 plant model of the baseline's code); "
                     f"the RK4 plant model at {now[0]['q_mse_rad2'] / exact['q_mse_rad2']:.3f}x of it."]
    baseline = ("the numpy reference of this checkout (`implementation: numpy`), in the same process"
                if revision == "numpy" else f"commit {revision}, in a child process")
    return "\n".join([f"{plans} held-out plans of identification.h5 (1 s each, 100 control steps), horizon 20, one "
                      f"iteration per control step, disturbance gain 1.0, limits on (`constraints: soft`), one thread. "
                      f"Baseline: {baseline}; now: this checkout's default (the compiled control step). Met: the "
                      "mean and p95 goals (issue 54) and the q MSE within 2 % of the baseline's, no limit crossed.",
                      "", *lines, *notes])


def multilevel_report(runs: list[dict], plans: int) -> str:
    """The multi-level iteration's table and verdict (docs/realtime.md's design): runs [{K, baseline rows, now
    rows}], the first K "all" (the exact step, the tracking reference)."""
    goals = {**GOALS, "identified": GOALS["plant"]}   # (the plant model with identified parameters)
    exact = {row["model"]: row for row in runs[0]["now"]}
    header = ("| model | K | numpy mean (ms) | compiled mean (ms) | compiled p95 (ms) | goal mean / p95 (ms) | "
              "q MSE (rad²) | q MSE / exact step's | limit violations | fallbacks | verdict |")
    lines = [header, "|" + "---|" * (header.count("|") - 1)]
    smallest = {}
    for model in exact:
        if model not in goals:
            continue
        mean_goal, p95_goal = goals[model]
        for run in runs:
            row = next(r for r in run["now"] if r["model"] == model)
            old = next(r for r in run["baseline"] if r["model"] == model)
            ratio = row["q_mse_rad2"] / exact[model]["q_mse_rad2"]
            fast = row["solve_ms_mean"] <= mean_goal and (p95_goal is None or row["solve_ms_p95"] <= p95_goal)
            safe = row["limit_violations"] == 0 and row["fallbacks"] == 0
            tracks = ratio <= 1.02
            verdict = ("fails (a limit crossed or a fallback)" if not safe else "met" if fast and tracks else
                       f"faster but tracks worse ({ratio:.3f}x)" if fast else "time goal not met")
            if verdict == "met":
                smallest[model] = run["K"]
            lines.append("| " + " | ".join([
                model, str(run["K"]), f"{old['solve_ms_mean']:.3f}", f"{row['solve_ms_mean']:.3f}",
                f"{row['solve_ms_p95']:.3f}", f"{mean_goal:g} / {p95_goal:g}" if p95_goal else f"{mean_goal:g} / -",
                f"{row['q_mse_rad2']:.4g}", f"{ratio:.4f}", str(row["limit_violations"]), str(row["fallbacks"]),
                verdict]) + " |")
    met = [f"{model}: K = {k}" for model, k in smallest.items()]
    summary = ("Met (the smallest K meeting the time and the tracking goal): " + "; ".join(met) + "."
               if met else "No model meets both goals at any K tried.")
    missing = [model for model in goals if model in exact and model not in smallest]
    if missing:
        summary += " Not met: " + ", ".join(missing) + "."
    return "\n".join([f"{plans} held-out plans of identification.h5 (1 s each, 100 control steps), horizon 20, one "
                      "iteration per control step, disturbance gain 1.0, limits on (`constraints: soft`), one thread; "
                      "per K of `jacobian_refresh` the numpy reference (same K) and the compiled step in the same "
                      "process. Tracking: the compiled step's q MSE against the exact step's (K = all) on the same "
                      "plans. Met: mean and p95 goals (issue 54), q MSE within 2 % of the exact step's, no limit "
                      "crossed, no fallback.", "", *lines, "", summary])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=pathlib.Path)
    parser.add_argument("--checkpoint", type=pathlib.Path, action="append", default=[])
    parser.add_argument("--identified", type=pathlib.Path)
    parser.add_argument("--plans", type=int, default=3)
    parser.add_argument("--baseline", default=BASELINE, help="the baseline: 'numpy' (the numpy reference of this checkout, "
                        "the default) or a git revision")
    parser.add_argument("--keep", type=pathlib.Path, help="make the data and checkpoints in this folder (kept)")
    parser.add_argument("--jacobian-refresh", nargs="+", metavar="K", help="the multi-level iteration: run every "
                        "controller once per K (all, or a number of nodes; the first must be all, the exact step)")
    parser.add_argument("--result", default="bench_mpc_multilevel.json",
                        help="with --jacobian-refresh and --write: the results file under docs/results/compiled_step/ "
                             "(a new name per run keeps the earlier runs' files)")
    parser.add_argument("--child", nargs=2, metavar=("CODE", "OUTPUT"), help=argparse.SUPPRESS)
    parser.add_argument("--write", action="store_true", help="update BENCHMARKS.md and docs/results/realtime/")
    sys.path.insert(0, str(ROOT / "tools"))
    from benchmark_report import machine_description, start_benchmark, write_benchmark_section
    args, origin = start_benchmark(parser, threads=1)      # (at the start: the code this run imports)
    if args.child:
        code, output = map(pathlib.Path, args.child)
        rows = closed_loops(code, args.dataset, args.checkpoint, args.identified, args.plans)
        output.write_text(json.dumps(rows))
        return
    if pathlib.Path(args.result).name != args.result or not args.result.endswith(".json"):
        parser.error(f"--result {args.result!r}: a file name ending .json (written under docs/results/compiled_step/)")
    refresh = None
    if args.jacobian_refresh:
        refresh = [value if value == "all" else int(value) for value in args.jacobian_refresh]
        if refresh[0] != "all" or args.baseline != "numpy":
            parser.error("--jacobian-refresh: the first K is all (the exact step), against the numpy baseline")
    given = args.dataset is not None
    if given:
        dataset, checkpoints, identified = args.dataset, args.checkpoint, args.identified
    else:
        folder = args.keep or pathlib.Path(tempfile.mkdtemp(prefix="bench_mpc_"))
        folder.mkdir(parents=True, exist_ok=True)
        dataset, checkpoints, identified = prepare(folder)
    if refresh is not None:
        runs = [dict(K=k, baseline=closed_loops(ROOT, dataset, checkpoints, identified, args.plans, "numpy", k),
                     now=closed_loops(ROOT, dataset, checkpoints, identified, args.plans, "compiled", k,
                                      exact=k == "all")) for k in refresh]
        text = multilevel_report(runs, args.plans) + (f"\n\nMachine: {machine_description(threads=1)}."
                                                      + (" Data and checkpoints from an earlier default run, passed "
                                                         "in." if given else "") + "\n")
        print(text)
        if args.write:
            from stdm_drake.files import write_text_atomic
            write_benchmark_section("Deployment", "The multi-level iteration (tools/bench_mpc.py --jacobian-refresh)",
                                    text, origin, record=False)
            write_text_atomic(ROOT / "docs" / "results" / "compiled_step" / args.result,
                              json.dumps(dict(plans=args.plans, provenance=origin, runs=runs), indent=1))
        return
    if args.baseline == "numpy":
        old = closed_loops(ROOT, dataset, checkpoints, identified, args.plans, implementation="numpy")
    else:
        old = baseline_rows(args.baseline, dataset, checkpoints, identified, args.plans)
    now = closed_loops(ROOT, dataset, checkpoints, identified, args.plans)
    text = report(now, old, args.plans, args.baseline)
    text += (f"\n\nMachine: {machine_description(threads=1)}."
             + (" Data and checkpoints from an earlier default run, passed in." if given else "") + "\n")
    print(text)
    if args.write:
        from stdm_drake.files import write_text_atomic
        compiled = args.baseline == "numpy"
        write_benchmark_section("Deployment", "The compiled MPC control step against the numpy reference (tools/bench_mpc.py)"
                                if compiled else "MPC control step (tools/bench_mpc.py)", text, origin, record=False)
        folder = ROOT / "docs" / "results" / ("compiled_step" if compiled else "realtime")
        folder.mkdir(parents=True, exist_ok=True)
        write_text_atomic(folder / "bench_mpc.json", json.dumps(dict(baseline=args.baseline, plans=args.plans,
                                                                     provenance=origin,
                                                                     baseline_rows=old, now_rows=now), indent=1))


if __name__ == "__main__":
    main()
