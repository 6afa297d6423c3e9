"""The options the affected-plant studies share (reality-gap, identification): output and data folders, the
robot and its effects file, workers, --quick; and the robot and effects they name, checked."""
import argparse
import pathlib

from stdm_drake.paths import MODELS_DIR

ROOT = pathlib.Path(__file__).resolve().parents[2]
EFFECTS_PRESET = MODELS_DIR / "ur10_effects.yaml"   # the UR-10's affected plant (the studies' default)


def add_affected_plant_arguments(parser: argparse.ArgumentParser, name: str, quick_minutes: int) -> None:
    """The shared options: -o (docs/results/NAME), --data (out/NAME_data), --robot, --plant-effects, --workers,
    --quick."""
    from stdm_drake.robots.robot import UR10_CONFIG
    parser.add_argument("-o", "--output", type=pathlib.Path, default=ROOT / "docs" / "results" / name)
    parser.add_argument("--data", type=pathlib.Path, default=ROOT / "out" / f"{name}_data")
    parser.add_argument("--robot", type=pathlib.Path, default=UR10_CONFIG, help="robot config (the nominal model)")
    parser.add_argument("--plant-effects", type=pathlib.Path, default=EFFECTS_PRESET,
                        help="the affected plant's effects (default: models/ur10_effects.yaml)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--quick", action="store_true",
                        help=f"tiny sizes: a pipeline check (about {quick_minutes} min)")


def robot_and_effects(args: argparse.Namespace):
    """(Robot, PlantEffects) of --robot and --plant-effects (an InputError of one line where they are bad)."""
    from stdm_drake.robots.plant_effects_check import plant_effects_for
    from stdm_drake.robots.robot import load_robot
    robot = load_robot(args.robot)
    return robot, plant_effects_for(args.plant_effects, robot, 0.001)


def quick_folders(args: argparse.Namespace, name: str) -> None:
    """With --quick, the default output and data folders become out/NAME_quick and out/NAME_quick_data (a pipeline
    check never writes over the committed results or reuses the full run's models)."""
    if args.quick and args.output == ROOT / "docs" / "results" / name:
        args.output = ROOT / "out" / f"{name}_quick"
    if args.quick and args.data == ROOT / "out" / f"{name}_data":
        args.data = ROOT / "out" / f"{name}_quick_data"
