"""The decisive experiment on the paper's UR-10 claim: the command line of
`stdm_drake.experiments.decisive` (design and verdict rules in docs/learning.md).

Usage: python tools/decisive_experiment.py [--quick] [--workers 2] [--backend local|ray] [--ray-address HOST:PORT]
       [-o docs/results/decisive] [--data out/decisive_data]
"""
import argparse
import dataclasses
import json
import os
import pathlib
import sys

os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from stdm_drake.cluster import add_runner_arguments, runner_config_from_args  # noqa: E402
from stdm_drake.experiments.decisive import (ALPHA, CELLS, ENDPOINTS, HORIZON, TEST, TRAIN,  # noqa: E402
                                             VALIDATION, run_study)
from stdm_drake.files import rows_csv, write_text_atomic  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=pathlib.Path, default=ROOT / "docs" / "results" / "decisive")
    parser.add_argument("--data", type=pathlib.Path, default=ROOT / "out" / "decisive_data")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--quick", action="store_true",
                        help="2 cells, 2 data seeds x 2 inits, 60 trajectories (pipeline check, ~1 min)")
    add_runner_arguments(parser)
    args = parser.parse_args(argv)
    runner = runner_config_from_args(args)
    cells, data_seeds, inits, sizes = CELLS, 3, 5, (TRAIN, VALIDATION, TEST)
    if args.quick:
        cells, data_seeds, inits, sizes = CELLS[:2], 2, 2, (10, 10, 20)
    study = run_study(args.data, runner, cells=cells, data_seeds=data_seeds, inits=inits, sizes=sizes,
                      progress=lambda text: print(text, flush=True))
    summary, rows = study["summary"], study["runs"]
    args.output.mkdir(parents=True, exist_ok=True)
    flat = [dict(cell=s["cell"], switch=s["switch"], naive_vs_euler_q=s["naive_vs_euler_q"],
                 naive_vs_unchanged_v=s["naive_vs_unchanged_v"], gated=s["gated"], verdict=s["verdict"],
                 **{f"{which} {label} {part}": s[which][label][part] for which in ("D_over_DD", "D2x_over_DD")
                    for _, label in ENDPOINTS for part in ("ratio", "low", "high")}) for s in summary]
    write_text_atomic(args.output / "runs.csv", rows_csv(rows))
    write_text_atomic(args.output / "cells.csv", rows_csv(flat))
    write_text_atomic(args.output / "results.json", json.dumps(dict(
        written_by="tools/decisive_experiment.py", quick=args.quick, data_seeds=data_seeds, inits=inits,
        split=dict(zip(("train", "validation", "test"), sizes)), alpha=ALPHA, horizon=HORIZON,
        seconds=study["seconds"], cells=[dataclasses.asdict(c) for c in cells], summary=summary, runs=rows),
        indent=2) + "\n")
    for s in summary:
        print(f"\n{s['cell']} ({s['switch']}): naive vs Euler q {s['naive_vs_euler_q']:.3g}x, vs 'v unchanged' "
              f"{s['naive_vs_unchanged_v']:.3g}x -> {s['verdict']}")
        for _, label in ENDPOINTS:
            r, c = s["D_over_DD"][label], s["D2x_over_DD"][label]
            print(f"  {label:>14}: D/DD {r['ratio']:.3g}x [{r['low']:.3g}, {r['high']:.3g}]   "
                  f"D-2x/DD {c['ratio']:.3g}x [{c['low']:.3g}, {c['high']:.3g}]")
    print(f"\n{len(rows)} models in {study['seconds']:.0f} s -> {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
