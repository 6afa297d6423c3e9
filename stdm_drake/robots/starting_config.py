"""A starting robot config for a description file nobody has written one for (`stdm-drake robot init`), and
the checks of a robot config before any work (`stdm-drake robot check`).

The rules, applied to the file's kinematic tree (`robots.description`):

- base: the tree's root link, welded to the world (none when the file fixes it itself: a URDF link
  "world", an SDF joint to "world");
- arm joints: the movable joints on the one chain from the root, up to the first link below which
  two or more branches move (a gripper's fingers) or the first joint of a <mimic> pair; every other
  movable joint is locked at the point of its range nearest 0;
- tool frame: the last arm link, followed down its fixed joints while there is one way on (of several,
  the one that carries the moving joints of a gripper, when one does);
- packages: each package:// name found as a folder (or a folder whose package.xml names it) at or
  beside the model's folder or one of the folders above it, else as the folder at or above the model's that
  holds every file its URIs name (a package shipped under another folder name); `--package` maps the rest;
- home: an SRDF group state named in HOME_STATE_NAMES when an SRDF is given; else, around the middle of
  each joint's position range (0 for a continuous joint), a configuration free of self-collision and,
  for an arm that tracks task-space plans, far from singularities (`starting_home`); link pairs in
  contact in every configuration tried touch by design and go to disabled_collisions.

- a tool or gripper mount: movable joints at the end of the chain after POSE_DIM or more joints that state effort
  limits, the file stating none for them, are locked, not arm joints (`mount_joints`);
- limits the file lacks for an arm joint (no effort or velocity limit, or zero; a revolute joint's position range
  [0, 0], URDF's default where <limit> gives none) are derived and written to the YAML marked as derived, to be
  replaced by the maker's ratings (`derived_limits.DERIVED_LIMITS`): velocity pi/2 rad/s (0.5 m/s prismatic);
  position range [-pi, pi]; effort twice the largest of |gravity torque| + 5 rad/s² x the joint's diagonal inertia M_jj over
  the home and 200 configurations drawn in the ranges, and at least a tenth of the largest joint's (a wrist
  carries a payload the description does not hold).
"""
from __future__ import annotations

import dataclasses
import logging
import os
import pathlib
import re
from typing import TYPE_CHECKING

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.files import line_text
from stdm_drake.robots import xml_file
from stdm_drake.robots.description import MOVABLE, SUFFIXES, Description, check_tree, read_description
from stdm_drake.robots.derived_limits import (PROVISIONAL_EFFORT, derive_effort_limits, derive_kinematic_limits,
                                              mount_joints)
from stdm_drake.robots.model_file import joint_facts
from stdm_drake.robots.robot import POSE_DIM, Robot, RobotConfig

if TYPE_CHECKING:
    from stdm_drake.robots.geometry_masses import MassesFromGeometry

HOME_STATE_NAMES = ("home", "ready", "zero", "default")
WORLD = "world"
logger = logging.getLogger(__name__)


@dataclasses.dataclass
class ArmChain:
    """What a description's kinematic tree gives a robot config: the base link (None: the file welds
    itself to the world), the arm joints from the base out, the other movable joints (locked) and the
    tool frame."""
    base: str | None
    arm_joints: list
    locked_joints: list
    tool_frame: str


def arm_chain(description: Description, mimics: list) -> ArmChain:
    """The arm of a description's tree (the rules in the module's docstring); InputError when it has no
    movable joint on a chain from its root."""
    description = Description(description.links, [joint for joint in description.joints
                                                  if joint.parent and joint.child and joint.parent != joint.child])
    children = description.children()
    child_links = {joint.child for joint in description.joints}
    roots = [link for link in description.links if link not in child_links]
    if WORLD in {joint.parent for joint in description.joints}:
        roots = [WORLD]
    movable_below = {}      # movable joints in the subtree of each link: children before parents, no recursion
    for start in roots:     # (a chain of hundreds of fixed frames is as deep as a description gets)
        for link in reversed(description.subtree(start)):
            movable_below[link] = sum((joint.kind in MOVABLE) + movable_below.get(joint.child, 0)
                                      for joint in children.get(link, []))

    def count(link: str) -> int:
        return movable_below.get(link, 0)

    if not roots:
        raise InputError("the file has no root link (every link is some joint's child)")
    root = max(roots, key=count)
    in_mimic = {name for pair in mimics for name in pair}
    arm, link = [], root
    while True:
        ways = [joint for joint in children.get(link, []) if (joint.kind in MOVABLE) + count(joint.child) > 0]
        if len(ways) != 1 or ways[0].name in in_mimic:
            break
        if ways[0].kind in MOVABLE:
            arm.append(ways[0])
        link = ways[0].child
    if not arm:
        raise InputError(f"no movable joint on a chain from the root link {root!r} (its branches: "
                         f"{', '.join(joint.name for joint in children.get(root, [])) or 'none'})")
    tool = arm[-1].child
    while True:
        fixed = [joint for joint in children.get(tool, []) if joint.kind not in MOVABLE]
        if len(fixed) > 1:   # (several frames: the one that carries the gripper, when one does)
            fixed = [joint for joint in fixed if count(joint.child) > 0]
        if len(fixed) != 1:
            break
        tool = fixed[0].child
    arm_names = [joint.name for joint in arm]
    locked = [joint.name for joint in description.joints if joint.kind in MOVABLE and joint.name not in arm_names]
    return ArmChain(None if root == WORLD else root, arm_names, locked, tool)


def find_packages(model_path: pathlib.Path, levels: int = 6, given: dict | None = None) -> tuple[dict, list, list]:
    """({package: folder} for the package:// names the file uses that are found by the rule in the module's
    docstring, or `given` (name -> folder: `robot init --package`, taken as given), [names not found], [names
    found by where their files are: a folder at or above the model's that holds every file the URIs name])."""
    uris = re.findall(r"package://([^/\"'<>\s]+)/([^\"'<>\s]+)", model_path.read_text(errors="replace"))
    names = sorted({name for name, _ in uris})
    found = dict(given or {})
    folders = [model_path.parent.resolve(), *list(model_path.parent.resolve().parents)[:levels]]
    for name in (name for name in names if name not in found):
        for folder in folders:
            candidates = [folder] if folder.name == name else []
            candidates += [folder / name] if (folder / name).is_dir() else []
            candidates += [manifest.parent for manifest in sorted(folder.glob("*/package.xml"))
                           if f"<name>{name}</name>" in manifest.read_text(errors="replace")]
            if candidates:
                found[name] = candidates[0]
                break
    located = []
    for name in (name for name in names if name not in found):   # (a package shipped under another folder name)
        files = {path for package, path in uris if package == name}
        folder = next((folder for folder in folders if all((folder / path).is_file() for path in files)), None)
        if folder is not None:
            found[name] = folder
            located.append(name)
    return found, [name for name in names if name not in found], located


def given_packages(items: list) -> dict:
    """{package: folder} of `robot init --package NAME=FOLDER` items; InputError for one of another form or whose
    folder is none."""
    packages = {}
    for item in items:
        package, _, folder = item.partition("=")
        if not package or not folder or "/" in package:
            raise InputError(f"--package {item!r}: give NAME=FOLDER (the package's name, then its folder)")
        if not pathlib.Path(folder).is_dir():
            raise InputError(f"--package {item!r}: {folder} is not a folder")
        packages[package] = pathlib.Path(folder).resolve()
    return packages


def srdf_home(srdf: pathlib.Path, arm_joints: list) -> list | None:
    """The first SRDF <group_state> named in HOME_STATE_NAMES that gives every arm joint, as positions, or None.
    InputError for a file that is no XML as MoveIt reads it (entities: `xml_file.check_xml`) and for a home
    value that is no number (it would be skipped silently)."""
    from stdm_drake.robots.description import PLAIN_NUMBER
    from stdm_drake.robots.xml_file import check_xml
    check_xml(srdf, "an SRDF file is")
    root = xml_file.parse(srdf).getroot()
    states = {state.get("name"): {joint.get("name"): joint.get("value") for joint in state.iter("joint")}
              for state in root.iter("group_state")}
    for name in HOME_STATE_NAMES:
        values = states.get(name, {})
        if not all(joint in values for joint in arm_joints):
            continue   # (a state of other joints)
        for joint in arm_joints:
            if values[joint] is None or not PLAIN_NUMBER.fullmatch(values[joint]):
                raise InputError(f"srdf {srdf.name}: group state {name!r} gives joint {joint!r} the value "
                                 f"{values[joint]!r}, which is no number (decimal digits, an optional exponent)")
        return [float(values[joint]) for joint in arm_joints]
    return None


def _relative(path: pathlib.Path, folder: pathlib.Path) -> str:
    """`path` relative to `folder` (with `..` where it lies outside: a YAML and its description move together;
    absolute only where no relative path exists, another drive)."""
    path, folder = path.resolve(), folder.resolve()
    try:
        return os.path.relpath(path, folder)
    except ValueError:
        return str(path)


# notes whose fix goes into the YAML: `robot init` writes it and exits 1 even though it does not pass yet
YAML_FIXES = ("no configuration near the middle of the ranges",)
MAX_ARM_JOINTS = 100   # movable joints of one arm's chain: `robot init`'s home search took 47 s for 3000


def starting_config(model_path: pathlib.Path, folder: pathlib.Path, name: str | None = None,
                    srdf: pathlib.Path | None = None, packages_near: pathlib.Path | None = None,
                    packages: dict | None = None) -> tuple[RobotConfig, list]:
    """(the starting RobotConfig of description file `model_path`, with paths relative to `folder` where its
    YAML will be written, home the middle of the ranges; notes for the user, one line each). InputError for a
    file that is no arm. packages_near: the file beside which its packages are looked for (default: model_path;
    a copy written elsewhere names its original); packages: package name -> folder, given by the user."""
    description = read_description(model_path)
    check_tree(description, f"{model_path.name}")   # (a loop: no chain to follow)
    _, continuous, mimics = joint_facts(model_path)
    chain = arm_chain(description, mimics)
    if len(chain.arm_joints) > MAX_ARM_JOINTS:   # (before the home search, whose work grows with the joints)
        raise InputError(f"{model_path.name}: its chain from the root has {len(chain.arm_joints)} movable joints; an "
                         f"arm here has at most {MAX_ARM_JOINTS} (a humanoid's limbs are several arms: describe one)")
    if description.models > 1:   # (a world of several arms: each is a robot of its own)
        raise InputError(f"{model_path.name} holds {description.models} models; a robot config describes one arm: "
                         "give a file of that arm's model")
    joints = {joint.name: joint for joint in description.joints}
    packages, missing, located = find_packages(packages_near or model_path, given=packages)
    notes = [f"package {package!r} not found near {(packages_near or model_path).name}: map it under package_paths"
             for package in missing]
    notes += [f"package {package!r}: no folder of that name; mapped to {packages[package].name}/, which holds every "
              "file its URIs name" for package in located]
    mounts = mount_joints(chain.arm_joints, joints)
    if mounts:
        chain = dataclasses.replace(chain, arm_joints=chain.arm_joints[:-len(mounts)],
                                    locked_joints=chain.locked_joints + mounts)
        notes.append(f"{', '.join(mounts)} locked: a tool or gripper mount (movable joints after {POSE_DIM} or more "
                     "arm joints with effort limits, the file giving them none), not arm joints")

    def middle(joint) -> float:
        if joint.name in continuous or joint.lower is None or joint.upper is None:
            return 0.0
        return 0.5 * (joint.lower + joint.upper)

    def nearest_zero(joint) -> float:
        lower = -np.inf if joint.lower is None else joint.lower
        upper = np.inf if joint.upper is None else joint.upper
        return float(np.clip(0.0, lower, upper)) if lower <= upper else 0.0

    config = RobotConfig(
        name=name or re.sub(r"[^A-Za-z0-9_.-]+", "_", description.name or model_path.stem),
        model=_relative(model_path, folder),
        package_paths={package: _relative(path, folder) for package, path in packages.items()},
        weld_frame=chain.base, arm_joints=chain.arm_joints,
        locked_joints={joint: nearest_zero(joints[joint]) for joint in chain.locked_joints},
        home=[round(middle(joints[joint]), 6) for joint in chain.arm_joints], tool_frame=chain.tool_frame,
        srdf=_relative(srdf, folder) if srdf is not None else "")
    notes += derive_kinematic_limits(config, joints)
    if len(chain.arm_joints) < POSE_DIM:
        notes.append(f"{len(chain.arm_joints)} arm joints: the excitation protocol only (task-space tracking needs "
                     f"{POSE_DIM})")
    return config, notes


def starting_home(robot: Robot, attempts: int = 200) -> tuple[list | None, list]:
    """(a home for `robot`, the link pairs in contact in every configuration tried). The configurations: its
    config's home and `attempts` drawn around it (uniform within +-0.25 of each joint's range, 1 rad for a
    continuous joint; numpy.random.default_rng(0)), rounded to 1e-3. Pairs that touch in all of them touch
    by design (overlapping geometry of neighbouring links, as MoveIt's setup assistant finds them) and are
    returned to be disabled; of the configurations free of every other contact, for an arm of POSE_DIM or
    more joints the one whose task Jacobian is best conditioned (task-space plans start there: the middle
    of the ranges is often a stretched, singular arm), else the config's home when free, else the first
    free one. Home None when none is free."""
    from stdm_drake.robots.kinematics import RobotKinematics
    from stdm_drake.robots.plant import SelfCollisionChecker, joint_limits
    checker = SelfCollisionChecker(robot, check_home=False)
    limits = joint_limits(checker.plant)
    lower, upper = limits.position_lower, limits.position_upper
    spread = np.where(np.isfinite(upper - lower), 0.25 * (upper - lower), 1.0)
    rng = np.random.default_rng(0)
    tried = [robot.home] + [np.round(np.clip(robot.home + rng.uniform(-spread, spread), lower, upper), 3)
                            for _ in range(attempts)]
    contacts = [{tuple(sorted(pair)) for pair in checker.colliding_links(q)} for q in tried]
    always = set.intersection(*contacts)
    touching = [list(pair) for pair in sorted(always)]
    free = [q for q, pairs in zip(tried, contacts) if pairs <= always]
    if not free:
        return None, touching
    if robot.num_joints < POSE_DIM:
        return list(map(float, free[0])), touching
    kinematics = RobotKinematics(checker.plant, robot=robot)
    return list(map(float, min(free, key=lambda q: np.linalg.cond(kinematics.task_jacobian(q))))), touching


def check_robot(robot: Robot) -> list[str]:
    """What stands between `robot` and data, beyond what loading it checks (the description's checks,
    limits, M(home) positive definite): home free of self-collision, gravity at home within each actuated
    joint's effort limit. Raises InputError for the first problem; returns one line of facts per joint."""
    from stdm_drake.robots.plant import Dynamics, SelfCollisionChecker, joint_limits
    checker = SelfCollisionChecker(robot)
    limits = joint_limits(checker.plant)
    dynamics = Dynamics(robot)
    check_holds_home(robot, dynamics, limits)
    gravity = np.abs(dynamics.gravity_torque(robot.home))
    inertia = dynamics.effective_inertia(robot.home)
    lines = []
    for j, joint in enumerate(robot.joint_names):
        lines.append(f"{joint}: range [{limits.position_lower[j]:.4g}, {limits.position_upper[j]:.4g}], velocity "
                     f"{limits.velocity[j]:.4g}, home {robot.home[j]:.4g}, gravity at home {gravity[j]:.3g}, "
                     f"effective inertia {inertia[j]:.3g}")
    return lines


def check_holds_home(robot: Robot, dynamics, limits) -> None:
    """InputError naming the joint when holding `robot`'s home against gravity takes at least an actuated
    joint's whole effort limit (its config key: effort_limits)."""
    gravity = np.abs(dynamics.actuated_gravity_torque(robot.home))
    for name, needed, effort in zip(robot.actuated_joint_names, gravity, limits.effort):
        if needed >= effort:
            raise InputError(f"robot {robot.name}: holding home against gravity takes {needed:.4g} N m on {name!r}, "
                             f"at or above its effort limit {effort:.4g}; give a larger effort_limits[{name!r}] in the "
                             "robot config, or a home where gravity pulls less")


def config_yaml(config: RobotConfig, source: str, notes: list) -> str:
    """The robot config YAML text of `config`, with a header naming the description `source` and the `notes`."""
    import yaml
    lines = [f"# Robot config written by `stdm-drake robot init` from {line_text(source)} (fields: RobotConfig in",
             "# stdm_drake/robots/robot.py; how each was chosen: docs/guides/robots.md, 'A robot from a description').",
             *[f"# NOTE: {line_text(note)}" for note in notes]]
    for field in ("name", "model", "package_paths", "weld_frame", "arm_joints", "locked_joints", "home",
                  "tool_frame", "srdf", "disabled_collisions", "position_limits", "velocity_limits", "effort_limits"):
        value = getattr(config, field)
        if value in ("", {}, [], None) and field != "weld_frame":
            continue
        text = yaml.safe_dump(value, default_flow_style=True, width=10_000, sort_keys=False).strip()
        lines.append(f"{field}: {text.removesuffix('...').strip()}")
    return "\n".join(lines) + "\n"


def write_starting_config(model: pathlib.Path, output: pathlib.Path, name: str | None = None,
                          srdf: pathlib.Path | None = None, force: bool = False,
                          masses: MassesFromGeometry | None = None,
                          packages: dict | None = None) -> tuple[RobotConfig, list, str]:
    """`robot init`: write the starting config of description `model` to `output` (never over an input, nor
    over an existing file unless `force`), with a home from `starting_home` unless the SRDF names one;
    returns (the config, notes, "" when it passes `check_robot`, else the one-line reason). masses: the links
    without <inertial> get masses from their geometry (`geometry_masses`), in a copy of the description
    beside `output` that the config names. packages: package name -> folder for package:// URIs the rule
    of the module's docstring does not find."""
    from stdm_drake.paths import check_input_file
    model = check_input_file(model, "model file")
    srdf = check_input_file(srdf, "srdf file") if srdf is not None else None
    if model.suffix.lower() == ".xacro":
        expanded = model.with_suffix("") if model.with_suffix("").suffix else model.with_suffix(".urdf")
        raise InputError(f"{model} is a xacro template: expand it first (`xacro {model} > {expanded}`; xacro: pip "
                         f"install xacro, or your ROS distribution's), then `stdm-drake robot init {expanded}`")
    if model.suffix.lower() not in SUFFIXES:
        raise InputError(f"model file {model}: a robot description is a .urdf or .sdf file (Drake's parsers)")
    if output.resolve() in {model.resolve(), *([srdf.resolve()] if srdf else [])}:
        raise InputError(f"--output {output} is an input file; choose another path")
    if output.exists() and not force:
        raise InputError(f"--output {output} exists; choose another path or pass --force to replace it")
    folder = output.absolute().parent
    if masses is None:
        return _write_starting_config(model, output, folder, name, srdf, model, [], packages)
    from stdm_drake.robots.geometry_masses import geometry_masses, write_with_masses
    masses.validate()
    final = masses.copy_path(model, folder)
    if final.resolve() in {model.resolve(), output.resolve(), *([srdf.resolve()] if srdf else [])}:
        raise InputError(f"the description with masses would be written over an input or the output ({final}); "
                         "write the YAML into another folder")
    if final.exists() and not force:
        raise InputError(f"{final} exists (the description with masses); choose another folder or pass --force")
    found = geometry_masses(model, find_packages(model, given=packages)[0], masses.density, masses.total_mass)
    copy = final.with_name(f"{final.name}.{os.getpid()}.urdf")   # (beside it: the relative mesh paths hold)
    try:
        write_with_masses(model, copy, found)
        return _write_starting_config(copy, output, folder, name, srdf, model, [masses.note(found, final)], packages,
                                      final)
    finally:
        copy.unlink(missing_ok=True)


def _write_starting_config(model, output, folder, name, srdf, original, notes, packages, final=None):
    """write_starting_config's work on description `model` (a copy with masses, to be renamed `final`, or the
    `original` itself)."""
    from stdm_drake.files import write_text_atomic
    from stdm_drake.robots.robot import load_robot
    config, more = starting_config(model, folder, name, srdf, packages_near=original, packages=packages)
    notes = notes + more
    try:   # (before the home search: holding a home against gravity is checked against these)
        notes += derive_effort_limits(Robot(config, folder), config)
    except InputError:   # (a config that does not load yet: the check below gives the reason; no stand-in kept)
        config.effort_limits = {joint: value for joint, value in config.effort_limits.items()
                                if value != PROVISIONAL_EFFORT}
    named = srdf_home(srdf, config.arm_joints) if srdf is not None else None
    if named is not None:   # (a named pose is kept as it is)
        config.home = named
    else:
        try:
            home, touching = starting_home(Robot(config, folder))
            config.disabled_collisions = touching
            if home is None:
                notes.append("no configuration near the middle of the ranges is free of self-collision: choose home")
            else:
                config.home = home
            if touching:
                notes.append(f"{len(touching)} link pairs touch in every configuration tried (by design): disabled")
        except InputError as error:   # (the check below gives the same reason as the command's error)
            notes.append(f"home not chosen: the config does not load yet ({error})")
    try:   # (checked before anything is written)
        check_robot(Robot(config, folder))
        problem = ""
    except InputError as error:
        problem = str(error)
    # a YAML that does not pass is written only where the fix goes into it (limits the file lacks, a home);
    # a description the checks refuse is one line, nothing written
    if problem and not any(note.startswith(YAML_FIXES) for note in notes):
        raise InputError(problem)
    if final is not None:
        os.replace(model, final)
        config.model = _relative(final, folder)
    write_text_atomic(output, config_yaml(config, original.name, notes))
    if not problem:
        check_robot(load_robot(output))   # (the file as written loads as the config did)
    return config, notes, problem
