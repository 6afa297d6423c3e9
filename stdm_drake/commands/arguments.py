"""What several commands' command lines share: the `--robot` option (when absent: the shipped preset a dataset
was collected with, else the UR-10's), the
`--visualization` option of the commands that record Meshcat animations, and the flags of a settings dataclass."""
import argparse
import dataclasses
import pathlib
import typing


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


def add_settings_flags(parser: argparse.ArgumentParser, settings_class) -> None:
    """One flag per field of a settings dataclass (`learning.settings.TrainSettings`): `--hidden-width` for
    `hidden_width`, its help, choices and conversion from the field's `setting` metadata, its type from the field's
    annotation (a list: one or more values; a bool: a switch). A flag left out stays absent from the parsed
    arguments (argparse.SUPPRESS), so the settings file, or the field's default, decides."""
    hints = typing.get_type_hints(settings_class)
    for field in dataclasses.fields(settings_class):
        meta, annotation = field.metadata, hints[field.name]
        default = field.default_factory() if field.default is dataclasses.MISSING else field.default
        options = dict(default=argparse.SUPPRESS, help=meta["help"])
        if annotation is bool:
            options["action"] = "store_true"
        else:
            options["type"] = meta.get("parse") or _flag_type(annotation)
            if typing.get_origin(annotation) in (list, typing.List):
                options["nargs"] = "+"
            if meta.get("choices"):
                options["choices"] = tuple(meta["choices"])
            shown = " ".join(map(_shown, default)) if isinstance(default, list) else _shown(default)
            if "{default}" in meta["help"]:
                options["help"] = meta["help"].replace("{default}", shown)
            elif default is not None and default != []:
                options["help"] = f"{meta['help']} (default {shown})"
        parser.add_argument("--" + field.name.replace("_", "-"), **options)


def _shown(value) -> str:
    """A default as its flag would take it: 0.001 as 1e-3, 0.0 as 0."""
    return f"{value:g}" if isinstance(value, float) else str(value)


def _flag_type(annotation):
    """The value type of a settings field's annotation: int for Optional[int] or List[int], and so on."""
    arguments = [a for a in typing.get_args(annotation) if a is not type(None)]
    return arguments[0] if arguments else annotation
