"""Does the default `train` learn on every protocol the toolbox ships? (docs/learning.md, "A default that
learns"; design committed before the first run.)

Five datasets, each as a new user makes it (seed 27, never used by another study): the default excitation
protocol, tracked plans (the paper's protocol, collect's default sensor), the identification protocol
(pid_dither.yaml with sensor_ideal.yaml, the README's MPC recipe), an imported log (tracked plans with the ideal
sensor written as a UR RTDE recording with timing jitter and dropped rows, then `stdm-drake import`) and the
Panda preset's tracked plans. On each, `train DATASET` with no flags but the seeds and output ("default") and
`train DATASET --model D` ("D"), the same seeds, the same default split; every model is evaluated on the
split's test trajectories (never used for any choice): one-step MSE of q and v beside the Euler step and
"v unchanged", the sensor's noise floor where the data have a truth, and `physics.learning_verdict`. Paired by
seed, D / default with a 95 % interval (`stdm_drake.stats.paired_ratio`).

    python tools/default_train_study.py [--quick] [--data /tmp/default_train_study] [-o docs/results/default_train]
    python tools/default_train_study.py --protocols excitation --seeds 5 6 7 8 9 10 11 12 13 14 \
        -o docs/results/default_train/replication      # run 1's replication (docs/learning.md)
    python tools/default_train_study.py --data-seed 28 --data /tmp/default_train_study_28 \
        -o docs/results/default_train/run2             # run 2: the selection rule, on new data
"""
from __future__ import annotations

import argparse
import concurrent.futures
import json
import os
import pathlib
import subprocess
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")

from stdm_drake.cli import main as cli  # noqa: E402

PROTOCOLS = ("excitation", "tracking", "identification", "imported_log", "panda")
DATA_SEED = 27
MARGIN = 1.10   # the default's MSE at most 10 % above D's
# count: trajectories collected (the log: plans); seeds: models per configuration; train_flags: added to both
# configurations' commands (the full run adds none: train's defaults)
FULL = dict(count=60, log_count=40, seeds=(0, 1, 2, 3, 4), train_flags=())
QUICK = dict(count=12, log_count=8, seeds=(0, 1), train_flags=("--epochs", "5"))
SMALL = dict(count=24, log_count=16, seeds=(0,), train_flags=("--epochs", "60"))   # the test's (tests/test_default_train.py)


def collect(folder: pathlib.Path, design: dict, data_seed: int = DATA_SEED) -> dict:
    """The five datasets in `folder` (made once; an existing file is kept), {protocol: path}."""
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.data.logs import simulated
    folder.mkdir(parents=True, exist_ok=True)
    count, seed = str(design["count"]), str(data_seed)
    common = ["--seed", seed, "--workers", "1", "--quiet"]
    commands = {
        "excitation": ["collect", "--protocol", "excitation", "--count", count],
        "tracking": ["collect", "--protocol", "tracking", "--count", count],
        "identification": ["collect", "--protocol", "tracking", "--count", count, "--controller",
                           "stdm-drake:controllers/pid_dither.yaml", "--sensor", "stdm-drake:controllers/sensor_ideal.yaml"],
        "panda": ["collect", "--protocol", "tracking", "--count", count, "--robot", "stdm-drake:models/panda.yaml"],
    }
    paths = {name: folder / f"{name}.h5" for name in PROTOCOLS}
    for name, command in commands.items():
        if not paths[name].exists():
            assert cli(command + common + ["-o", str(paths[name])]) == 0, name
    if not paths["imported_log"].exists():
        original, log = folder / "log_original.h5", folder / "log_record.csv"
        if not original.exists():
            assert cli(["collect", "--protocol", "tracking", "--count", str(design["log_count"]), "--sensor",
                        "stdm-drake:controllers/sensor_ideal.yaml", *common, "-o", str(original)]) == 0
        simulated.write_rtde_csv(load_dataset(original), log)
        assert cli(["import", str(log), "--quiet", "-o", str(paths["imported_log"])]) == 0
    return paths


def train_command(dataset: pathlib.Path, output: pathlib.Path, config: str, design: dict) -> list:
    """The `stdm-drake train` arguments of one configuration ("default" or "D") on one dataset."""
    model = ["--model", "D"] if config == "D" else []
    seeds = ["--seeds", *map(str, design["seeds"])]
    return ["train", str(dataset), *model, *seeds, *design["train_flags"], "--quiet", "-o", str(output)]


def run_train(arguments: list) -> tuple[int, float, str]:
    """One `stdm-drake train` in its own process (one torch thread, train's default): (exit status, seconds,
    its output)."""
    started = time.perf_counter()
    process = subprocess.run([sys.executable, "-c", "import sys; from stdm_drake.cli import main; "
                              "sys.exit(main(sys.argv[1:]))", *arguments], capture_output=True, text=True)
    return process.returncode, time.perf_counter() - started, process.stdout + process.stderr


def train_all(paths: dict, runs: pathlib.Path, design: dict, workers: int, protocols=PROTOCOLS) -> dict:
    """Every (protocol, configuration) trained into runs/<protocol>_<config> (kept when its summary exists);
    returns {folder name: seconds} of the runs made now."""
    jobs = {f"{name}_{config}": train_command(paths[name], runs / f"{name}_{config}", config, design)
            for name in protocols for config in ("default", "D") if not (runs / f"{name}_{config}" / "summary.json").exists()}
    seconds = {}
    with concurrent.futures.ThreadPoolExecutor(max_workers=workers) as pool:
        futures = {pool.submit(run_train, arguments): folder for folder, arguments in jobs.items()}
        for future in concurrent.futures.as_completed(futures):
            code, elapsed, output = future.result()
            folder = futures[future]
            (runs / f"{folder}.log").write_text(output)
            if code != 0:
                raise RuntimeError(f"train {folder} failed ({code}):\n{output[-2000:]}")
            seconds[folder] = round(elapsed, 1)
            print(f"{folder}: {elapsed:.0f} s", flush=True)
    return seconds


def evaluate(paths: dict, runs: pathlib.Path, design: dict, protocols=PROTOCOLS) -> dict:
    """Per protocol: each model's test errors beside the Euler step, its verdict, its validation entry from
    train's summary.json, and the paired ratios D / default (q and v one step)."""
    from stdm_drake.data.compatibility import shipped_preset_of
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.data.inspect import noise_floor
    from stdm_drake.learning.evaluate import compare_with_baselines
    from stdm_drake.learning.learned_model import LearnedModel
    from stdm_drake.learning.physics import ConstantVelocity
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
        models = [LearnedModel(runs / f"{name}_{config}" / f"seed{seed}" / "checkpoint.pt", robot=robot,
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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
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
    args = parser.parse_args(argv)
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
    record = dict(written_by="stdm-drake tools/default_train_study.py", quick=args.quick,
                  design=dict(design, data_seed=args.data_seed, margin=MARGIN), train_seconds=seconds,
                  met=all(result["met"] for result in results.values()), protocols=results,
                  seconds=round(time.perf_counter() - started, 1))
    args.output.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.output / "results.json", json.dumps(record, indent=1, default=json_default) + "\n")
    text = table(results)
    write_text_atomic(args.output / "results.md", text)
    print(text + f"success (every protocol met): {'met' if record['met'] else 'not met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
