"""`stdm-drake reproduce`: the paper's experiments end to end for a robot, with a report beside their
numbers."""
import argparse
import pathlib
import sys
import time

from stdm_drake.cluster import add_runner_arguments, check_workers, runner_config_from_args
from stdm_drake.commands.arguments import add_plant_effects_argument, add_robot_argument, command_robot
from stdm_drake.errors import check_seed
from stdm_drake.experiments.jobs import FULL, QUICK
from stdm_drake.experiments.reproduce import reproduce
from stdm_drake.files import line_text
from stdm_drake.outputs import add_force_argument, check_output_folder, fresh_default_folder
from stdm_drake.robots.plant import DEFAULT_PLANT_TIME_STEP
from stdm_drake.robots.plant_effects_check import plant_effects_for


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="every stage at reduced size (about 35 s on 2 cores)")
    parser.add_argument("--output", "-o", type=pathlib.Path,
                        help="report folder (default out/reproduce, or out/reproduce-NAME with --robot, numbered -2, -3, "
                             "... where an earlier run's report is); the datasets and checkpoints of an unfinished "
                             "run, or of a folder given here, are reused")
    add_robot_argument(parser, "another fully actuated arm of 6 or more joints runs the same experiments with "
                               "its protocols derived from its model")
    add_plant_effects_argument(parser, "every dataset and closed loop on the affected plant (report in "
                                       "out/reproduce-effects by default)")
    parser.add_argument("--seed", type=int, default=0, help="data collection seed")
    parser.add_argument("--workers", type=int, default=2,
                        help="training processes (default 2); with --backend ray and no cluster, the local Ray "
                             "instance's CPUs")
    add_runner_arguments(parser)
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    add_force_argument(parser)


def run(args: argparse.Namespace) -> int:
    check_workers(args.workers)
    check_seed("--seed", args.seed)
    robot = command_robot(args)
    robot.check_can_track()
    effects = plant_effects_for(args.plant_effects, robot, DEFAULT_PLANT_TIME_STEP)
    default = "out/reproduce" + ("" if args.robot is None else f"-{robot.name}") + ("" if effects is None else "-effects")
    output = args.output or fresh_default_folder(default, "reproduce")
    check_output_folder("-o/--output", output, inputs=[args.robot, args.plant_effects], force=args.force)
    profile = QUICK if args.quick else FULL
    started = time.perf_counter()
    runner = runner_config_from_args(args)
    path, failures = reproduce(profile, output, seed=args.seed, workers=args.workers, progress=not args.quiet,
                               robot=robot, runner=runner, plant_effects=effects)
    print(f"wrote {line_text(path)} and {line_text(path.with_suffix('.md'))} in {time.perf_counter() - started:.0f} s")
    for failure in failures:
        print(f"stdm-drake reproduce: error: MPC stage: {failure}", file=sys.stderr)
    return 2 if failures else 0
