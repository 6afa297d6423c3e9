"""The quick report's sine-sum interval across seeds: how many networks the quick stage needs to show the paper's effect.

The main job (`stdm-drake reproduce --quick`) trains the sine-sum's headline configuration (5 layers, swish, MSE,
alpha 1, 6000 full-batch steps) as its sine-sum stage and prints the paired ratio naive / derivative test MSE
with its 95 % interval. This study runs that stage with NETWORKS paired networks at each initialization seed
and records, per (networks, seed), the ratio, the interval, its verdict and the wall time, so that the number of
networks the quick stage trains rests on a measurement (design and success criteria: docs/learning.md, "The
quick report's sine-sum: how many networks", written before its runs).

    python tools/study.py quick-sine-sum --networks 3 6 10 --seeds 100 101 ... [-o docs/results/quick_sine_sum]
"""
import argparse
import dataclasses
import json
import pathlib
import time

from stdm_drake.files import write_text_atomic

ROOT = pathlib.Path(__file__).resolve().parents[2]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--networks", type=int, nargs="+", required=True,
                        help="paired networks per run of the quick stage (each value a separate run per seed)")
    parser.add_argument("--seeds", type=int, nargs="+", required=True, help="initialization seeds")
    parser.add_argument("--workers", type=int, default=2, help="processes (the quick stage's own default: 2)")
    parser.add_argument("--result", default="results.json", help="file name of the results under --output")
    parser.add_argument("-o", "--output", type=pathlib.Path, default=ROOT / "docs" / "results" / "quick_sine_sum")


def run(args: argparse.Namespace) -> int:
    from stdm_drake.errors import InputError
    from stdm_drake.experiments.sine_sum import QUICK, headline, run_study

    if min(args.networks) < 2 or max(args.networks) > 50:
        raise InputError("--networks must each be in 2..50 (a paired interval needs two networks)")
    path = args.output / args.result
    if path.exists():
        raise InputError(f"{path} exists: results of an earlier run are not overwritten; name another --result")
    rows = []
    for networks in args.networks:
        for seed in args.seeds:
            config = dataclasses.replace(QUICK, seeds=networks, headline_seeds=networks,
                                         table_seeds=min(QUICK.table_seeds, networks), seed=seed)
            started = time.perf_counter()
            study = run_study(config, workers=args.workers, progress=False)
            top = headline(study)
            rows.append(dict(networks=networks, seed=seed, ratio=top["ratio"], low=top["ratio_low"],
                             high=top["ratio_high"], verdict=top["verdict"],
                             naive_mean_test_mse=top["naive_mean_test_mse"],
                             derivative_mean_test_mse=top["derivative_mean_test_mse"],
                             wall_seconds=round(time.perf_counter() - started, 1)))
            row = rows[-1]
            print(f"networks {networks} seed {seed}: {row['ratio']:.3g}x [{row['low']:.3g}, {row['high']:.3g}] "
                  f"{row['verdict']} ({row['wall_seconds']} s)", flush=True)
    summary = {str(networks): dict(
        seeds=len(args.seeds), helps=sum(r["verdict"] == "helps" for r in rows if r["networks"] == networks),
        hurts=sum(r["verdict"] == "hurts" for r in rows if r["networks"] == networks),
        mean_wall_seconds=round(sum(r["wall_seconds"] for r in rows if r["networks"] == networks) / len(args.seeds), 1))
        for networks in args.networks}
    for networks, found in summary.items():
        print(f"networks {networks}: interval above 1 ('helps') on {found['helps']} of {found['seeds']} seeds, "
              f"below 1 on {found['hurts']}; {found['mean_wall_seconds']} s per run")
    args.output.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(dict(
        written_by="tools/study.py quick-sine-sum", provenance=args.provenance, workers=args.workers,
        quick_profile=dict(layers=list(QUICK.layers), activation="swish", epochs=QUICK.epochs, alpha=QUICK.alpha),
        summary=summary, rows=rows), indent=2) + "\n")
    return 0
