"""The identification study: white-box identification of an affected plant against the number of training
plans and the sensor model (design, amendment and results in docs/identification.md, fixed before the runs).

Usage: python tools/identification_study.py [--quick] [--workers 2] [-o docs/results/identification]
       [--data out/identification_data] [--robot models/ur10.yaml] [--plant-effects models/ur10_effects.yaml]

Part "white": runs A (ideal sensor, true derivatives), B (ideal sensor, smoothed), C (paper's sensor,
smoothed) at 5, 10 and 18 training plans per pose (--quick: 1, on 12 plans); for A and C at 18, the
identified model's one-step and 20-step errors beside the physics baselines. Writes summary.md,
summary.csv, results.json (the rows and model errors) and one identify report per run (reports/*.json).
Part "grey" (after "white", whose results.json it reads): D, DD, G-id-state, GD-id-state (5 seeds, 300
epochs; --grey-models for others, e.g. run 1's D DD G G-id GD-id) on both sensors' data at 5, 10 and 18 plans
per pose (--grey-sizes), each grey box on the robot identified from its own training plans; writes
grey_box.md and grey_box.json (--grey-output). Part "closed" (after "white"): the tuned closed loop at 18
plans per pose: MPC with the nominal plant, the true plant, the identified robot, D and G-id-state (each
seed), each model's setting chosen on the validation plans, then the test plans; writes closed_loop.md and
closed_loop.json. Datasets and checkpoints are kept in --data and reused.
"""
import json
import os
import pathlib
import sys

os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from affected_plant import parser_for, robot_and_effects  # noqa: E402
from stdm_drake.experiments import identification_study as study  # noqa: E402


def main(argv=None) -> int:
    parser = parser_for(__doc__, "identification", quick_minutes=2)
    parser.add_argument("--part", choices=("white", "grey", "closed", "all"), default="all",
                        help="white box only, grey box only or the closed loop only (both read the white box's "
                             "results.json), or all three")
    parser.add_argument("--grey-models", nargs="+", choices=tuple(study.GREY_BOX_MODELS), metavar="NAME",
                        help="the grey-box part's models (D always; default: the profile's: "
                             f"{' '.join(study.FULL['grey_models'])}); e.g. D G-id-state GD-id-state for run 2")
    parser.add_argument("--grey-sizes", nargs="+", type=int, metavar="N",
                        help="the grey-box part's training plans per pose (default: the profile's: "
                             f"{' '.join(map(str, study.FULL['grey_sizes']))}; each one the white box ran at)")
    parser.add_argument("--grey-output", default="grey_box", metavar="STEM",
                        help="the grey-box part's file names, STEM.json and STEM.md (default grey_box)")
    args = parser.parse_args(argv)
    loaded = robot_and_effects(args, "identification_study")
    if loaded is None:
        return 2
    robot, effects = loaded
    profile = dict(study.QUICK if args.quick else study.FULL)
    if args.grey_models:
        profile["grey_models"] = tuple(dict.fromkeys(["D", *args.grey_models]))
    if args.grey_sizes:
        profile["grey_sizes"] = tuple(args.grey_sizes)
    say = lambda line: print(line, flush=True)  # noqa: E731
    out = args.output
    if args.part in ("white", "all"):
        study.write_white_box(study.run_study(profile, args.data, robot, effects, workers=args.workers, say=say),
                              out, args.quick)
        print((out / "summary.md").read_text())
    if args.part in ("grey", "all"):
        white = json.loads((out / "results.json").read_text())
        grey = study.write_grey_box(study.run_grey_box(profile, args.data, robot, white, workers=args.workers, say=say),
                                    out, args.quick, args.grey_output)
        print(study.grey_box_table(grey))
    if args.part in ("closed", "all"):
        white = json.loads((out / "results.json").read_text())
        from stdm_drake.experiments import identification_closed_loop as closed_loop
        closed = closed_loop.write_closed_loop(closed_loop.run_closed_loop(profile, args.data, robot, white,
                                                                           workers=args.workers, say=say), out, args.quick)
        print(closed_loop.closed_loop_table(closed))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
