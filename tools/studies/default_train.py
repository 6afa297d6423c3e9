"""The default-train study: whether the default `train` learns on every protocol the toolbox ships.

docs/learning.md, "A default that learns"; design committed before the first run.

Five datasets, each as a new user makes it (seed 27, never used by another study): the default excitation
protocol, tracked plans (the paper's protocol, collect's default sensor), the identification protocol
(pid_dither.yaml with sensor_ideal.yaml, the README's MPC recipe), an imported log (tracked plans with the ideal
sensor written as a UR RTDE recording with timing jitter and dropped rows, then `stdm-drake import`) and the
Panda preset's tracked plans. On each, `train DATASET` with no flags but the seeds and output ("default") and
`train DATASET --model D` ("D"), the same seeds, the same default split; every model is evaluated on the
split's test trajectories (never used for any choice): one-step MSE of q and v beside the Euler step and
"v unchanged", the sensor's noise floor where the data have a truth, and `physics.learning_verdict`. Paired by
seed, D / default with a 95 % interval (`stdm_drake.stats.paired_ratio`).

    python tools/study.py default-train [--quick] [--data /tmp/default_train_study] [-o docs/results/default_train]
    python tools/study.py default-train --protocols excitation --seeds 5 6 7 8 9 10 11 12 13 14 \
        -o docs/results/default_train/replication      # run 1's replication (docs/learning.md)
    python tools/study.py default-train --data-seed 28 --data /tmp/default_train_study_28 \
        -o docs/results/default_train/run2             # run 2: the selection rule, on new data
"""
from __future__ import annotations

import argparse
import json
import pathlib
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
PROTOCOLS = ("excitation", "tracking", "identification", "imported_log", "panda")
DATA_SEED = 27
MARGIN = 1.10   # the default's MSE at most 10 % above D's
# count: trajectories collected (the log: plans); seeds: models per configuration; train_settings: `TrainSettings`
# fields set in both configurations (the full run sets none: train's defaults)
FULL = dict(count=60, log_count=40, seeds=(0, 1, 2, 3, 4), train_settings={})
QUICK = dict(count=12, log_count=8, seeds=(0, 1), train_settings=dict(epochs=5))
SMALL = dict(count=24, log_count=16, seeds=(0,), train_settings=dict(epochs=60))   # the test's (tests/test_default_train.py)


def collect(folder: pathlib.Path, design: dict, data_seed: int = DATA_SEED) -> dict:
    """The five datasets in `folder` (made once; an existing file is kept), {protocol: path}: `collect` and
    `import` as a new user runs them (the library's jobs with the commands' defaults)."""
    from stdm_drake.collection.collect_job import CollectJob, collect_job
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.data.logs import simulated
    from stdm_drake.data.logs.import_job import ImportJob, import_job
    from stdm_drake.paths import CONTROLLERS_DIR, MODELS_DIR
    folder.mkdir(parents=True, exist_ok=True)
    common = dict(count=design["count"], seed=data_seed, workers=1, progress=False)
    jobs = {
        "excitation": dict(protocol="excitation"),
        "tracking": dict(protocol="tracking"),
        "identification": dict(protocol="tracking", controller=CONTROLLERS_DIR / "pid_dither.yaml",
                               sensor=CONTROLLERS_DIR / "sensor_ideal.yaml"),
        "panda": dict(protocol="tracking", robot=MODELS_DIR / "panda.yaml"),
    }
    paths = {name: folder / f"{name}.h5" for name in PROTOCOLS}
    for name, settings in jobs.items():
        if not paths[name].exists():
            collect_job(CollectJob(output=paths[name], **common, **settings))
    if not paths["imported_log"].exists():
        original, log = folder / "log_original.h5", folder / "log_record.csv"
        if not original.exists():
            collect_job(CollectJob(output=original, protocol="tracking", sensor=CONTROLLERS_DIR / "sensor_ideal.yaml",
                                   **dict(common, count=design["log_count"])))
        simulated.write_rtde_csv(load_dataset(original), log)
        import_job(ImportJob(log=log, output=paths["imported_log"], progress=False))
    return paths


def train_settings(config: str, design: dict):
    """The `TrainSettings` of one configuration ("default": DD with train's other defaults, what `train` ran by default
    until the settling experiment made naive D the default (docs/settling.md); "D": `--model D`) with the design's
    seeds and settings, and the fields set (what a user would have given as flags)."""
    from stdm_drake.learning.settings import TrainSettings
    given = dict(design["train_settings"], seeds=list(design["seeds"]), model="D" if config == "D" else "DD")
    return TrainSettings(**given), frozenset(given)


def run_train(dataset: pathlib.Path, output: pathlib.Path, config: str, design: dict) -> tuple[float, str]:
    """One `train` of a configuration on one dataset (in a pool worker, one torch thread: train's default):
    (seconds, what it printed)."""
    import contextlib
    import io

    from stdm_drake.learning.train_job import TrainJob, train_job
    settings, given = train_settings(config, design)
    printed = io.StringIO()
    started = time.perf_counter()
    with contextlib.redirect_stdout(printed), contextlib.redirect_stderr(printed):
        train_job(TrainJob(dataset=dataset, output=output, settings=settings, progress=False, given=given))
    return time.perf_counter() - started, printed.getvalue()


def train_all(paths: dict, runs: pathlib.Path, design: dict, workers: int, protocols=PROTOCOLS) -> dict:
    """Every (protocol, configuration) trained into runs/<protocol>_<config> (kept when its summary exists; what
    each printed in runs/<protocol>_<config>.log), `workers` at a time; returns {folder name: seconds} of the runs
    made now."""
    from stdm_drake.cluster import RunnerConfig, job_pool
    jobs = {f"{name}_{config}": (paths[name], runs / f"{name}_{config}", config, design)
            for name in protocols for config in ("default", "D") if not (runs / f"{name}_{config}" / "summary.json").exists()}
    seconds = {}
    with job_pool(RunnerConfig(workers=workers)) as pool:
        for position, future in pool.completed([(run_train, arguments) for arguments in jobs.values()]):
            folder = list(jobs)[position]
            elapsed, output = future.result()
            (runs / f"{folder}.log").write_text(output)
            seconds[folder] = round(elapsed, 1)
            print(f"{folder}: {elapsed:.0f} s", flush=True)
    return seconds


def evaluate(paths: dict, runs: pathlib.Path, design: dict, protocols=PROTOCOLS) -> dict:
    """Per protocol: each model's test errors beside the Euler step, its verdict, its validation entry from
    train's summary.json, and the paired ratios D / default (q and v one step)."""
    from stdm_drake.data.compatibility import shipped_preset_of
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.data.inspect import noise_floor
    from stdm_drake.dynamics.model_files import load_model
    from stdm_drake.dynamics.physics import ConstantVelocity
    from stdm_drake.learning.evaluate import compare_with_baselines
    from stdm_drake.robots.robot import load_robot
    from stdm_drake.stats import paired_ratio
    results = {}
    for name in protocols:
        dataset = load_dataset(paths[name])
        robot = load_robot(shipped_preset_of(dataset))
        summaries = {config: json.loads((runs / f"{name}_{config}" / "summary.json").read_text())
                     for config in ("default", "D")}
        test = summaries["D"]["split"]["test"]
        assert test == summaries["default"]["split"]["test"], name   # the same held-out trajectories
        models = [load_model(runs / f"{name}_{config}" / f"seed{seed}" / "checkpoint.pt", robot,
                             name=f"{config} seed {seed}") for config in ("default", "D") for seed in design["seeds"]]
        floor = noise_floor(dataset, test)
        rows = compare_with_baselines(models + [ConstantVelocity(robot.state_dim, robot.action_dim, dataset.sample_period)],
                                      dataset.transitions(test), None, noise_floor=floor)
        errors = {row.name: dict(q=row.one_step.angle_mse, v=row.one_step.velocity_mse, ratio_to_euler_q=row.ratio_q,
                                 ratio_to_velocity_unchanged_v=row.ratio_v, over_noise_floor_q=row.floor_ratio_q,
                                 over_noise_floor_v=row.floor_ratio_v, verdict=row.verdict) for row in rows}
        chosen = {str(seed): summaries["default"]["seeds"][str(seed)]["validation"]["models"][0]["name"]
                  for seed in design["seeds"]}
        ratios = {}
        for key in ("q", "v"):
            ratio = paired_ratio([errors[f"D seed {s}"][key] for s in design["seeds"]],
                                 [errors[f"default seed {s}"][key] for s in design["seeds"]])
            ratios[key] = ratio.as_dict() | dict(margin_verdict=margin_verdict(ratio))
        learned = {config: sum(errors[f"{config} seed {s}"]["verdict"].startswith("learned") for s in design["seeds"])
                   for config in ("default", "D")}
        results[name] = dict(
            dataset=str(paths[name]), protocol=dataset.protocol, robot=robot.name, test_trajectories=test,
            derivative_sources=summaries["default"]["derivative_sources"], chosen=chosen, noise_floor=floor,
            errors=errors, learned_of=dict(learned, seeds=len(design["seeds"])), d_over_default=ratios,
            validation={config: {seed: entry["validation"] for seed, entry in summaries[config]["seeds"].items()}
                        for config in ("default", "D")},
            met=learned["default"] == len(design["seeds"]) and all(
                ratios[key]["margin_verdict"] in ("better than D", "within 10 % of D") for key in ("q", "v")))
    return results


def margin_verdict(ratio) -> str:
    """The interval's reading of D / default (> 1: the default's MSE is lower) against the 10 % margin."""
    if ratio.pairs < 2:
        return "inconclusive (one pair)"
    if ratio.low > 1.0:
        return "better than D"
    if ratio.low >= 1.0 / MARGIN:
        return "within 10 % of D"
    if ratio.high < 1.0 / MARGIN:
        return "worse than D by more than 10 %"
    return "inconclusive"


def table(results: dict) -> str:
    """The Markdown table of docs/learning.md."""
    lines = ["| protocol | default learned | D learned | default q vs Euler | default v vs 'v unchanged' | "
             "D / default q | D / default v | alpha and targets chosen (per seed) | met |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, result in results.items():
        errors = result["errors"]
        seeds = [key for key in errors if key.startswith("default seed ")]
        geo = lambda key: float(np.exp(np.mean(np.log([errors[s][key] for s in seeds]))))  # noqa: E731
        ratio = lambda key: result["d_over_default"][key]  # noqa: E731
        text = lambda r: f"{r['ratio']:.3g}x [{r['low']:.3g}, {r['high']:.3g}] {r['margin_verdict']}"  # noqa: E731
        chosen = "; ".join(value.split("(", 1)[-1].rstrip(")") for value in result["chosen"].values())
        learned = result["learned_of"]
        lines.append(f"| {name} | {learned['default']} of {learned['seeds']} | {learned['D']} of {learned['seeds']} | "
                     f"{geo('ratio_to_euler_q'):.3g}x | {geo('ratio_to_velocity_unchanged_v'):.3g}x | "
                     f"{text(ratio('q'))} | {text(ratio('v'))} | {chosen} | {'yes' if result['met'] else 'no'} |")
    return "\n".join(lines) + "\n"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="12 trajectories, 2 seeds, 5 epochs (a check that it runs)")
    parser.add_argument("--data", type=pathlib.Path, default=pathlib.Path("/tmp/default_train_study"))
    parser.add_argument("-o", "--output", type=pathlib.Path, default=ROOT / "docs" / "results" / "default_train")
    parser.add_argument("--workers", type=int, default=2, help="train runs at once (default 2)")
    parser.add_argument("--protocols", nargs="+", choices=PROTOCOLS, default=list(PROTOCOLS),
                        help="the protocols to run (default all five)")
    parser.add_argument("--seeds", type=int, nargs="+", help="the model seeds (default: the design's, 0-4); other "
                        "seeds train into their own runs folder")
    parser.add_argument("--data-seed", type=int, default=DATA_SEED,
                        help=f"seed of the five datasets (default {DATA_SEED}, run 1; run 2: 28)")


def run(args: argparse.Namespace) -> int:
    design = dict(QUICK if args.quick else FULL)
    runs = args.data / "runs"
    if args.seeds is not None and tuple(args.seeds) != design["seeds"]:
        design["seeds"] = tuple(args.seeds)
        runs = args.data / ("runs_seeds_" + "_".join(map(str, args.seeds)))
    started = time.perf_counter()
    paths = collect(args.data, design, args.data_seed)
    runs.mkdir(parents=True, exist_ok=True)
    seconds = train_all(paths, runs, design, args.workers, args.protocols)
    results = evaluate(paths, runs, design, args.protocols)
    from stdm_drake.files import json_default, write_text_atomic
    record = dict(written_by="tools/study.py default-train", provenance=args.provenance, quick=args.quick,
                  design=dict(design, data_seed=args.data_seed, margin=MARGIN), train_seconds=seconds,
                  met=all(result["met"] for result in results.values()), protocols=results,
                  seconds=round(time.perf_counter() - started, 1))
    args.output.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.output / "results.json", json.dumps(record, indent=1, default=json_default) + "\n")
    text = table(results)
    write_text_atomic(args.output / "results.md", text)
    print(text + f"success (every protocol met): {'met' if record['met'] else 'not met'}")
    return 0

