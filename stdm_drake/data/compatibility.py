"""Which robot a dataset belongs to: the robot a command's `--robot` names, checked once (its plant
loads, its home is free of self-collision) and checked against a dataset's recorded robot and limits.
The one place where robot, dataset and plant meet; checkpoints compare their recorded robot in
`learning.learned_model`."""
import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.robots.plant import JointLimits, SelfCollisionChecker, joint_limits
from stdm_drake.robots.robot import Robot, load_robot, UR10_CONFIG
from stdm_drake.paths import MODELS_DIR


def shipped_preset_of(dataset):
    """The shipped robot preset (models/*.yaml) `dataset` was collected with, by its recorded joint names and
    description file (SHA-256), the UR-10's first and then by name (so a preset's plant-effects variant, which
    shares its description, is never picked over it); None when no preset matches (a user's own robot). A user's
    own config on a shipped description file gets the preset: the nominal model is the description, the same."""
    recorded = dataset.metadata
    if recorded.robot_model_sha256 is None:
        return None
    presets = [UR10_CONFIG] + sorted(path for path in MODELS_DIR.glob("*.yaml") if path != UR10_CONFIG)
    for path in presets:
        try:
            robot = load_robot(path)
        except InputError:   # (a YAML there that is no robot preset)
            continue
        if recorded.joint_names in (None, list(robot.joint_names)) and \
                recorded.robot_model_sha256 == robot.model_sha256():
            return path
    return None


def resolve_robot(path=None, dataset=None) -> Robot:
    """The robot a job runs with: the config YAML at `path`, else the shipped preset `dataset` was collected with
    (`shipped_preset_of`), else the UR-10's (the toolbox's default robot); loaded and checked by `robot_for`
    (with `dataset`: InputError unless the dataset was collected with it)."""
    return robot_for(path or (shipped_preset_of(dataset) if dataset is not None else None) or UR10_CONFIG, dataset)


def robot_for(path, dataset=None) -> Robot:
    """The robot of the config YAML at `path` (a command's `--robot`), its plant built once to check
    that it loads and that home is free of self-collision; with `dataset`, InputError unless the dataset
    was collected with it (`check_dataset_robot`)."""
    robot = load_robot(path)
    checker = SelfCollisionChecker(robot)  # the model loads, and its home is free of self-collision, before any work
    if dataset is not None:
        check_dataset_robot(dataset, robot, joint_limits(checker.plant))
    return robot


def check_dataset_robot(dataset, robot: Robot, limits: JointLimits) -> None:
    """InputError unless `dataset` (a loaded Dataset) was collected with `robot`: the same joints and model
    file, as its metadata records them, and states within `limits` (the robot's joint limits) give or take
    `check_within_limits`'s margins."""
    recorded = dataset.metadata
    name = recorded.robot_name or "?"
    if recorded.joint_names is not None and recorded.joint_names != list(robot.joint_names):
        raise InputError(f"{dataset.path} was collected with robot {name} (joints {recorded.joint_names}), "
                         f"not {robot.name}; pass its config with --robot")
    if recorded.robot_model_sha256 not in (None, robot.model_sha256()):
        raise InputError(f"{dataset.path} was collected with another model file than {robot.model_path.name} "
                         f"(robot {name}); pass its config with --robot")
    check_array_widths(dataset, robot)
    check_within_limits(dataset, robot, limits)


def check_array_widths(dataset, robot: Robot) -> None:
    """InputError unless every array of every trajectory has one column per joint of `robot` (n), the
    actions (tau, tau_next) one per actuated joint (m)."""
    for index in range(dataset.num_trajectories):
        for key, array in dataset.trajectory(index).arrays().items():
            action = key in ("tau", "tau_next")
            count = robot.action_dim if action else robot.num_joints
            if array.shape[-1] != count:
                raise InputError(f"{dataset.path}: trajectory {index} {key} has {array.shape[-1]} columns, robot "
                                 f"{robot.name} has {count} {'actuated joints' if action else 'joints'}; not this "
                                 "robot's data")


def check_within_limits(dataset, robot: Robot, limits: JointLimits, position_margin: float = 0.5,
                        velocity_factor: float = 1.5) -> None:
    """InputError if the dataset's states (q, v: (T, n) per trajectory, n: the robot's, `check_array_widths`) leave the position limits by more
    than `position_margin` (rad or m) or the velocity limits by more than `velocity_factor` times."""
    for index in range(dataset.num_trajectories):
        traj = dataset.trajectory(index)
        for key, low, high in (("q", limits.position_lower - position_margin, limits.position_upper + position_margin),
                               ("v", -velocity_factor * limits.velocity, velocity_factor * limits.velocity)):
            outside = (getattr(traj, key) < low) | (getattr(traj, key) > high)
            if outside.any():
                step, joint = np.argwhere(outside)[0]
                raise InputError(f"{dataset.path}: trajectory {index} {key} of {robot.joint_names[joint]} is "
                                 f"{getattr(traj, key)[step, joint]:.4g} at step {step}, far outside robot {robot.name}'s "
                                 "limits; not this robot's data")
