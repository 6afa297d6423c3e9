"""`stdm-drake import`: a real robot's log (UR RTDE CSV, ROS 2 bag) as a validated dataset of protocol "logged"
that train, evaluate, view, inspect, identify and mpc's model side take like any dataset (docs/real_logs.md; the
job: `data.logs.import_job`)."""
import argparse
import pathlib

from stdm_drake.commands.arguments import add_robot_argument
from stdm_drake.outputs import add_force_argument


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from stdm_drake.data.logs.mapping import FORMATS
    parser.add_argument("log", type=pathlib.Path,
                        help="the log: an RTDE CSV file (space or comma delimited, a header of field names), or a "
                             "ROS 2 bag (its folder, or one .db3 / .mcap file)")
    add_robot_argument(parser, "the logged arm: its joints, limits and description")
    parser.add_argument("--output", "-o", type=pathlib.Path, required=True, help="dataset file to write (.h5)")
    parser.add_argument("--format", choices=FORMATS, help="the log's format (default: from the file)")
    parser.add_argument("--mapping", type=pathlib.Path,
                        help="typed YAML of what the log does not say (torque constants, joint names, topics, "
                             "splitting and smoothing; see docs/real_logs.md); options below override it")
    parser.add_argument("--sample-period", type=float, help="the dataset's sample period, s (default, or 0: the log's median period)")
    parser.add_argument("--torque-source", choices=("target_moment", "current", "effort"),
                        help="RTDE: target_moment (default) or current (times --torque-constants); bags: effort")
    parser.add_argument("--torque-constants", type=float, nargs="+", metavar="NM_PER_A",
                        help="per joint, N m / A, for --torque-source current")
    parser.add_argument("--joint-states-topic", help="bags: the JointState topic (default /joint_states)")
    parser.add_argument("--controller-state-topic",
                        help="bags: the JointTrajectoryControllerState topic with the plan (default: the bag's topic "
                             "of that type, if any)")
    parser.add_argument("--joint-names", nargs="+", metavar="NAME",
                        help="bags: the log's name of each of the robot's arm joints, in the robot's order")
    parser.add_argument("--quiet", action="store_true", help="no lines on success (a refusal is still its one line)")
    add_force_argument(parser)


def run(args: argparse.Namespace) -> int:
    from stdm_drake.data.logs.import_job import ImportJob, import_job
    import_job(ImportJob(log=args.log, output=args.output, robot=args.robot, mapping=args.mapping, format=args.format,
                         sample_period=args.sample_period, torque_source=args.torque_source,
                         torque_constants=args.torque_constants, joint_states_topic=args.joint_states_topic,
                         controller_state_topic=args.controller_state_topic, joint_names=args.joint_names,
                         progress=not args.quiet, force=args.force))
    return 0
