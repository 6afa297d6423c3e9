"""Robots: the typed robot config (RobotConfig, the UR-10 preset models/ur10.yaml), the Robot that adds
itself to a Drake MultibodyPlant. The description file itself: `stdm_drake.robots.model_file`; plants and
simulators: `stdm_drake.robots.plant`.

For a robot of n arm joints (in its config's order; the UR-10: shoulder_pan, shoulder_lift, elbow,
wrist_1, wrist_2, wrist_3): state x = [q (n) rad, v (n) rad/s]; action = the torques (m) N m of its
m actuated arm joints, in the same order (m = n unless the config lists unactuated joints, like the
Acrobot's shoulder).
"""
import dataclasses
import hashlib
import logging
import math
import pathlib
import typing

import numpy as np

from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlant

from stdm_drake.config import one_line, require, load_yaml_config
from stdm_drake.errors import InputError
from stdm_drake.files import line_text
from stdm_drake.robots.description import SUFFIXES, check_description
from stdm_drake.robots.inertia_substitution import drake_inertia_warnings_left_out, inertia_substitutions
from stdm_drake.robots.limit_checks import check_config_limit, limit_overrides, limits_drake_refuses
from stdm_drake.robots.mass_matrix import check_arm_inertias
from stdm_drake.robots.meshes import mesh_cache_dir
from stdm_drake.robots.model_file import (joint_facts, loadable_model, offline_parser,
                                   srdf_disabled_collisions, unmodelled_joint_effects, weld_joint_at)
from stdm_drake.robots.nested_models import check_nested_fixed, frame_by_name, nested_joint_note, robot_instance
from stdm_drake.paths import MODELS_DIR, SHIPPED_PREFIX, check_input_file, shipped_file

UR10_CONFIG = MODELS_DIR / "ur10.yaml"
POSE_DIM = 6  # coordinates a tool pose fixes: rotation (3) and position (3)
logger = logging.getLogger(__name__)


@dataclasses.dataclass
class RobotDefaults:
    """The files commands use for a robot when not told otherwise (paths relative to the robot's YAML
    file, or stdm-drake:FOLDER/NAME); an empty one is derived from the robot's model instead (see the
    robots guide's table of derived settings, docs/guides/robots.md). excitation: `collect --protocol excitation` ranges;
    excitation_local: reproduce's local excitation data; tracking: `collect --protocol tracking` poses
    and planner; identification_controller: reproduce's identification data; mpc: `mpc` settings."""
    excitation: str = ""
    excitation_local: str = ""
    tracking: str = ""
    identification_controller: str = ""
    mpc: str = ""


@dataclasses.dataclass
class RobotConfig:
    """A robot arm as stdm-drake sees it (typed YAML, loaded with `load_robot`).

    name: a label for files and plots. model: the URDF or SDF file (a path relative to the YAML file's
    folder, package://, or stdm-drake:models/NAME for a shipped one); package_paths: package name ->
    folder, for package:// URIs (relative paths: to the YAML file's folder). weld_frame: the frame
    welded to the world origin, or None when the model fixes its base itself (e.g. a joint to
    "world"). arm_joints: the joints the data, models and controllers see, in the model's order
    (one revolute or prismatic degree of freedom each); locked_joints: any other movable joint ->
    the position (rad or m) it is welded at (fingers, say). effort_limits (N m or N) and
    velocity_limits (rad/s or m/s): per arm joint, for joints whose file gives none (or to replace
    the file's); an arm joint without an actuator gets one with its effort limit (from the file's
    <limit effort=...>, else from effort_limits). unactuated_joints: arm joints that move freely with
    no actuator (an underactuated robot such as the Acrobot; an actuator the file gives them is
    removed): the action then has one torque per actuated arm joint, and tracking and MPC refuse the
    robot. home: one position per arm joint (rad or m), a configuration well inside the limits.
    tool_frame: the frame task-space plans move. Position limits come from the file or position_limits;
    only a URDF "continuous" joint may have none. srdf: a MoveIt SRDF (path or package:// URI) whose
    <disable_collisions link1= link2=> pairs never count as self-collision (nor touch in simulation);
    disabled_collisions: more such link pairs, [[link_a, link_b], ...]. defaults: the protocol,
    controller and MPC files written for this robot (`RobotDefaults`; absent ones are derived).
    """
    name: str = ""
    model: str = ""
    package_paths: typing.Dict[str, str] = dataclasses.field(default_factory=dict)
    weld_frame: typing.Optional[str] = None
    arm_joints: typing.List[str] = dataclasses.field(default_factory=list)
    locked_joints: typing.Dict[str, float] = dataclasses.field(default_factory=dict)
    effort_limits: typing.Dict[str, float] = dataclasses.field(default_factory=dict)
    velocity_limits: typing.Dict[str, float] = dataclasses.field(default_factory=dict)
    position_limits: dict[str, list[float]] = dataclasses.field(default_factory=dict)
    unactuated_joints: typing.List[str] = dataclasses.field(default_factory=list)
    home: typing.List[float] = dataclasses.field(default_factory=list)
    tool_frame: str = ""
    srdf: str = ""
    disabled_collisions: list[list[str]] = dataclasses.field(default_factory=list)
    defaults: RobotDefaults = dataclasses.field(default_factory=RobotDefaults)

    def validate(self) -> None:
        """Checks that need no model file (the rest happen when the plant is built)."""
        if not self.name or not self.model or not self.tool_frame:
            raise InputError("robot config needs name, model and tool_frame")
        require(self.arm_joints and len(set(self.arm_joints)) == len(self.arm_joints),
                "robot config arm_joints must list distinct joints", self.arm_joints)
        if len(self.home) != len(self.arm_joints) or not all(math.isfinite(value) for value in self.home):
            raise InputError(f"robot config home must give {len(self.arm_joints)} finite positions (one per arm "
                             f"joint), got {self.home}")
        require(set(self.unactuated_joints) <= set(self.arm_joints) and len(set(self.unactuated_joints)) == len(
            self.unactuated_joints), "robot config unactuated_joints must list distinct arm joints", self.unactuated_joints)
        for pair in self.disabled_collisions:
            if len(pair) != 2 or not all(isinstance(link, str) and link for link in pair) or pair[0] == pair[1]:
                raise InputError(f"robot config disabled_collisions: each entry is two different link names, got {pair}")
        if len(self.unactuated_joints) == len(self.arm_joints):
            raise InputError("robot config: every arm joint is unactuated; the robot needs at least one actuator")
        if overlap := set(self.locked_joints) & set(self.arm_joints):
            raise InputError(f"robot config: joints {sorted(overlap)} are both arm joints and locked")
        require(all(map(math.isfinite, self.locked_joints.values())),   # (NaN: an eigenvalue solver's error, later)
                "robot config locked_joints must lock each joint at a finite position (rad or m)", self.locked_joints)
        for field in ("effort_limits", "velocity_limits"):
            for joint, value in getattr(self, field).items():
                check_config_limit(field, joint, value, self.arm_joints)
        for joint, values in self.position_limits.items():
            if joint not in self.arm_joints and joint not in self.locked_joints:
                raise InputError(f"robot config position_limits: {joint!r} is not an arm or locked joint")
            require(len(values) == 2 and all(abs(value) <= 1e6 for value in values) and values[0] < values[1], f"robot "
                    f"config position_limits[{joint!r}] must be [lower, upper], lower < upper, within 1e6 (rad or m)", values)


class Robot:
    """A robot built from a RobotConfig: adds itself to a MultibodyPlant and says what it is.
    joint_names: the arm joints in order; num_joints; home (n,) rad; tool_frame; model_path and
    model_sha256 (of the description file, recorded in datasets); config_path: the YAML it was loaded
    from (`load_robot`; None in code); inertia_substitutions: per link, what Drake simulates in place of its
    inertia (`inertia_substitution.inertia_substitution`, also recorded in datasets)."""
    config_path: pathlib.Path | None = None

    def __init__(self, config: RobotConfig, folder: pathlib.Path):
        config.validate()
        self.config = config
        self.folder = pathlib.Path(folder)
        self.package_paths = {name: self._resolve(path) for name, path in config.package_paths.items()}
        for name, path in self.package_paths.items():
            if not path.is_dir():
                raise InputError(f"robot {config.name}: package {name!r} folder not found: {path}")
        self.model_path = check_input_file(self._model_file(config.model), f"robot {config.name}: model file")
        if self.model_path.suffix.lower() not in SUFFIXES:
            raise InputError(f"robot {config.name}: model must be a .urdf or .sdf file, got {self.model_path.name}")
        overrides = limit_overrides(config.position_limits, config.velocity_limits, config.effort_limits)
        description = check_description(self.model_path, self.name, config.arm_joints, overrides, config.locked_joints,
                                        self.package_paths)
        self.inertia_substitutions = inertia_substitutions(description)
        for link, substitute in self.inertia_substitutions.items():
            logger.warning("robot %s: %s: link %r has %s", self.name, self.model_path.name, link, substitute)
        self.file_limits, self.continuous_joints, self.mimic_pairs = joint_facts(self.model_path, self.package_paths)
        for effect in unmodelled_joint_effects(self.model_path, config.arm_joints):
            logger.warning("robot %s: %s states %s", self.name, self.model_path.name, effect)
        self.srdf_path = self._model_file(config.srdf, "srdf") if config.srdf else None
        self._srdf_pairs = srdf_disabled_collisions(self.srdf_path, self.name) if self.srdf_path else []
        self._reported_srdf_links = False
        # the model text to parse when meshes are missing or converted (None: the file itself), read once
        refused = limits_drake_refuses(description)   # (the others go on the plant, `add_to` and `check_plant`)
        loadable = loadable_model(self.name, self.model_path, self.package_paths,
                                  {joint: values for joint, values in overrides.items() if joint in refused})
        self._model_text = loadable.text
        for warning in loadable.warnings(self.model_path.name):
            logger.warning("robot %s: %s", self.name, warning)
        if loadable.converted:
            logger.info("robot %s: %d meshes read through OBJ copies in %s", self.name, len(loadable.converted),
                        mesh_cache_dir())

    def disabled_collisions(self, has_link) -> list[tuple[str, str]]:
        """The link pairs whose contact is ignored: the SRDF's <disable_collisions> and the config's
        disabled_collisions, of the links for which has_link(name) is true. A config pair naming another
        link is an InputError; SRDF pairs naming links the model lacks (an SRDF written for the arm with
        its gripper, say) are left out with one warning."""
        unknown = [link for pair in self.config.disabled_collisions for link in pair if not has_link(link)]
        if unknown:
            raise InputError(f"robot {self.name}: disabled_collisions names {unknown[0]!r}, not a link of "
                             f"{self.model_path.name}")
        absent = sorted({link for pair in self._srdf_pairs for link in pair if not has_link(link)})
        if absent and not self._reported_srdf_links:
            self._reported_srdf_links = True
            logger.warning("robot %s: %s names links the model lacks (%s); their pairs are left out", self.name,
                           self.srdf_path.name, ", ".join(absent))
        pairs = [tuple(pair) for pair in self.config.disabled_collisions]
        return pairs + [pair for pair in self._srdf_pairs if all(has_link(link) for link in pair)]

    def default_file(self, purpose: str) -> pathlib.Path | None:
        """The file the robot's config names for `purpose` (a `RobotDefaults` field), or None: derive it.
        InputError when the named file is missing."""
        value = getattr(self.config.defaults, purpose)
        if not value:
            return None
        return check_input_file(self._resolve(value), f"robot {self.name}: defaults.{purpose} file")

    def _model_file(self, model: str, what: str = "model") -> pathlib.Path:
        """The model (or SRDF, `what`) file: a path (relative to the config's folder), or package://NAME/PATH
        in one of package_paths or a package Drake ships locally (package://drake/examples/acrobot/Acrobot.urdf)."""
        if not model.startswith("package://"):
            return self._resolve(model)
        package, _, rest = model[len("package://"):].partition("/")
        if package in self.package_paths:
            return self.package_paths[package] / rest
        package_map = offline_parser(MultibodyPlant(0.0)).package_map()
        if not package_map.Contains(package):
            raise InputError(f"robot {self.config.name}: {what} {model!r}: unknown package {package!r}; map it under "
                             "package_paths")
        return pathlib.Path(package_map.GetPath(package)) / rest

    def _resolve(self, path: str) -> pathlib.Path:
        if path.startswith(SHIPPED_PREFIX):  # stdm-drake:models/ur10.urdf
            try:
                return shipped_file(path)
            except ValueError as error:
                raise InputError(f"robot {self.config.name}: {error}") from None
        path = pathlib.Path(path)
        path = path if path.is_absolute() else self.folder / path
        try:
            return path.resolve()
        except RuntimeError:   # a symlink loop (Python < 3.13): `check_input_file` names it
            return path.absolute()

    @property
    def name(self) -> str:
        return self.config.name

    @property
    def joint_names(self) -> tuple:
        return tuple(self.config.arm_joints)

    @property
    def num_joints(self) -> int:
        return len(self.config.arm_joints)

    @property
    def actuated_joint_names(self) -> tuple:
        """The arm joints with an actuator, in arm order: one torque each in the action."""
        return tuple(name for name in self.config.arm_joints if name not in self.config.unactuated_joints)

    @property
    def actuated_indices(self) -> np.ndarray:
        """Positions (m,) of the actuated joints among the arm joints."""
        return np.array([j for j, name in enumerate(self.config.arm_joints) if name not in self.config.unactuated_joints])

    @property
    def action_dim(self) -> int:
        """Size of the action: torques of the actuated arm joints."""
        return len(self.config.arm_joints) - len(self.config.unactuated_joints)

    @property
    def fully_actuated(self) -> bool:
        return not self.config.unactuated_joints

    def check_fully_actuated(self, what: str) -> None:
        """InputError unless every arm joint has an actuator; `what` names what needs it."""
        if not self.fully_actuated:
            raise InputError(f"robot {self.name} is underactuated ({', '.join(self.config.unactuated_joints)} without an "
                             f"actuator): {what} needs a torque on every joint; use the excitation protocol, train and "
                             "evaluate")

    @property
    def state_dim(self) -> int:
        """Size of the state x = [q, v]."""
        return 2 * len(self.config.arm_joints)

    @property
    def home(self) -> np.ndarray:
        return np.asarray(self.config.home, dtype=float)

    @property
    def tool_frame(self) -> str:
        return self.config.tool_frame

    def check_can_track(self) -> None:
        """InputError unless the robot can follow task-space plans with joint torques: at least 6 arm
        joints (a tool pose has 6 coordinates), every one of them actuated."""
        self.check_fully_actuated("tracking task-space plans")
        if self.num_joints < POSE_DIM:
            raise InputError(f"robot {self.name} has {self.num_joints} arm joints; task-space plans place the tool's "
                             f"position and orientation and need at least {POSE_DIM}: use the excitation protocol")

    def record(self) -> dict:
        """What a result file records of the robot: its name, config YAML, description file and its sha256."""
        return dict(name=self.name, config=None if self.config_path is None else str(self.config_path),
                    model=str(self.model_path), model_sha256=self.model_sha256())

    def model_sha256(self) -> str:
        """SHA-256 of the robot description file, stored in every dataset."""
        return hashlib.sha256(self.model_path.read_bytes()).hexdigest()

    def add_to(self, plant: MultibodyPlant, model_name_prefix: str = ""):
        """Parse the model into `plant` (not finalized), weld its base, lock the locked joints, add missing arm
        actuators; return its instance, named with model_name_prefix ("ghost::ur10": copies sharing a plant)."""
        parser = offline_parser(plant, model_name_prefix)
        for name, path in self.package_paths.items():
            parser.package_map().Add(name, str(path))
        text, before = self._model_text, plant.num_model_instances()
        try:
            with drake_inertia_warnings_left_out(bool(self.inertia_substitutions)):
                instances = (parser.AddModels(str(self.model_path)) if text is None
                             else parser.AddModelsFromString(text, self.model_path.suffix.lower().lstrip(".")))
        except (RuntimeError, ValueError) as error:   # (ValueError: a number Drake's parser cannot read, "nan")
            why = next((f" (SDFormat refuses a world holding link {link!r}: {text.split(':')[0]})" for link, text in
                        self.inertia_substitutions.items() if "Failed to load a world" in str(error)), "")
            raise InputError(f"robot {self.name}: {self.model_path.name} does not load: {one_line(error)}{why}") from None
        instance = robot_instance(plant, instances, f"robot {self.name}: {self.model_path.name}", added_from=before)
        config = self.config
        if config.weld_frame is not None:
            if not plant.HasFrameNamed(config.weld_frame, instance):
                raise InputError(f"robot {self.name}: weld_frame {config.weld_frame!r} is not a frame of the model")
            try:
                plant.WeldFrames(plant.world_frame(), plant.GetFrameByName(config.weld_frame, instance), RigidTransform())
            except RuntimeError as error:
                raise InputError(f"robot {self.name}: cannot weld {config.weld_frame!r} to the world, the model already "
                                 f"fixes it there ({one_line(error)}); leave weld_frame out") from None
        if frame_by_name(plant, config.tool_frame, instance) is None:
            links = [plant.get_body(index).name() for index in plant.GetBodyIndices(instance)]
            shown = f"its {len(links)} links end with " if len(links) > 5 else "its links: "
            raise InputError(f"robot {self.name}: tool_frame {config.tool_frame!r} is not a frame of "
                             f"{self.model_path.name} ({shown}{', '.join(links[-5:])})")
        for name in list(config.arm_joints) + list(config.locked_joints):
            if not plant.HasJointNamed(name, instance):
                raise InputError(f"robot {self.name}: joint {name!r} is not in {self.model_path.name}"
                                 f"{nested_joint_note(plant, name, instance)}")
        self._remove_mimic_constraints(plant)
        for name, (lower, upper) in config.position_limits.items():
            if name in config.arm_joints:
                plant.GetJointByName(name, instance).set_position_limits([lower], [upper])
        for name, position in config.locked_joints.items():
            weld_joint_at(plant, plant.GetJointByName(name, instance), position)
        actuators = {plant.get_joint_actuator(index).joint().name(): plant.get_joint_actuator(index)
                     for index in plant.GetJointActuatorIndices()
                     if plant.get_joint_actuator(index).model_instance() == instance}
        efforts = {}  # actuated arm joint -> effort limit
        for name in config.arm_joints:
            joint = plant.GetJointByName(name, instance)
            if joint.num_velocities() != 1:
                raise InputError(f"robot {self.name}: arm joint {name!r} has {joint.num_velocities()} degrees of "
                                 "freedom; arm joints must be revolute or prismatic")
            if name in config.unactuated_joints:
                continue
            effort = config.effort_limits.get(name)
            if effort is None and name in actuators:
                effort = actuators[name].effort_limit()
            if effort is None:
                effort = self.file_limits.get(name, {}).get("effort")
            if effort is None or not 0 < effort < math.inf:
                raise InputError(f"robot {self.name}: arm joint {name!r} has no effort limit; give effort_limits in "
                                 "the robot config")
            efforts[name] = effort
        # one actuator per actuated arm joint, in arm order (the action's order); rebuilt when the file's
        # actuators are missing, out of order or on an unactuated joint
        if list(actuators) != list(efforts):
            for actuator in actuators.values():
                plant.RemoveJointActuator(actuator)
            actuators = {name: plant.AddJointActuator(f"{name}_actuator", plant.GetJointByName(name, instance), effort)
                         for name, effort in efforts.items()}
        for name, effort in efforts.items():
            actuators[name].set_effort_limit(effort)
        return instance

    def _remove_mimic_constraints(self, plant: MultibodyPlant) -> None:
        """Drake turns a URDF <mimic> into a coupler constraint, and a joint in a constraint cannot be
        welded. A mimic between locked joints (a gripper's fingers) is dropped (both are welded at their
        configured positions); a mimic that involves an arm joint is refused."""
        config = self.config
        for follower, leader in self.mimic_pairs:
            arm = [name for name in (follower, leader) if name in config.arm_joints]
            if arm:
                raise InputError(f"robot {self.name}: arm joint {arm[0]!r} is in a <mimic> pair ({follower} mimics "
                                 f"{leader}); arm joints must move independently (lock both, or leave the pair out)")
        locked_pairs = [pair for pair in self.mimic_pairs if set(pair) & set(config.locked_joints)]
        if not locked_pairs:
            return
        if len(locked_pairs) != len(self.mimic_pairs) or plant.num_constraints() != len(self.mimic_pairs) or any(
                name not in config.locked_joints for pair in locked_pairs for name in pair):
            raise InputError(f"robot {self.name}: locked joints {sorted(set(sum(locked_pairs, ())))} are in <mimic> "
                             "pairs with joints that are not locked; lock every joint of a mimic pair")
        for constraint in plant.GetConstraintIds():
            plant.RemoveConstraint(constraint)

    def check_plant(self, plant: MultibodyPlant, instance) -> None:
        """After Finalize: the arm joints are the plant's only degrees of freedom, in order, each with
        finite position and velocity limits and an actuator, home within the position limits;
        configured limits replace the file's."""
        config = self.config
        names = [plant.get_joint(index).name() for index in plant.GetJointIndices(instance)
                 if plant.get_joint(index).num_velocities() > 0]
        if plant.num_positions(instance) != self.num_joints or plant.num_velocities(instance) != self.num_joints:
            free = "a floating base (give weld_frame)" if any(plant.get_body(b).is_floating_base_body()
                                                              for b in plant.GetBodyIndices(instance)) else names
            raise InputError(f"robot {self.name}: the model moves {plant.num_velocities(instance)} degrees of "
                             f"freedom ({free}); list the others under locked_joints")
        check_nested_fixed(plant, instance, f"robot {self.name}: {self.model_path.name}")
        order = sorted(config.arm_joints, key=lambda name: plant.GetJointByName(name, instance).velocity_start())
        if order != list(config.arm_joints):
            raise InputError(f"robot {self.name}: list arm_joints in the model's order: {order}")
        for name in config.arm_joints:
            joint = plant.GetJointByName(name, instance)
            lower, upper = joint.position_lower_limits()[0], joint.position_upper_limits()[0]
            velocity = config.velocity_limits.get(name, joint.velocity_upper_limits()[0])
            if not (np.isfinite(lower) and np.isfinite(upper)) and name not in self.continuous_joints:
                raise InputError(f"robot {self.name}: arm joint {name!r} has no position limits in the model; give "
                                 f"position_limits[{name!r}] in the robot config")
            if not np.isfinite(velocity):
                raise InputError(f"robot {self.name}: arm joint {name!r} has no velocity limit; give velocity_limits")
            home = self.home[config.arm_joints.index(name)]
            if not lower <= home <= upper:
                raise InputError(f"robot {self.name}: home {home:g} of {name!r} is outside its position limits "
                                 f"[{lower:g}, {upper:g}]")
            if name in config.velocity_limits:
                joint.set_velocity_limits([-velocity], [velocity])
        check_arm_inertias(plant, instance, self.home, f"robot {self.name}")


def load_robot(path) -> Robot:
    """The Robot of a robot config YAML (the UR-10 preset: `UR10_CONFIG`, models/ur10.yaml); a URDF or SDF given in
    its place is an InputError naming `robot init`, which writes the config of one."""
    path = pathlib.Path(path)
    if path.suffix.lower() in (*SUFFIXES, ".xml", ".srdf"):
        raise InputError(f"{line_text(path)} is a robot description, not a robot config (a YAML naming it, its arm "
                         f"joints and home): write one with `stdm-drake robot init {line_text(path.name)}`")
    robot = Robot(load_yaml_config(path, RobotConfig, what="robot config"), path.parent)
    robot.config_path = path.resolve()
    return robot
