"""`stdm-drake collect`: simulate a robot under a data protocol (excitation or tracking) and write a
dataset (the job: `collection.collect_job`)."""
import argparse
import pathlib

from stdm_drake.collection.protocols import PROTOCOLS
from stdm_drake.commands.arguments import add_plant_effects_argument, add_robot_argument, add_visualization_argument
from stdm_drake.outputs import add_force_argument
from stdm_drake.robots.plant import DEFAULT_PLANT_TIME_STEP
from stdm_drake.robots.station import DEFAULT_SAMPLE_PERIOD


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--protocol", choices=PROTOCOLS,
                        help="data protocol (default: the one --config's tag names, `protocol: !Excitation` or "
                             "`!Tracking`; else tracking)")
    parser.add_argument("--config", type=pathlib.Path,
                        help="protocol YAML (default: the file the robot config's `defaults` names, for the UR-10 "
                             "trajectories/excitation.yaml or tracking.yaml; without one, excitation ranges and "
                             "tracking poses derived from the robot, see docs/guides/robots.md)")
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
    parser.add_argument("--workers", type=int, default=None,
                        help="worker processes (default: 1 for a job under 25,000 plant steps, e.g. 24 tracked "
                             "plans, else min(2, cores)); the data do not depend on it")
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


def run(args: argparse.Namespace) -> int:
    from stdm_drake.collection.collect_job import CollectJob, collect_job
    collect_job(CollectJob(output=args.output, protocol=args.protocol, count=args.count, seed=args.seed,
                           config=args.config, controller=args.controller, sensor=args.sensor, robot=args.robot,
                           sample_period=args.sample_period, plant_time_step=args.plant_time_step,
                           workers=args.workers, plant_effects=args.plant_effects, meshcat=args.meshcat,
                           html=args.html, visualization=args.visualization, export_plans=args.export_plans,
                           progress=not args.quiet, force=args.force))
    return 0
