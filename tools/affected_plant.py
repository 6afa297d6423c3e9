"""The command line the affected-plant experiment tools share (tools/reality_gap.py,
tools/identification_study.py): output and data folders, the robot and its effects file, workers, --quick;
and the robot and effects they name, checked, or a one-line error."""
import argparse
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]


def parser_for(doc: str, name: str, quick_minutes: int) -> argparse.ArgumentParser:
    """An ArgumentParser with the shared options: -o (docs/results/NAME), --data (out/NAME_data), --robot,
    --plant-effects, --workers, --quick."""
    from stdm_drake.experiments.reality_gap import EFFECTS_PRESET
    from stdm_drake.robots.robot import UR10_CONFIG
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("-o", "--output", type=pathlib.Path, default=ROOT / "docs" / "results" / name)
    parser.add_argument("--data", type=pathlib.Path, default=ROOT / "out" / f"{name}_data")
    parser.add_argument("--robot", type=pathlib.Path, default=UR10_CONFIG, help="robot config (the nominal model)")
    parser.add_argument("--plant-effects", type=pathlib.Path, default=EFFECTS_PRESET,
                        help="the affected plant's effects (default: models/ur10_effects.yaml)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--quick", action="store_true",
                        help=f"tiny sizes: a pipeline check (about {quick_minutes} min)")
    return parser


def robot_and_effects(args, tool: str):
    """(Robot, PlantEffects) of --robot and --plant-effects, or None after a one-line error on stderr."""
    from stdm_drake.errors import InputError
    from stdm_drake.robots.plant import plant_effects_for
    from stdm_drake.robots.robot import load_robot
    try:
        robot = load_robot(args.robot)
        return robot, plant_effects_for(args.plant_effects, robot, 0.001)
    except InputError as error:
        print(f"{tool}: error: {error}", file=sys.stderr)
        return None
