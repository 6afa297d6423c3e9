"""`stdm-drake collect`: simulate a robot under a data protocol (excitation or tracking) and write a
dataset."""
import argparse
import os
import pathlib
import sys

from stdm_drake.collection.protocols import PROTOCOLS
from stdm_drake.collection.collect import CollectionRequest, collect, collection_request
from stdm_drake.commands.arguments import (add_plant_effects_argument, add_robot_argument, add_visualization_argument,
                                           check_meshcat_allowed, command_visualization)
from stdm_drake.data.writer import HDF5_RESERVE_BYTES, write_dataset
from stdm_drake.files import check_free_space
from stdm_drake.errors import InputError
from stdm_drake.outputs import add_force_argument, check_output_file
from stdm_drake.robots.plant import DEFAULT_PLANT_TIME_STEP
from stdm_drake.robots.robot import UR10_CONFIG
from stdm_drake.robots.station import DEFAULT_SAMPLE_PERIOD


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--protocol", choices=PROTOCOLS,
                        help="data protocol (default: the one --config's tag names, `protocol: !Excitation` or "
                             "`!Tracking`; else tracking)")
    parser.add_argument("--config", type=pathlib.Path,
                        help="protocol YAML (default: the file the robot config's `defaults` names, for the UR-10 "
                             "trajectories/excitation.yaml or tracking.yaml; without one, excitation ranges and "
                             "tracking poses derived from the robot, see README)")
    parser.add_argument("--controller", type=pathlib.Path,
                        help="tracking controller gains YAML (default: controllers/inverse_dynamics.yaml); tracking "
                             "protocol only")
    parser.add_argument("--sensor", type=pathlib.Path,
                        help="sensor noise/filter YAML (default: controllers/sensor.yaml for tracking, "
                             "an ideal sensor for excitation)")
    add_robot_argument(parser, "the robot to simulate")
    parser.add_argument("--count", type=int, help="number of trajectories, >= 1 (default: the paper's, 200 / 100)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (same seed -> same file)")
    parser.add_argument("--sample-period", type=float, default=DEFAULT_SAMPLE_PERIOD,
                        help="data sample period in s (default 0.01; the learned model steps at this period)")
    parser.add_argument("--plant-time-step", type=float, default=DEFAULT_PLANT_TIME_STEP,
                        help="discrete plant step in s (default 0.001)")
    parser.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                        help="worker processes (default: min(2, cores)); the data do not depend on it")
    parser.add_argument("--meshcat", action="store_true",
                        help="show each trajectory in Meshcat at real time as it is collected (prints the URL; "
                             "from a terminal, the server stays up until Ctrl+C)")
    parser.add_argument("--html", type=pathlib.Path,
                        help="save a standalone Meshcat HTML file that replays every collected trajectory")
    add_plant_effects_argument(parser, "the data come from the affected plant")
    add_visualization_argument(parser)
    parser.add_argument("--output", "-o", type=pathlib.Path, required=True, help="dataset file to write (.h5)")
    parser.add_argument("--export-plans", type=pathlib.Path, metavar="DIR",
                        help="tracking: also write every plan for a real controller into DIR (new or empty): CSV files "
                             "(t, q, q̇, q̈ per joint), a ROS 2 bag of trajectory_msgs/JointTrajectory, plans.json")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    add_force_argument(parser)


def request_from_args(args: argparse.Namespace) -> CollectionRequest:
    """`collection_request` from the command line's arguments."""
    return collection_request(args.protocol, count=args.count, seed=args.seed, config=args.config,
                              controller=args.controller, sensor=args.sensor, sample_period=args.sample_period,
                              plant_time_step=args.plant_time_step, robot=args.robot or UR10_CONFIG, workers=args.workers,
                              plant_effects=args.plant_effects)


def run(args: argparse.Namespace) -> int:
    import time

    request = request_from_args(args)
    robot = request.settings.robot
    inputs = [args.config, args.controller, args.sensor, args.robot, robot.model_path, args.visualization,
              args.plant_effects]
    visualization = command_visualization(args)
    if args.export_plans is not None:   # (first: the outputs' locks would put files in a new folder)
        from stdm_drake.collection.export import check_export_folder
        if request.protocol != "tracking":
            raise InputError("--export-plans: plans exist only with --protocol tracking")
        if pathlib.Path(args.output).absolute().is_relative_to(pathlib.Path(args.export_plans).absolute()):
            raise InputError(f"-o/--output {args.output} is inside --export-plans {args.export_plans}; write the "
                             "dataset elsewhere")
        check_export_folder(args.export_plans, args.force)
    check_output_file("-o/--output", args.output, kind="dataset", inputs=inputs, force=args.force)
    check_output_file("--html", args.html, kind="html", inputs=inputs + [args.output], force=args.force)
    if args.meshcat or args.html:
        check_meshcat_allowed("--meshcat" if args.meshcat else "--html")
    recorder = None
    if args.meshcat or args.html:
        from stdm_drake.robots.recorder import TrajectoryRecorder
        recorder = TrajectoryRecorder(request.settings.sample_period, robot=request.settings.robot,
                                      visualization=visualization)
        if args.meshcat:
            print(f"Meshcat: {recorder.meshcat.web_url()}", file=sys.stderr)
    started = time.perf_counter()
    trajectories, groups, metadata = collect(
        request, progress=not args.quiet,
        on_trajectory=None if recorder is None else lambda traj: recorder.add(traj.q_true, realtime=args.meshcat),
        check_size=lambda size: check_free_space(args.output, size + HDF5_RESERVE_BYTES))
    elapsed = time.perf_counter() - started
    path = write_dataset(args.output, trajectories, groups, metadata)
    simulated = sum(len(t.tau) for t in trajectories) * request.settings.sample_period
    print(f"wrote {path}: {len(trajectories)} {request.protocol} trajectories, {simulated:.1f} s simulated "
          f"in {elapsed:.1f} s ({simulated / elapsed:.1f}x real time)")
    if args.export_plans is not None:
        from stdm_drake.collection.export import export_plans
        written = export_plans(args.export_plans, trajectories, metadata, robot, args.force)
        print(f"wrote {len(trajectories)} plans to {args.export_plans} ({len(written)} files: CSV, a ROS 2 bag, "
              "plans.json); run them on the robot, then `stdm-drake import` its log")
    if recorder is not None:
        recorder.finish(args.html, keep_serving=args.meshcat)
    return 0
