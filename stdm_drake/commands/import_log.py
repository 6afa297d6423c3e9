"""`stdm-drake import`: a real robot's log (UR RTDE CSV, ROS 2 bag) as a validated dataset of protocol "logged"
that train, evaluate, view, inspect, identify and mpc's model side take like any dataset (docs/real_logs.md)."""
import argparse
import dataclasses
import pathlib
import sys

from stdm_drake.commands.arguments import add_robot_argument, command_robot
from stdm_drake.errors import InputError
from stdm_drake.outputs import add_force_argument, check_output_file


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
    parser.add_argument("--quiet", action="store_true")
    add_force_argument(parser)


def command_mapping(args: argparse.Namespace, log):
    """The LogMapping of --mapping (defaults without it) with the options given on the command line, for
    the format of `log`, checked (a setting given, as an option or a file's key, must be one the import uses)."""
    from stdm_drake.config import file_keys
    from stdm_drake.data.logs.importer import detect_format
    from stdm_drake.data.logs.mapping import LogMapping, check_settings_used, load_mapping
    mapping = load_mapping(args.mapping) if args.mapping is not None else LogMapping()
    options = dict(format=args.format, sample_period=args.sample_period, torque_source=args.torque_source,
                   torque_constants=args.torque_constants, joint_states_topic=args.joint_states_topic,
                   controller_state_topic=args.controller_state_topic, joint_names=args.joint_names)
    options = {key: value for key, value in options.items() if value is not None}
    mapping = dataclasses.replace(mapping, **options)
    mapping.validate()
    mapping = mapping.with_format(detect_format(log, mapping.format))
    check_settings_used(mapping, set(options) | file_keys(args.mapping))
    return mapping


def run(args: argparse.Namespace) -> int:
    from stdm_drake.data.logs.importer import import_log
    log = args.log
    if not (log.exists() or log.is_symlink()):
        raise InputError(f"log not found: {log}")
    if not (log.is_file() or log.is_dir()):
        raise InputError(f"log {log} is not a file or a bag folder")
    if args.output.suffix.lower() not in (".h5", ".hdf5"):
        raise InputError(f"-o/--output {args.output}: a dataset is an .h5 file")
    if log.is_dir() and args.output.absolute().parent == log.absolute():
        raise InputError(f"-o/--output {args.output} is inside the bag folder {log}; write the dataset elsewhere")
    check_output_file("-o/--output", args.output, kind="dataset", inputs=[log, args.mapping, args.robot],
                      force=args.force)
    mapping = command_mapping(args, log)
    robot = command_robot(args)
    kind = mapping.format
    if not args.quiet:
        print(f"import {log} ({kind}) as a {robot.name} log", file=sys.stderr)
    record = import_log(log, robot, mapping, args.output)
    pieces, resampling = record["trajectories"], record["resampling"]
    print(f"wrote {args.output}: {pieces['kept']} trajectories from {pieces['rows']} rows at a sample period of "
          f"{record['mapping']['sample_period'] or resampling['log_period_s']:g} s (split at {pieces['gaps']} gaps, "
          f"{pieces['pauses']} pauses, {pieces['mode_changes']} mode changes, {pieces['cuts']} cuts; "
          f"{pieces['dropped_short']} short pieces dropped, {pieces['rows_not_running']} rows not running left out)")
    print(f"resampling: log period {resampling['log_period_s']:g} s, stamp jitter RMS {resampling['jitter_rms_s']:.3g} s, "
          f"estimated angle error {resampling['estimated_q_error_rad']:.3g} rad; torque from "
          f"{record['torque_source']}; derivative targets: "
          + ("the logged plan, " if record["derivatives"]["planned"] else "")
          + "measured, smoothed (Savitzky-Golay)"
          + ("; train chooses between the plan (when close to the logged motion) and the smoothed ones by validation"
             if record["derivatives"]["planned"] else "; train uses the smoothed ones"))
    return 0
