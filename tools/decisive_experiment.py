"""The decisive experiment on the paper's UR-10 claim: the command line of
`stdm_drake.experiments.decisive` (design and verdict rules in docs/learning.md).

Usage: python tools/decisive_experiment.py [--quick] [--resume] [--workers 2] [--backend local|ray]
       [--ray-address HOST:PORT] [-o docs/results/decisive] [--data out/decisive_data]

--resume keeps the rows of the output folder's results.json when its design (seeds, split, alpha,
horizon) is this run's, and trains only the models it lacks (new cells or controls).
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
from stdm_drake.errors import InputError  # noqa: E402
from stdm_drake.experiments.decisive import (ALPHA, CELLS, CONTROLS, ENDPOINTS, HORIZON, TEST,  # noqa: E402
                                             TRAIN, VALIDATION, DecisiveRun, run_study)
from stdm_drake.files import json_default, rows_csv, write_text_atomic  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=pathlib.Path, default=ROOT / "docs" / "results" / "decisive")
    parser.add_argument("--data", type=pathlib.Path, default=ROOT / "out" / "decisive_data")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--quick", action="store_true",
                        help="the literal and learned-structure cells, 2 data seeds x 2 inits, 50 trajectories "
                             "(pipeline check, ~2 min)")
    parser.add_argument("--resume", action="store_true",
                        help="keep the output folder's rows of the same design; train only the missing models")
    add_runner_arguments(parser)
    args = parser.parse_args(argv)
    runner = runner_config_from_args(args)
    cells, data_seeds, inits, sizes = CELLS, 3, 5, (TRAIN, VALIDATION, TEST)
    if args.quick:
        cells, data_seeds, inits, sizes = (CELLS[0], CELLS[-1]), 2, 2, (10, 10, 20)
    design = dict(quick=args.quick, data_seeds=data_seeds, inits=inits,
                  split=dict(zip(("train", "validation", "test"), sizes)), alpha=ALPHA, horizon=HORIZON)
    try:
        done = earlier_rows(args.output / "results.json", design, cells) if args.resume else []
    except InputError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    study = run_study(args.data, runner, cells=cells, data_seeds=data_seeds, inits=inits, sizes=sizes, done=done,
                      progress=lambda text: print(text, flush=True))
    summary, rows = study["summary"], study["runs"]
    args.output.mkdir(parents=True, exist_ok=True)
    ratios = ["D_over_DD"] + [f"{control}_over_DD" for control in CONTROLS]
    flat = [dict(cell=s["cell"], switch=s["switch"], structure=s["structure"], naive_vs_euler_q=s["naive_vs_euler_q"],
                 naive_vs_unchanged_v=s["naive_vs_unchanged_v"], gated=s["gated"], verdict=s["verdict"],
                 **{f"{which} {label} {part}": s[which][label][part] for which in ratios if which in s
                    for _, label in ENDPOINTS for part in ("ratio", "low", "high")}) for s in summary]
    write_text_atomic(args.output / "runs.csv", rows_csv([dataclasses.asdict(row) for row in rows]))
    write_text_atomic(args.output / "cells.csv", rows_csv(flat))
    write_text_atomic(args.output / "results.json", json.dumps(dict(
        written_by="tools/decisive_experiment.py", **design, seconds=study["seconds"],
        train_seconds_total=round(sum(row.train_seconds for row in rows), 1),
        reused_rows=study["reused"], cells=[dataclasses.asdict(c) for c in cells], summary=summary, runs=rows),
        indent=2, default=json_default) + "\n")
    for s in summary:
        print(f"\n{s['cell']} ({s['switch']}): naive vs Euler q {s['naive_vs_euler_q']:.3g}x, vs 'v unchanged' "
              f"{s['naive_vs_unchanged_v']:.3g}x -> {s['verdict']}")
        for _, label in ENDPOINTS:
            print(f"  {label:>14}: " + "   ".join(
                f"{which[:-len('_over_DD')]}/DD {s[which][label]['ratio']:.3g}x [{s[which][label]['low']:.3g}, "
                f"{s[which][label]['high']:.3g}]" for which in ratios if which in s))
    print(f"\n{len(rows)} models ({study['reused']} kept from the earlier run) in {study['seconds']:.0f} s "
          f"-> {args.output}")
    return 0


def earlier_rows(path: pathlib.Path, design: dict, cells) -> list[DecisiveRun]:
    """The rows of an earlier results.json of the same design, for --resume (none if it does not exist)."""
    if not path.exists():
        return []
    try:
        earlier = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise InputError(f"--resume: cannot read {path}: {error}") from None
    differs = [name for name, value in design.items() if earlier.get(name) != value]
    if differs:
        raise InputError(f"--resume: {path} has another design ({', '.join(differs)} differ); "
                         "choose another -o or leave out --resume")
    periods = {cell.name: cell.sample_period for cell in cells}
    rows = [row for row in earlier.get("runs", []) if row.get("cell") in periods]
    for row in rows:   # rows written before D-half existed trained at their cell's own period
        row.setdefault("train_sample_period", periods[row["cell"]])
    try:
        return [DecisiveRun(**row) for row in rows]
    except TypeError as error:
        raise InputError(f"--resume: {path} has runs of another format ({error}); choose another -o or leave "
                         "out --resume") from None


if __name__ == "__main__":
    sys.exit(main())
