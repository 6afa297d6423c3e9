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

import copy
import dataclasses
import logging
import os
import pathlib
import re

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.robots import xml_file
from stdm_drake.robots.description import (MAX_ARM_JOINTS, MOVABLE, Description, check_tree, read_description,
                                           PLAIN_NUMBER)
from stdm_drake.robots.derived_limits import (derive_kinematic_limits,
                                              mount_joints)
from stdm_drake.robots.model_file import joint_facts
from stdm_drake.robots.robot import POSE_DIM, Robot, RobotConfig
from stdm_drake.robots.xml_file import check_xml
from stdm_drake.robots.kinematics import RobotKinematics
from stdm_drake.robots.plant import SelfCollisionChecker, joint_limits, Dynamics

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
        branches = [joint for joint in children.get(root, []) if (joint.kind in MOVABLE) + count(joint.child) > 0]
        if len(branches) > 1:   # (a world of two arms: each branch moves, none is the chain)
            raise InputError(f"the root link {root!r} branches into {len(branches)} moving chains ("
                             f"{', '.join(joint.name for joint in branches)}); robot init takes one arm: give a "
                             "description of one, or write its robot config (robots guide, \"The robot file\")")
        raise InputError(f"no movable joint on a chain from the root link {root!r} (its branches: "
                         f"{', '.join(joint.name for joint in children.get(root, [])) or 'none'})")
    tool = arm[-1].child
    while True:
        fixed = [joint for joint in children.get(tool, []) if joint.kind not in MOVABLE
                 and "::" not in joint.child]   # (not into a model nested in the arm: its frames are its own)
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


def relative_to(path: pathlib.Path, folder: pathlib.Path) -> str:
    """`path` relative to `folder` (with `..` where it lies outside: a YAML and its description move together;
    absolute only where no relative path exists, another drive)."""
    path, folder = path.resolve(), folder.resolve()
    try:
        return os.path.relpath(path, folder)
    except ValueError:
        return str(path)


# notes whose fix goes into the YAML: `robot init` writes it and exits 1 even though it does not pass yet
YAML_FIXES = ("no configuration near the middle of the ranges",)


def starting_config(model_path: pathlib.Path, folder: pathlib.Path, name: str | None = None,
                    srdf: pathlib.Path | None = None, packages_near: pathlib.Path | None = None,
                    packages: dict | None = None, keep: dict | None = None) -> tuple[RobotConfig, list]:
    """(the starting RobotConfig of description file `model_path`, with paths relative to `folder` where its
    YAML will be written, home the middle of the ranges; notes for the user, one line each). InputError for a
    file that is no arm. packages_near: the file beside which its packages are looked for (default: model_path;
    a copy written elsewhere names its original); packages: package name -> folder, given by the user; keep: the
    fields an existing YAML sets that `--update` keeps (`config_update.kept_fields`), in place of the rules'."""
    xml_file.check_xml(model_path, "a URDF or SDF file is", count_frames=True)   # (its size first: then its packages)
    packages, missing, located = find_packages(packages_near or model_path, given=packages)
    description = read_description(model_path, packages=packages)   # (an SDF's package:// includes: these folders)
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
        model=relative_to(model_path, folder),
        package_paths={package: relative_to(path, folder) for package, path in packages.items()},
        weld_frame=chain.base, arm_joints=chain.arm_joints,
        locked_joints={joint: nearest_zero(joints[joint]) for joint in chain.locked_joints},
        home=[round(middle(joints[joint]), 6) for joint in chain.arm_joints], tool_frame=chain.tool_frame,
        srdf=relative_to(srdf, folder) if srdf is not None else "")
    for field, value in (keep or {}).items():
        setattr(config, field, copy.deepcopy(value))
    unknown = sorted(set(config.arm_joints) - set(joints))
    if unknown:
        raise InputError(f"the robot config names arm joints the description does not have: {', '.join(unknown)}")
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
    checker = SelfCollisionChecker(robot)
    limits = joint_limits(checker.plant)
    dynamics = Dynamics(robot)
    check_holds_home(robot, dynamics, limits)
    gravity = np.abs(dynamics.gravity_torque(robot.home))
    inertia = dynamics.effective_inertia(robot.home)
    lines = []
    for j, joint in enumerate(robot.joint_names):   # (units of a revolute joint, or of a prismatic one)
        turns = checker.plant.GetJointByName(joint).type_name() != "prismatic"
        q, v, f, m = ("rad", "rad/s", "N m", "kg m²") if turns else ("m", "m/s", "N", "kg")
        lines.append(f"{joint}: range [{limits.position_lower[j]:.4g}, {limits.position_upper[j]:.4g}] {q}, velocity "
                     f"{limits.velocity[j]:.4g} {v}, home {robot.home[j]:.4g} {q}, gravity at home {gravity[j]:.3g} {f}, "
                     f"effective inertia {inertia[j]:.3g} {m}")
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
