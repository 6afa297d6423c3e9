"""`stdm-drake compare`: which model for this robot, on its own data: every model kind fitted on the dataset's train
split, rated open loop beside the physics baselines and, on a simulated plant with plans, in closed loop under the
same MPC, with a recommendation (the job and its rule: `experiments.compare`)."""
import argparse
import pathlib

from stdm_drake.commands.arguments import add_robot_argument
from stdm_drake.outputs import add_force_argument


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from stdm_drake.experiments.compare import KINDS
    parser.add_argument("dataset", type=pathlib.Path, help="dataset file (.h5): simulated (`collect`) or a log (`import`)")
    add_robot_argument(parser, "must be the dataset's robot")
    parser.add_argument("--output", "-o", type=pathlib.Path,
                        help="folder for the stages' files and compare.md/.csv/.html/.json (default: out/compare, or "
                             "the first of out/compare-2, -3, ... without results); a rerun into it reuses what is done")
    parser.add_argument("--quick", action="store_true",
                        help="a first look: one seed per learned kind, small networks trained briefly, 2 closed-loop "
                             "plans without tuning (default: 3 seeds, the full size, 5 plans, each MPC tuned on 2)")
    parser.add_argument("--kinds", nargs="+", default=list(KINDS), metavar="KIND",
                        help=f"the kinds to compare, of {', '.join(KINDS)} (default all; G needs identified)")
    parser.add_argument("--no-closed-loop", action="store_true", help="the open-loop table alone")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    add_force_argument(parser)


def run(args: argparse.Namespace) -> int:
    from stdm_drake.experiments.compare import FULL, QUICK, CompareJob, run_compare
    record = run_compare(CompareJob(dataset=args.dataset, robot=args.robot, output=args.output,
                                    profile=QUICK if args.quick else FULL, kinds=tuple(args.kinds),
                                    closed_loop=not args.no_closed_loop, progress=not args.quiet, force=args.force))
    return 0 if record["recommendation"]["kind"] is not None else 1
