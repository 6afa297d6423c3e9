"""`stdm-drake identify`: the robot's link inertias and joint friction from one of its datasets (white box),
physically consistent, written as an identified robot (`identified.yaml`) that every command takes as a
model, with a report (`identified.json`) of the excitation, the fit and the test torque errors (the job:
`identification.identify_job`)."""
import argparse
import pathlib

from stdm_drake.commands.arguments import add_robot_argument
from stdm_drake.outputs import add_force_argument


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from stdm_drake.identification.identify import REGULARIZATIONS, SMOOTHING_WINDOWS, VELOCITY_SCALES
    parser.add_argument("dataset", type=pathlib.Path, help="dataset file (.h5) of the robot")
    add_robot_argument(parser, "the description whose parameters are identified; must be the dataset's robot")
    parser.add_argument("--output", "-o", type=pathlib.Path, required=True,
                        help="identified robot to write (.yaml); the report goes beside it (.json)")
    parser.add_argument("--derivatives", choices=("true", "smoothed"),
                        help="states and accelerations: the simulation's true ones (default for simulated data), or "
                             "central differences of the Savitzky-Golay-smoothed measured angles, the torques through "
                             "the same smoother (its window chosen on validation; default for a real robot's log)")
    parser.add_argument("--velocity-scales", type=float, nargs="+", default=list(VELOCITY_SCALES), metavar="V_S",
                        help="candidate Coulomb smoothing scales, rad/s (default %(default)s)")
    parser.add_argument("--regularizations", type=float, nargs="+", default=list(REGULARIZATIONS), metavar="LAMBDA",
                        help="candidate weights toward the description's parameters (default %(default)s)")
    parser.add_argument("--windows", type=int, nargs="+", metavar="SAMPLES",
                        help=f"candidate Savitzky-Golay windows with --derivatives smoothed (default {list(SMOOTHING_WINDOWS)}; 1: "
                             "no smoothing, the raw differences)")
    parser.add_argument("--train", type=int, help="training trajectories (per group with --per-group)")
    parser.add_argument("--val", type=int, help="validation trajectories (per group with --per-group)")
    parser.add_argument("--test", type=int, help="test trajectories (default: all the rest)")
    parser.add_argument("--per-group", choices=("on", "off"),
                        help="split per initial-pose group (default: on for tracking data, off otherwise)")
    parser.add_argument("--split-seed", type=int, default=0, help="seed of the trajectory split (default 0; the "
                                                                  "same split as `train` with the same options)")
    parser.add_argument("--quiet", action="store_true")
    add_force_argument(parser)


def run(args: argparse.Namespace) -> int:
    from stdm_drake.identification.identify_job import IdentifyJob, identify_job
    identify_job(IdentifyJob(dataset=args.dataset, output=args.output, robot=args.robot, derivatives=args.derivatives,
                             velocity_scales=tuple(args.velocity_scales), regularizations=tuple(args.regularizations),
                             windows=None if args.windows is None else tuple(args.windows), train=args.train,
                             val=args.val, test=args.test, per_group=args.per_group, split_seed=args.split_seed,
                             progress=not args.quiet, force=args.force))
    return 0
