"""What several commands' command lines share: the `--robot` option (when absent: the shipped preset a dataset
was collected with, else the UR-10's), the
`--visualization` option of the commands that record Meshcat animations, and the `--alpha` value type."""
import argparse
import pathlib

import numpy as np


def add_robot_argument(parser: argparse.ArgumentParser, role: str) -> None:
    """`--robot PATH`: a robot config YAML; `role` says what the command does with it."""
    parser.add_argument("--robot", type=pathlib.Path, help=f"robot config YAML (default: the shipped preset the "
                                                           f"dataset was collected with, else the UR-10's, "
                                                           f"models/ur10.yaml); {role}")


def command_robot(args: argparse.Namespace, dataset=None):
    """The Robot `--robot` names, its plant loaded and its home checked free of self-collision; when absent the
    shipped preset `dataset` was collected with (`data.compatibility.shipped_preset_of`), else the UR-10's; with
    `dataset`, InputError unless the dataset was collected with it."""
    from stdm_drake.data.compatibility import resolve_robot
    return resolve_robot(args.robot, dataset)


def add_visualization_argument(parser: argparse.ArgumentParser) -> None:
    """`--visualization PATH`: Drake's VisualizationConfig YAML for the Meshcat recording."""
    parser.add_argument("--visualization", type=pathlib.Path,
                        help="Drake VisualizationConfig YAML for the Meshcat recording, e.g. `publish_proximity: "
                             "true` to show the collision geometry (default: the illustration geometry only)")


def add_plant_effects_argument(parser: argparse.ArgumentParser, role: str) -> None:
    """`--plant-effects PATH`: the effects the simulated plant has beyond the robot's description."""
    parser.add_argument("--plant-effects", type=pathlib.Path, metavar="FILE",
                        help="plant effects YAML (friction, rotor inertia, payload, mass scales, torque noise; e.g. "
                             f"models/ur10_effects.yaml): {role}; the robot file stays the nominal model")


def parse_alpha(text: str):
    """--alpha: a number >= 0 or the word 'auto'."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0 or 'auto', got {text!r}") from None
    if not (np.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected a number >= 0 or 'auto', got {text!r}")
    return value
