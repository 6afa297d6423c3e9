"""The links and joints a robot description file (URDF or SDF) states, read from its XML, and the checks of
them that Drake's parser leaves out (a negative or zero mass, an inertia no body has: a warning at most)
or makes late (a kinematic loop: when the plant is finalized; reversed limits: an assertion that ends
the process). Each is an InputError naming the link or joint. Used by `stdm_drake.robots.robot`."""
from __future__ import annotations

import dataclasses
import math
import pathlib
import re
import sys

import numpy as np

from stdm_drake.errors import InputError, bound_text
from stdm_drake.robots import sdf_includes, xml_file
from stdm_drake.robots.limit_checks import MAX_GYRATION_RADIUS, check_limits
from stdm_drake.robots.xml_file import ASCII_SPACE, UnreadNumber, WrongCount, check_xml

MOVABLE = ("revolute", "continuous", "prismatic")
SUFFIXES = (".urdf", ".sdf")    # the descriptions Drake's parsers read, and these checks with them
# movable joints of one arm: `robot init`'s home search took 47 s for 3000, and Drake's contact solver does not converge
# on a 101-joint chain's plant
MAX_ARM_JOINTS = 100


@dataclasses.dataclass
class Inertial:
    """A link's <inertial>: mass (kg) and its rotational inertia (3, 3) kg m² about the centre of mass;
    mass None: a value in it is not a number (Drake's parser names it; nothing is checked here)."""
    mass: float | None
    inertia: np.ndarray


@dataclasses.dataclass
class Joint:
    """A joint: its type (URDF's words; SDF's "revolute" and "prismatic" are the same), parent and child
    link, and the limits the file states (lower, upper: rad or m; velocity: rad/s or m/s; effort: N m or N;
    absent: None)."""
    name: str
    kind: str
    parent: str
    child: str
    lower: float | None = None
    upper: float | None = None
    velocity: float | None = None
    effort: float | None = None


@dataclasses.dataclass
class Description:
    """links: link name -> its Inertial (None: the file gives none, a massless frame); joints in file order;
    models: the file's top-level models (an SDF world may hold several; a URDF is one); name: the robot's or
    model's name the file gives ("" where it gives none, or holds several)."""
    links: dict
    joints: list
    models: int = 1
    name: str = ""
    included: dict = dataclasses.field(default_factory=dict)   # the included files' links: "file: link" -> Inertial
    nested: list = dataclasses.field(default_factory=list)     # a lone top model's nested models (inline, included)

    def children(self) -> dict:
        """Link name -> the joints whose parent it is."""
        table = {}
        for joint in self.joints:
            table.setdefault(joint.parent, []).append(joint)
        return table

    def subtree(self, link: str) -> list[str]:
        """`link` and every link below it (through any joint), in depth-first order (the tree is checked)."""
        children, order, stack = self.children(), [], [link]
        while stack:
            name = stack.pop()
            order.append(name)
            stack += [joint.child for joint in reversed(children.get(name, []))]
        return order


def file_number(text) -> float | None:
    """A number of the file (None for text that is none: Drake's parser names that itself)."""
    try:
        return float(text)
    except (TypeError, ValueError):
        return None


INERTIA_KEYS = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
# A number as URDF and SDF files write one: decimal digits, an optional exponent (inf and nan too). Anything else
# (a hexadecimal float, "7.1junk", "1_000") these checks cannot read as Drake's parser does, which reads some of
# it otherwise (a prefix, a hexadecimal value), so `read_description` refuses the file.
PLAIN_NUMBER = re.compile(r"\s*[-+]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|inf|infinity|nan)\s*",
                          re.IGNORECASE | re.ASCII)   # (ASCII digits: Python reads "３" and "٢" as numbers, Drake does not)


def checked_number(text: str | None, what: str) -> float | None:
    """The number `text` writes (None for an absent text); UnreadNumber naming `what` for one PLAIN_NUMBER is not."""
    if text is None:
        return None
    if not PLAIN_NUMBER.fullmatch(text):
        raise UnreadNumber(f"{what} is {text.strip(ASCII_SPACE)!r}")
    return float(text)


def _inertial(mass: str | None, values: dict, defaults: dict, link: str) -> Inertial:
    """The Inertial of the file's texts of a mass and of the inertia entries (`values`: INERTIA_KEYS -> text);
    an absent text (None) takes its value from `defaults` ("mass" and INERTIA_KEYS); a text that is not a
    number: UnreadNumber."""
    numbers = {key: defaults[key] if text is None else checked_number(text, f"link {link!r}: its {key}")
               for key, text in dict(values, mass=mass).items()}
    get = numbers.get
    return Inertial(get("mass"), np.array([[get("ixx"), get("ixy"), get("ixz")], [get("ixy"), get("iyy"), get("iyz")],
                                           [get("ixz"), get("iyz"), get("izz")]], dtype=float))


def _urdf(root) -> Description:
    """URDF: a link without <inertial> is a massless frame; absent values in one are 0."""
    links = {}
    for link in root.findall("link"):
        inertial = link.find("inertial")
        if inertial is None:
            links[link.get("name")] = None
            continue
        mass, inertia = inertial.find("mass"), inertial.find("inertia")
        values = {key: inertia.get(key) if inertia is not None else None for key in INERTIA_KEYS}
        links[link.get("name")] = _inertial(mass.get("value") if mass is not None else None, values,
                                            dict.fromkeys(("mass",) + INERTIA_KEYS, 0.0), link.get("name"))
    joints = []
    for joint in root.findall("joint"):
        parent, child, limit = joint.find("parent"), joint.find("child"), joint.find("limit")
        values = {key: checked_number(limit.get(key), f"joint {joint.get('name')!r}: its {key} limit")
                  for key in ("lower", "upper", "velocity", "effort")} if limit is not None else {}
        if joint.get("type") == "continuous":   # (URDF: its lower and upper are ignored)
            values.pop("lower", None), values.pop("upper", None)
        joints.append(Joint(joint.get("name"), joint.get("type"), parent.get("link") if parent is not None else None,
                            child.get("link") if child is not None else None, **values))
    return Description(links, joints, name=root.get("name") or "")


def _sdf(root, included_models: int = 0) -> Description:
    """SDFormat's defaults: a link without <inertial> has mass 1 kg and unit inertia; a velocity or effort
    limit below 0 means none. Names are scoped as SDFormat scopes them: a nested model's links and joints are
    "inner::name", and where the file holds several models (a world of two arms) every name is "model::name",
    so two models that both have a link "base" are two links, not one link with two parents; a joint placed in
    the world itself names its links scoped ("arm::tool"). `included_models`: the models the file's worlds
    <include> (`read_description` reads them), counted among the top-level ones."""
    links, joints = {}, []
    defaults = dict(mass=1.0, ixx=1.0, iyy=1.0, izz=1.0, ixy=0.0, ixz=0.0, iyz=0.0)

    def models(element):   # (the models at the top, inside <sdf> or its <world>s)
        for child in element:
            if child.tag == "model":
                yield child
            elif child.tag == "world":
                yield from (model for model in child if model.tag == "model")

    def read_joints(element, prefix: str) -> None:
        for joint in element.findall("joint"):
            values = {key: checked_number(joint.findtext(f"axis/limit/{key}"), f"joint {joint.get('name')!r}: its {key} limit")
                      for key in ("lower", "upper", "velocity", "effort")}
            for key in ("velocity", "effort"):   # (SDFormat: a limit below 0 is not enforced, -1 its default)
                if values[key] is not None and values[key] < 0:
                    values[key] = None
            parent, child = ((joint.findtext(end) or "").strip() for end in ("parent", "child"))
            joints.append(Joint(prefix + (joint.get("name") or ""), joint.get("type"),
                                parent if parent in ("world", "") else prefix + parent, child and prefix + child,
                                **values))

    def read_model(model, prefix: str) -> None:
        for link in model.findall("link"):
            inertial = link.find("inertial")
            read = inertial.findtext if inertial is not None else (lambda key: None)  # noqa: E731
            links[prefix + link.get("name", "")] = _inertial(
                read("mass"), {key: read(f"inertia/{key}") for key in INERTIA_KEYS}, defaults, prefix + link.get("name", ""))
        read_joints(model, prefix)

    top = list(models(root))
    several = len(top) + included_models > 1
    pending = [(model, f"{model.get('name', '')}::" if several else "") for model in reversed(top)]
    while pending:   # (depth first, without recursion: a file may nest thousands of models)
        model, prefix = pending.pop()
        read_model(model, prefix)
        pending += [(nested, f"{prefix}{nested.get('name', '')}::") for nested in reversed(model.findall("model"))]
    for world in root.iter("world"):
        read_joints(world, "")
    return Description(links, joints, max(1, len(top) + included_models),
                       top[0].get("name") or "" if len(top) == 1 and not included_models else "")


def read_description(path: pathlib.Path, including: tuple = (), packages: dict | None = None) -> Description:
    """The links and joints of a URDF or SDF file. InputError (one line) for a file these checks cannot read as
    Drake's parser would: XML that is not well-formed (an undefined entity included) and entity declarations
    (a DTD's `<!ENTITY>`: Python's parser expands them, Drake's does not, so the two would see different files;
    a "billion laughs" file among them). So no check is skipped for a file Drake then parses, nor for the local files
    an SDF includes (`sdf_includes.included_files`; their links' masses checked, not returned: Drake scopes them), and an
    SDF that includes itself, directly or through others (`including`: the files whose includes led here), is refused
    (Drake's parser would recurse until the process crashes)."""
    check_xml(path, "a URDF or SDF file is", count_frames=True)
    root = xml_file.parse(path).getroot()
    # a xacro template's macros and substitutions, which Drake's parser skips or reads as written (the links a macro
    # makes would be missing); an unused <xacro:property> or <xacro:arg> changes nothing and loads
    template = next((f"<{element.tag}>" for element in root.iter() if element.tag.startswith("xacro:")
                     and element.tag not in ("xacro:property", "xacro:arg")), None) or next(
        (f"{value!r}" for element in root.iter() for value in element.attrib.values() if "${" in value or "$(" in value),
        None)
    if template is not None:
        raise InputError(f"{path.name} is a xacro template (its {template}): expand it first (`xacro {path.name} > "
                         "robot.urdf`; xacro: pip install xacro, or your ROS distribution's)")
    # a world's <include>s are its models (a model's own are nested in it: Drake scopes them)
    world_includes = [include for world in root.iter("world") for include in world.findall("include")]
    try:
        description = _sdf(root, len(world_includes)) if root.tag == "sdf" else _urdf(root)
        xml_file.check_numbers(root, PLAIN_NUMBER)
    except UnreadNumber as error:
        raise InputError(f"{path.name}: {error}, not a number as URDF and SDF write one (decimal digits, an optional "
                         "exponent); these checks cannot read it, and Drake's parser would read it otherwise") from None
    except WrongCount as error:
        raise InputError(f"{path.name}: {error}") from None
    if root.tag == "sdf" and len(including) < sdf_includes.MAX_INCLUDE_DEPTH:
        chain = (*including, pathlib.Path(path).resolve())

        def read_included(included: pathlib.Path) -> Description:
            if included.resolve() in chain:
                start = chain.index(included.resolve())
                names = " -> ".join(item.name for item in (*chain[start:], included))
                who = "" if start == 0 else f" its included {included.name}"
                raise InputError(f"{chain[0].name}:{who} includes itself ({names}); Drake's parser would not end")
            return read_description(included, chain, packages)

        def target(include, where: str) -> pathlib.Path:
            found = sdf_includes.include_target(include, path, packages)
            if found is None:
                raise InputError(f"{path.name}: {where} includes {(include.findtext('uri') or '').strip()!r}, a file "
                                 "these checks cannot find (give a path, file://, or package:// or model:// of the "
                                 "robot config's package_paths)")
            return found

        several = description.models > 1
        for include in world_includes:
            included = target(include, "its world")
            model = read_included(included)   # (its XML checked before anything here reads it)
            _check_transmissions_in_world(included, path.name)
            name = (include.findtext("name") or "").strip() or model.name
            _check_own_links(model, included.name)
            description.name = "" if several else name
            _add_model(description, model, f"{name}::" if several else "")
        # a top-level model's <include merge="true">: the included links and joints are that model's own
        tops = [*root.findall("model"), *(model for world in root.iter("world") for model in world.findall("model"))]
        merged = [(model, include) for model in tops for include in model.findall("include") if _merged(include)]
        for model, include in merged:
            prefix = f"{model.get('name', '')}::" if several else ""
            _add_model(description, read_included(target(include, f"its model {model.get('name')!r}")), prefix)
        done = [*world_includes, *(include for _, include in merged)]
        model_includes = [include for include in root.iter("include") if all(include is not d for d in done)]
        if len(tops) == 1 and not several:
            description.nested = sorted({model.get("name", "") for model in tops[0].findall("model")} | {
                (include.findtext("name") or "").strip() or pathlib.Path((include.findtext("uri") or "").strip()).stem
                for include in tops[0].findall("include") if not _merged(include)})
        if not including:
            _check_own_links(description, path.name)
        for included in sdf_includes.included_files(root, path, packages, model_includes):
            inner = read_included(included)
            for link, inertial in [*inner.links.items(), *inner.included.items()]:
                name = f"{included.name}: {link}" if link in inner.links else link
                if inertial is not None:
                    check_inertial(inertial, f"{path.name}: its included {included.name}: link {link!r}")
                    description.included[name] = inertial
    return description


def _check_transmissions_in_world(included: pathlib.Path, world: str) -> None:
    """InputError where a URDF a world includes has a <transmission> on a joint of effort limit 0: Drake's parser
    skips that transmission with a warning, then fails on the world with "Failed to load a world", naming neither
    (measured; the URDF alone loads)."""
    root = xml_file.parse(included).getroot()
    if root.tag != "robot":
        return
    efforts = {joint.get("name"): (joint.find("limit").get("effort") if joint.find("limit") is not None else None)
               for joint in root.findall("joint")}   # (not a transmission's <joint>, which names one)
    for transmission in root.findall("transmission"):   # (Drake reads the robot's own, not nested ones)
        for joint in transmission.findall("joint"):
            effort = file_number(efforts.get(joint.get("name")))
            if effort == 0:
                raise InputError(f"{world}: its included {included.name}: joint {joint.get('name')!r} has a "
                                 "<transmission> and effort limit 0, which Drake's parser cannot load inside a world "
                                 "(it skips the transmission, then fails on the world); give the joint its effort "
                                 "limit, or leave out its transmission")


def _merged(include) -> bool:
    """Whether an SDF <include> merges its model into the including one (SDFormat's booleans: true or 1)."""
    return (include.get("merge") or "").strip().lower() in ("true", "1")


def _check_own_links(description: Description, where: str) -> None:
    """InputError for a lone model with no link of its own, only nested models (an arm inside a wrapper model: Drake
    loads the arm as the nested instance, and a robot's links and joints are its own model's)."""
    if description.nested and not any("::" not in link for link in description.links):
        raise InputError(f"{where}: its model {description.name!r} holds no link of its own, only the nested model"
                         f"{'s' if len(description.nested) > 1 else ''} {', '.join(description.nested)}: a robot's links "
                         "and joints are its own model's (write the arm into it, or include it with merge=\"true\")")


def _add_model(description: Description, model: Description, prefix: str) -> None:
    """The links and joints of an included `model` (read from its file) into `description`, scoped `prefix`: a
    world's model ("name::" where the world holds several), or a model's merged include (its own scope)."""
    description.links.update({prefix + link: inertial for link, inertial in model.links.items()})
    description.joints += [dataclasses.replace(joint, name=prefix + joint.name, child=joint.child and prefix + joint.child,
                                               parent=joint.parent if joint.parent in ("world", "") else prefix + joint.parent)
                           for joint in model.joints]
    description.included.update(model.included)


def check_description(path: pathlib.Path, robot: str, arm_joints, overrides: dict | None = None,
                      locked_joints=(), packages: dict | None = None) -> Description:
    """InputError naming robot `robot` and the link or joint, before Drake parses the file, for: a kinematic
    loop (a link that is the child of two joints, or joints in a cycle); a negative or non-finite mass or
    inertia on any link; an arm joint that moves no mass at all; a movable joint whose lower position
    limit is above its upper one or whose velocity limit is negative (Drake's assertions end the process);
    an arm joint with a non-finite or zero limit. Principal moments no body has are Drake's to replace
(`inertia_substitution.inertia_substitutions` says with what). Massless frames (no <inertial>, or mass 0 and no inertia:
    a flange or tool frame), point masses and thin rods are valid bodies and pass; whether each arm joint
    moves inertia about its own axis is checked on the plant (M(home) positive definite,
    `Robot.check_plant`). overrides: per joint name, the limits the robot config gives instead of the
    file's ({"lower", "upper", "velocity", "effort"}: rad or m, rad/s or m/s, N m or N), applied before the checks.
    Returns the description read; a file that is not well-formed XML or declares entities is refused (`read_description`, which
    follows the SDF includes of `packages`, the robot config's package_paths, too)."""
    where = f"robot {robot}: {path.name}"
    if len(arm_joints) > MAX_ARM_JOINTS:   # (before any work that grows with them; `robot init` refuses the same)
        raise InputError(f"robot {robot}: its config names {len(arm_joints)} arm joints; an arm here has at most "
                         f"{MAX_ARM_JOINTS} (a humanoid's limbs are several arms: describe one)")
    try:
        description = read_description(path, packages=packages)
    except InputError as error:
        raise InputError(f"robot {robot}: {error}") from None
    check_tree(description, where)
    for joint in description.joints:
        if joint.name in arm_joints and joint.kind not in MOVABLE:
            raise InputError(f"{where}: arm joint {joint.name!r} is a {joint.kind} joint; arm_joints name the joints "
                             f"that move ({', '.join(MOVABLE)})")
    for link, inertial in description.links.items():
        if inertial is not None:
            check_inertial(inertial, f"{where}: link {link!r}")
    check_moved_mass(description, arm_joints, where)
    for joint in description.joints:
        if joint.kind == "continuous" and {"lower", "upper"} & set((overrides or {}).get(joint.name, {})):
            raise InputError(f"{where}: joint {joint.name!r} is continuous (no position limits in URDF); leave it out "
                             "of position_limits")
        if joint.kind in MOVABLE:
            joint = dataclasses.replace(joint, **(overrides or {}).get(joint.name, {}))
            check_limits(joint, f"{where}: {'arm ' if joint.name in arm_joints else ''}joint {joint.name!r}",
                         arm=joint.name in arm_joints, locked=joint.name in locked_joints)
    return description


def check_tree(description: Description, where: str) -> None:
    """InputError unless the joints form a tree: each link the child of one joint at most, no cycle."""
    parents = {}
    for joint in description.joints:
        if not (joint.parent and joint.child):   # (malformed: Drake's parser names it)
            continue
        if joint.child in parents:
            raise InputError(f"{where}: link {joint.child!r} is the child of joints {parents[joint.child].name!r} and "
                             f"{joint.name!r}, a kinematic loop; Drake's plant needs a tree (close loops with a "
                             "constraint, not a joint)")
        parents[joint.child] = joint
    done = set()   # links whose way up to a root is known to end (each link walked once: linear in the links)
    for start in parents:
        path, index = [], {}
        link = start
        while link in parents and link not in done:
            if link in index:
                cycle = [parents[name].name for name in path[index[link]:]]
                raise InputError(f"{where}: joints {', '.join(cycle)} form a cycle through link {link!r}, a kinematic "
                                 "loop; Drake's plant needs a tree")
            index[link] = len(path)
            path.append(link)
            link = parents[link].parent
        done.update(path)


def check_inertial(inertial: Inertial, where: str) -> None:
    """InputError for a negative or non-finite mass (kg) or a non-finite inertia entry (kg m²): numbers no body has and
    Drake's parser would not use as written (it replaces a negative mass by 1 kg). Principal moments no body has (one
    negative, or breaking the triangle inequality) are Drake's to replace, not refused here (`inertia_substitution`
    says what Drake uses). A mass of 0 is a massless frame whatever its inertia says (`model_file.zero_massless_inertia`
    zeroes it); for a subnormal one, the least mass that keeps the moments in its reach is advised (held-out run 42)."""
    mass, inertia = inertial.mass, inertial.inertia
    if mass is None:
        return
    if not math.isfinite(mass) or mass < 0:
        raise InputError(f"{where} has mass {mass:g} kg; a mass is a finite number >= 0")
    if 0 < mass < sys.float_info.min:   # (Drake divides the inertia by it: inf, and the plant simulates inf)
        top = np.abs(np.linalg.eigvalsh(inertia)).max() if np.isfinite(inertia).all() else 0.0
        least = max(sys.float_info.min, top / MAX_GYRATION_RADIUS ** 2)
        reach = (f" (its largest principal moment {top:.6g} kg m² within mass x ({MAX_GYRATION_RADIUS:g} m)², as far "
                 "as a body reaches)" if least > sys.float_info.min else "")
        raise InputError(f"{where} has mass {mass!r} kg; a mass is 0 (a massless frame) or at least "
                         f"{bound_text(least, at_least=True)} kg{reach}")
    if not np.isfinite(inertia).all():
        raise InputError(f"{where} has a non-finite inertia entry; give finite ixx, ixy, ixz, iyy, iyz, izz (kg m²)")
    with np.errstate(over="ignore"):   # (the overflow is the refusal's, not a warning of its own)
        per_unit_mass = inertia / mass if mass > 0 else np.zeros(3)
    if not np.isfinite(per_unit_mass).all():
        raise InputError(f"{where} has inertia entries up to {np.abs(inertia).max():g} kg m² for a mass of {mass:g} "
                         "kg: per unit mass they overflow a double (Drake's plant would hold inf)")


def check_moved_mass(description: Description, arm_joints, where: str) -> None:
    """InputError for an arm joint none of whose moved links (its child and all below) has a mass."""
    for joint in description.joints:
        if joint.name not in arm_joints or joint.child not in description.links:
            continue
        moved = description.subtree(joint.child)
        masses = [description.links[link].mass for link in moved if description.links.get(link) is not None]
        if not any(mass is None or mass > 0 for mass in masses):
            raise InputError(f"{where}: arm joint {joint.name!r} moves links {', '.join(moved)}, none of which has a "
                             "mass; give them an <inertial>")


# The robot config key that replaces each limit the file states.
