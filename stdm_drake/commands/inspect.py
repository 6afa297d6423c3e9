"""`stdm-drake inspect`: print a summary of a dataset file, optionally checked against a robot."""
from __future__ import annotations

import argparse
import pathlib

from stdm_drake.data.dataset import load_dataset
from stdm_drake.data.inspect import summary


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dataset", type=pathlib.Path, help="dataset file (.h5) written by `stdm-drake collect`")
    parser.add_argument("--robot", type=pathlib.Path,
                        help="robot config YAML: refuse a dataset collected with another robot (default: no check)")


def run(args: argparse.Namespace) -> int:
    dataset = load_dataset(args.dataset)
    if args.robot is not None:
        from stdm_drake.data.compatibility import robot_for
        robot_for(args.robot, dataset)
    print(summary(dataset))
    return 0
