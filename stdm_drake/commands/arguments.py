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
    from stdm_drake.data.compatibility import robot_for, shipped_preset_of
    from stdm_drake.robots.robot import UR10_CONFIG
    path = args.robot or (shipped_preset_of(dataset) if dataset is not None else None) or UR10_CONFIG
    return robot_for(path, dataset)


def add_visualization_argument(parser: argparse.ArgumentParser) -> None:
    """`--visualization PATH`: Drake's VisualizationConfig YAML for the Meshcat recording."""
    parser.add_argument("--visualization", type=pathlib.Path,
                        help="Drake VisualizationConfig YAML for the Meshcat recording, e.g. `publish_proximity: "
                             "true` to show the collision geometry (default: the illustration geometry only)")


def check_meshcat_allowed(option: str) -> None:
    """`option` (--html, --meshcat) needs Meshcat's server: refused at once when DRAKE_ALLOW_NETWORK (a list of
    the services Drake may open, separated by ":"; unset or empty: all) leaves Meshcat out."""
    import os
    allowed = os.environ.get("DRAKE_ALLOW_NETWORK", "")
    if allowed and "meshcat" not in allowed.split(":"):
        from stdm_drake.errors import InputError
        raise InputError(f"{option} needs Meshcat, which DRAKE_ALLOW_NETWORK={allowed} turns off; set "
                         "DRAKE_ALLOW_NETWORK=meshcat (Meshcat serves on this machine only)")


def command_visualization(args: argparse.Namespace):
    """The VisualizationConfig `--visualization` names (None when absent: the recorder's default)."""
    if args.visualization is None:
        return None
    if not (getattr(args, "html", None) or getattr(args, "meshcat", False)):
        from stdm_drake.errors import InputError
        raise InputError("--visualization configures the Meshcat recording: give --html FILE"
                         + (" or --meshcat" if hasattr(args, "meshcat") else "") + " too, or leave it out")
    from stdm_drake.robots.recorder import load_visualization_config
    return load_visualization_config(args.visualization)


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


def load_model_file(path):
    """The file behind a model: a `Checkpoint` that `train` wrote (.pt) or an `IdentifiedRobot` that
    `identify` wrote (.yaml); both know their dataset (`check_fits`, `trained_on`, `split_indices`)."""
    from stdm_drake.identification.identified import is_identified_file, load_identified
    from stdm_drake.learning.checkpoint import load_checkpoint
    return load_identified(path) if is_identified_file(path) else load_checkpoint(pathlib.Path(path))


def command_model(source, robot, *, name: str | None = None, **learned_options):
    """The model of a model file (a path, or what `load_model_file` loaded), its file as `model.checkpoint`:
    a checkpoint as a `LearnedModel` (`learned_options` passed on), an identified robot as the
    description's plant with its parameters (which needs `robot`). Without `name`: the checkpoint's model
    type ("model" if it has none), or "identified"."""
    from stdm_drake.errors import InputError
    from stdm_drake.identification.identified import IdentifiedRobot
    from stdm_drake.learning.learned_model import LearnedModel
    if isinstance(source, (str, pathlib.Path)):
        source = load_model_file(source)
    if isinstance(source, IdentifiedRobot):
        if robot is None:
            raise InputError(f"{source.path}: an identified robot needs its robot (--robot)")
        return source.model(robot, name=name or "identified")
    model = LearnedModel(source, name=name, robot=robot, **learned_options)
    if name is None:
        model.name = model.checkpoint.metadata.model_type or "model"
    return model


def model_description(model) -> str:
    """One line on what a model file's model is (architecture and training, or the identification)."""
    from stdm_drake.learning.learned_model import LearnedModel
    if not isinstance(model, LearnedModel):
        record = model.checkpoint.identification
        return (f"model {model.name}: identified rigid-body model of {record.robot} from {pathlib.Path(record.dataset).name}"
                f" ({record.derivative_source} derivatives, Coulomb velocity scale {record.coulomb_velocity_scale:g} "
                f"rad/s; test torque error {record.test_torque_error:.3g})")
    checkpoint = model.checkpoint
    config = checkpoint.model_config
    alpha = checkpoint.training_config.alpha if checkpoint.training_config else float("nan")
    return (f"model {model.name}: {config.hidden_layers}x{config.hidden_width} {config.activation}, "
            f"{config.ensemble_size} member(s), {'probabilistic' if config.probabilistic else 'deterministic'}, "
            f"{'delta' if config.residual else 'direct'}, {model.structure.label}, derivative alpha {alpha:g}"
            + (f" ({checkpoint.metadata.derivative_source} targets)" if alpha > 0 and checkpoint.metadata.derivative_source
               else ""))
