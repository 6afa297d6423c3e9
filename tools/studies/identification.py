"""The identification study: white, grey and black boxes of an affected plant (docs/identification.md).

White-box identification of an affected plant (the UR-10 with models/ur10_effects.yaml by default) against
the number of training plans and the sensor model (design, amendment and results in docs/identification.md,
fixed before the runs):

    python tools/study.py identification [--quick] [--workers 2] [-o docs/results/identification]
        [--data out/identification_data] [--robot models/ur10.yaml] [--plant-effects models/ur10_effects.yaml]
        [--part white|grey|closed|all]

Runs (each at every training size per start pose, validation and test plans fixed):
    A  ideal sensor, the simulation's true q, q̇, q̈ (the goal: torque error <= 1 %, friction within 5 %)
    B  ideal sensor, smoothed derivatives (parallel filtering: what the filter alone costs)
    C  the paper's sensor (controllers/sensor.yaml), smoothed derivatives (the degradation)
For A and C at the largest size, the identified model's one-step and 20-step errors on the test plans
beside the physics baselines and the nominal plant. `identification_boxes.run_study` does it (part "white"; --quick: 1 plan per
pose on 12 plans); it writes summary.md, summary.csv, results.json (the rows and model errors) and one
identify report per run (reports/*.json).

Grey box against black box (`run_grey_box`, part "grey", after "white", whose results.json it reads; on both
sensors' data, the same split): D and DD (`train`'s black boxes), G (grey box on the description's plant
step), G-id and GD-id (grey box on the plant identified from the same training plans: run A's for the ideal
sensor, C's for the paper's), `SEEDS` seeds each (300 epochs; --grey-models for others, e.g. run 1's D DD G
G-id GD-id); one-step and 20-step q MSE on the test plans, each grey box's ratio to D paired by seed with a
95 % interval, at every training size of the profile (--grey-sizes; run 3: each grey box on the robot
identified from its own plans); writes grey_box.md and grey_box.json (--grey-output). Part "closed" (after
"white"): the tuned closed loop at the largest size (`identification_closed_loop`): MPC with the nominal
plant, the true plant, the identified robot, D and G-id-state (each seed), each model's setting chosen on
the validation plans, then the test plans; writes closed_loop.md and closed_loop.json. Datasets and
checkpoints are kept in --data and reused.
"""
import argparse
import json

from studies import identification_closed_loop as closed_loop
from studies.affected_plant import add_affected_plant_arguments, robot_and_effects
from studies.identification_boxes import (FULL, GREY_BOX_MODELS, QUICK, grey_box_table, run_grey_box, run_study,
                                          write_grey_box, write_white_box)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_affected_plant_arguments(parser, "identification", quick_minutes=2)
    parser.add_argument("--part", choices=("white", "grey", "closed", "all"), default="all",
                        help="white box only, grey box only or the closed loop only (both read the white box's "
                             "results.json), or all three")
    parser.add_argument("--grey-models", nargs="+", choices=tuple(GREY_BOX_MODELS), metavar="NAME",
                        help="the grey-box part's models (D always; default: the profile's: "
                             f"{' '.join(FULL['grey_models'])}); e.g. D G-id-state GD-id-state for run 2")
    parser.add_argument("--grey-sizes", nargs="+", type=int, metavar="N",
                        help="the grey-box part's training plans per pose (default: the profile's: "
                             f"{' '.join(map(str, FULL['grey_sizes']))}; each one the white box ran at)")
    parser.add_argument("--grey-output", default="grey_box", metavar="STEM",
                        help="the grey-box part's file names, STEM.json and STEM.md (default grey_box)")


def run(args: argparse.Namespace) -> int:
    robot, effects = robot_and_effects(args)
    profile = dict(QUICK if args.quick else FULL)
    if args.grey_models:
        profile["grey_models"] = tuple(dict.fromkeys(["D", *args.grey_models]))
    if args.grey_sizes:
        profile["grey_sizes"] = tuple(args.grey_sizes)
    say = lambda line: print(line, flush=True)  # noqa: E731
    out = args.output
    if args.part in ("white", "all"):
        write_white_box(run_study(profile, args.data, robot, effects, workers=args.workers, say=say), out, args.quick,
                        args.provenance)
        print((out / "summary.md").read_text())
    if args.part in ("grey", "all"):
        white = json.loads((out / "results.json").read_text())
        grey = write_grey_box(run_grey_box(profile, args.data, robot, white, workers=args.workers, say=say),
                              out, args.quick, args.provenance, args.grey_output)
        print(grey_box_table(grey))
    if args.part in ("closed", "all"):
        white = json.loads((out / "results.json").read_text())
        closed = closed_loop.write_closed_loop(closed_loop.run_closed_loop(profile, args.data, robot, white,
                                                                           workers=args.workers, say=say), out, args.quick,
                                               args.provenance)
        print(closed_loop.closed_loop_table(closed))
    print(f"wrote {out}")
    return 0
