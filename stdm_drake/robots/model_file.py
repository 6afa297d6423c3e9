"""Robot description files as stdm-drake reads them, beside Drake's parser: the joint facts a URDF or
SDF states (limits, continuous joints, <mimic> pairs), the model text Drake can load (missing visual
meshes left out, STL and COLLADA meshes converted to OBJ in a cache), an offline Parser, and welding a
joint at a position. Used by `stdm_drake.robots.robot`."""
import dataclasses
import logging
import os
import pathlib
import re

import numpy as np

from pydrake.math import RigidTransform
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant

from stdm_drake.errors import InputError
from stdm_drake.paths import check_input_file
from stdm_drake.robots import xml_file
from stdm_drake.robots.description import file_number
from stdm_drake.robots.meshes import (CONVERTED_MESHES, DRAKE_COLLISION_MESHES, MESHCAT_VISUAL_MESHES,
                                      collada_in_metres, mesh_as_obj)
from stdm_drake.robots.sdf_includes import MAX_INCLUDE_DEPTH, included_files
from stdm_drake.robots.xml_file import check_xml


def joint_facts(path: pathlib.Path, packages: dict | None = None, depth: int = 0) -> tuple[dict, set, list]:
    """(per joint name, the limits the description file states: {"effort": N m, "velocity": ...}
    (URDF <limit effort= velocity=>, SDF <axis><limit><effort>/<velocity>); the names of URDF
    "continuous" joints, which have no position limits; the URDF <mimic> pairs (follower, leader)).
    An SDF's included files (`sdf_includes.included_files`, `packages` its package:// folders) add theirs: a world
    that includes a URDF arm states that arm's limits in the URDF. An unparsable file gives ({}, set(), [])."""
    import xml.etree.ElementTree as ElementTree
    try:
        root = xml_file.parse(path).getroot()
    except (ElementTree.ParseError, OSError):
        return {}, set(), []
    included = ([joint_facts(target, packages, depth + 1) for target in included_files(root, path, packages)]
                if root.tag == "sdf" and depth < MAX_INCLUDE_DEPTH else [])
    limits = {}
    continuous = {joint.get("name") for joint in root.iter("joint") if joint.get("type") == "continuous"}
    mimics = [(joint.get("name"), joint.find("mimic").get("joint")) for joint in root.iter("joint")
              if joint.find("mimic") is not None and joint.get("name") and joint.find("mimic").get("joint")]
    for joint in root.iter("joint"):
        name, values = joint.get("name"), {}
        urdf = joint.find("limit")
        if urdf is not None:
            values = {key: file_number(urdf.get(key)) for key in ("effort", "velocity")}
        sdf = joint.find("axis/limit")
        if sdf is not None:
            values = {key: file_number(sdf.findtext(key)) for key in ("effort", "velocity")}
        values = {key: value for key, value in values.items() if value is not None}
        if name and values:  # (a URDF <transmission> names its joint too, without limits)
            limits[name] = values
    for their_limits, their_continuous, their_mimics in included:
        for name, values in their_limits.items():
            limits.setdefault(name, values)
        continuous |= their_continuous
        mimics += their_mimics
    return limits, continuous, mimics


def unmodelled_joint_effects(path: pathlib.Path, joints) -> list[str]:
    """What a URDF states about `joints` that Drake's plant does not simulate, one phrase per kind:
    <dynamics friction> (Coulomb friction, N m) and a <transmission> mechanicalReduction other than 1.
    Empty for an SDF or an unparsable file."""
    import xml.etree.ElementTree as ElementTree
    try:
        root = xml_file.parse(path).getroot()
    except (ElementTree.ParseError, OSError):
        return []
    joints = set(joints)
    friction = {}
    for joint in root.iter("joint"):
        dynamics = joint.find("dynamics")
        value = file_number(dynamics.get("friction")) if dynamics is not None else None
        if joint.get("name") in joints and value:
            friction[joint.get("name")] = value
    reductions = {}
    for transmission in root.iter("transmission"):
        names = [joint.get("name") for joint in transmission.iter("joint")]
        values = [value for value in (file_number(element.text) for element in transmission.iter("mechanicalReduction"))
                  if value is not None]
        for name in names:
            if name in joints and values and values[0] != 1.0:
                reductions[name] = values[0]
    effects = []
    if friction:
        effects.append("joint friction (" + ", ".join(f"{name} {value:g}" for name, value in friction.items())
                       + "; N m, or N on a prismatic joint): the simulated joints have none, only the viscous "
                       "<dynamics damping>")
    if reductions:
        effects.append("gear ratios (" + ", ".join(f"{name} {value:g}" for name, value in reductions.items())
                       + "): the action is the joint torque itself and no rotor inertia is reflected")
    return effects


def srdf_disabled_collisions(path: pathlib.Path, name: str) -> list[tuple[str, str]]:
    """The (link1, link2) pairs of a MoveIt SRDF's <disable_collisions> elements; InputError naming robot
    `name` for a missing or unparsable file."""
    check_input_file(path, f"robot {name}: srdf file")
    check_xml(path, "an SRDF file is")     # (entities refused: a "billion laughs" file among them)
    root = xml_file.parse(path).getroot()
    pairs = [(element.get("link1"), element.get("link2")) for element in root.iter("disable_collisions")]
    bad = [pair for pair in pairs if not all(pair)]
    if bad:
        raise InputError(f"robot {name}: srdf {path.name}: a <disable_collisions> element lacks link1 or link2")
    return pairs


def weld_joint_at(plant: MultibodyPlant, joint, position: float) -> None:
    """Replace a one-dof revolute or prismatic `joint` by a weld at `position` (rad or m); an actuator on
    it is removed first."""
    from pydrake.math import RotationMatrix
    from pydrake.common.eigen_geometry import AngleAxis
    kind = joint.type_name()
    if kind not in ("revolute", "prismatic"):
        raise InputError(f"locked joint {joint.name()!r} is {kind}; only revolute and prismatic joints can be locked")
    axis = np.asarray(joint.revolute_axis() if kind == "revolute" else joint.translation_axis(), dtype=float)
    X_FM = (RigidTransform(RotationMatrix(AngleAxis(position, axis / np.linalg.norm(axis))), np.zeros(3))
            if kind == "revolute" else RigidTransform(position * axis))
    parent, child = joint.frame_on_parent(), joint.frame_on_child()
    for index in plant.GetJointActuatorIndices():   # (a URDF <transmission> gives a locked joint one)
        if plant.get_joint_actuator(index).joint().index() == joint.index():
            plant.RemoveJointActuator(plant.get_joint_actuator(index))
    plant.RemoveJoint(joint)
    plant.WeldFrames(parent, child, X_FM)


def offline_parser(plant: MultibodyPlant, model_name_prefix: str = "") -> Parser:
    """A Parser whose package map holds no remote packages.

    Drake's default PackageMap registers the remote `drake_models` package, and with
    DRAKE_ALLOW_NETWORK=meshcat that registration itself throws. We construct the parser with
    the variable briefly unset, then drop `drake_models`, so that any package://drake_models
    reference fails at once ("unknown package") instead of trying a download.
    """
    saved = os.environ.pop("DRAKE_ALLOW_NETWORK", None)
    try:
        parser = Parser(plant, model_name_prefix=model_name_prefix)
    finally:
        if saved is not None:
            os.environ["DRAKE_ALLOW_NETWORK"] = saved
    if parser.package_map().Contains("drake_models"):
        parser.package_map().Remove("drake_models")
    return parser


def _package(uri: str) -> tuple[str | None, str]:
    """(package, path inside it) of a package:// or model:// reference (model://: SDF's name for the same
    thing); (None, uri) for another."""
    for scheme in ("package://", "model://"):
        if uri.startswith(scheme):
            package, _, rest = uri[len(scheme):].partition("/")
            return package, rest
    return None, uri


def mesh_path(uri: str, model_path: pathlib.Path, package_paths: dict) -> pathlib.Path | None:
    """The file a mesh reference names (package://, file:// or relative to the model), or None for a
    package the robot config does not map (Drake resolves one it knows; `loadable_model`)."""
    package, rest = _package(uri)
    if package is not None:
        return package_paths[package] / rest if package in package_paths else None
    path = pathlib.Path(uri[len("file://"):] if uri.startswith("file://") else uri)
    return path if path.is_absolute() else model_path.parent / path

@dataclasses.dataclass
class LoadableModel:
    """A description file made loadable by Drake. text: the model text to parse instead of the file (None:
    the file parses as it is); missing_visuals: visual mesh references left out because their file is
    missing; converted: mesh references replaced by an OBJ copy (collision meshes Drake cannot read,
    visuals Meshcat cannot show); renamed_materials: URDF material names defined twice with different
    colours or named without a definition (`repair_materials`); massless: links of mass 0
    whose inertia entries were set to 0 (`zero_massless_inertia`); missing_collisions: collision mesh
    references left out because their file is missing (the dynamics do not need them; the self-collision
    check and contact then leave that geometry out); undefined_sdf_elements: SDF elements Drake's parser
    refuses as undefined, left out (`remove_undefined_sdf_elements`); unmapped_packages: package names of
    mesh references that neither package_paths nor Drake maps (their meshes are among the missing)."""
    text: str | None
    missing_visuals: list
    converted: list
    renamed_materials: list = dataclasses.field(default_factory=list)
    massless: list = dataclasses.field(default_factory=list)
    missing_collisions: list = dataclasses.field(default_factory=list)
    undefined_sdf_elements: list = dataclasses.field(default_factory=list)
    unmapped_packages: list = dataclasses.field(default_factory=list)

    def warnings(self, file: str) -> list[str]:
        """One line per kind of change made to description `file` to load it (none for a converted mesh)."""
        lines = []
        if self.unmapped_packages:
            lines.append(f"packages {', '.join(self.unmapped_packages)} not found: their meshes are left out (map them "
                         "under package_paths; without collision meshes the self-collision check does not see them)")
        if self.missing_visuals:
            lines.append(f"visual meshes not found, loaded without them: {', '.join(self.missing_visuals)}")
        if self.missing_collisions:
            lines.append("collision meshes not found, loaded without them (the self-collision check and contact leave "
                         f"them out): {', '.join(self.missing_collisions)}")
        if self.massless:
            lines.append(f"links {', '.join(self.massless)} have mass 0 and inertia entries; taken as massless frames "
                         "(inertia 0)")
        if self.renamed_materials:
            lines.append(f"{file} defines materials {', '.join(self.renamed_materials)} twice with different colours, "
                         "or names them without a definition; the later definitions are renamed and undefined ones "
                         "left out (visual only)")
        if self.undefined_sdf_elements:
            lines.append(f"{file}: elements SDFormat does not define there left out (Drake's parser refuses them; "
                         f"another simulator's extensions): {', '.join(self.undefined_sdf_elements)}")
        return lines


def set_joint_limits(root, limits: dict) -> None:
    """Write `limits` (joint name -> {"lower", "upper": rad or m, "velocity": rad/s or m/s, "effort": N m or N})
    into the joints of a parsed URDF or SDF tree, replacing what the file states (URDF <limit>, SDF
    <axis><limit>; made when absent)."""
    import xml.etree.ElementTree as ElementTree
    for joint in (root.iter("joint") if root.tag == "sdf" else root.findall("joint")):   # (not a <transmission>'s)
        values = limits.get(joint.get("name"))
        if not values:
            continue
        if root.tag == "sdf":
            axis = joint.find("axis")
            axis = axis if axis is not None else ElementTree.SubElement(joint, "axis")
            limit = axis.find("limit")
            limit = limit if limit is not None else ElementTree.SubElement(axis, "limit")
            for key, value in values.items():
                element = limit.find(key)
                (element if element is not None else ElementTree.SubElement(limit, key)).text = repr(float(value))
        else:
            limit = joint.find("limit")
            limit = limit if limit is not None else ElementTree.SubElement(joint, "limit")
            for key, value in values.items():
                limit.set(key, repr(float(value)))


def repair_materials(root) -> tuple[list[str], list[str], list[str]]:
    """URDF materials (visual only) as Drake's parser takes them: a name defined twice with different colours
    or textures has each later definition renamed NAME~2, NAME~3, ... (a visual that names a material
    without defining it keeps the first definition, also where that comes later in the file); a visual naming a
    material that is defined nowhere loses its <material> (the default colour). Returns (the names renamed, the
    names undefined, the names given their later definition)."""
    import xml.etree.ElementTree as ElementTree
    if root.tag == "sdf":
        return [], [], []
    definitions, renamed = {}, []
    for material in root.iter("material"):
        name = material.get("name")
        if not name or len(material) == 0:
            continue
        content = "".join(ElementTree.tostring(child, encoding="unicode").strip() for child in material)
        versions = definitions.setdefault(name, [])
        if content not in versions:
            versions.append(content)
        if versions.index(content) > 0:
            material.set("name", f"{name}~{versions.index(content) + 1}")
            renamed += [name] if name not in renamed else []
    undefined, forward, seen = [], [], set()
    for material in list(root.iter("material")):   # (in file order: Drake's parser, as urdfdom, reads a name-only
        name = material.get("name")                # material by the definitions before it; held-out run 37)
        if len(material):
            seen.add(name)
        elif name in definitions and name not in seen:
            material.extend(ElementTree.fromstring(f"<m>{definitions[name][0]}</m>"))   # (the first definition's)
            forward += [name] if name not in forward else []
    for visual in root.iter("visual"):
        for material in visual.findall("material"):
            if len(material) == 0 and material.get("name") not in definitions:
                visual.remove(material)
                undefined += [material.get("name")] if material.get("name") not in undefined else []
    return renamed, undefined, forward


def zero_massless_inertia(root) -> list[str]:
    """Set to 0 the inertia entries of every <inertial> whose mass is 0 (a massless frame: inertia is mass
    times a unit inertia, so the entries mean nothing; Drake's parser would put a 1 kg body in its place).
    Returns the links changed."""
    import xml.etree.ElementTree as ElementTree
    changed = []
    for link in root.iter("link"):
        inertial = link.find("inertial")
        if inertial is None:
            continue
        mass = inertial.find("mass")
        text = mass.get("value") if root.tag != "sdf" and mass is not None else (mass.text if mass is not None else None)
        if file_number(text) != 0.0:
            continue
        inertia = inertial.find("inertia")
        if inertia is None:   # (SDFormat's default is unit moments: a massless frame has none)
            inertia = ElementTree.SubElement(inertial, "inertia")
            if root.tag != "sdf":
                inertia.attrib.update(dict.fromkeys(("ixx", "ixy", "ixz", "iyy", "iyz", "izz"), "0"))
                continue
        if root.tag == "sdf":   # (an absent moment defaults to 1 in SDFormat)
            entries = [ElementTree.SubElement(inertia, key) for key in ("ixx", "iyy", "izz") if inertia.find(key) is None]
            entries += [element for element in inertia if file_number(element.text) != 0.0]
            for element in entries:
                element.text = "0"
        else:
            entries = [key for key, value in inertia.attrib.items() if file_number(value) != 0.0]
            for key in entries:
                inertia.set(key, "0")
        changed += [link.get("name")] if entries else []
    return changed


def loadable_model(name: str, model_path: pathlib.Path, package_paths: dict, limits: dict | None = None) -> LoadableModel:
    """The model text Drake can load (see LoadableModel), with the robot config's `limits` in place of the
    file's (`set_joint_limits`; Drake's parser asserts on some that the config replaces): visuals whose mesh file is missing are left
    out, collision meshes in a format Drake does not read (STL, COLLADA, ...) and visuals Meshcat does
    not show (STL, ...) point to OBJ copies (`mesh_as_obj`), every other mesh path becomes a file:// URI
    (Drake resolves only URIs in a model parsed from text), and an SDF's relative <include> an absolute path. A mesh file that is missing is left out
    (visual or collision: the dynamics need neither); a collision mesh in a format neither Drake nor
    trimesh reads is an InputError naming robot `name`."""
    import xml.etree.ElementTree as ElementTree
    try:
        tree = xml_file.parse(model_path)
    except ElementTree.ParseError:
        return LoadableModel(None, [], [])  # Drake's parser gives the precise error
    root = tree.getroot()
    scratch = MultibodyPlant(0.0)   # (kept alive while its parser's package map is asked)
    drake_packages = offline_parser(scratch).package_map()
    parents = {child: parent for parent in root.iter() for child in parent}
    missing, missing_collisions, converted, references, dropped, unmapped = [], [], [], [], [], []
    for element in [element for element in root.iter() if element.tag in ("visual", "collision")]:
        for mesh in element.iter("mesh"):
            uri_element = mesh.find("uri")
            uri = mesh.get("filename") if uri_element is None else (uri_element.text or "").strip()
            package = _package(uri)[0] if uri else None
            unknown_package = package is not None and package not in package_paths and not drake_packages.Contains(package)
            unmapped += [package] if unknown_package and package not in unmapped else []
            path = mesh_path(uri, model_path, package_paths) if uri else None
            if path is None and not unknown_package:   # (no mesh, or Drake resolves the package)
                continue
            if unknown_package or not path.is_file():
                found = missing if element.tag == "visual" else missing_collisions
                found += [uri] if uri not in found else []
                dropped += [element] if element not in dropped else []
                continue
            suffix = path.suffix.lower()
            readable = DRAKE_COLLISION_MESHES if element.tag == "collision" else MESHCAT_VISUAL_MESHES
            if suffix not in readable or (suffix == ".dae" and not collada_in_metres(path)):
                if suffix not in CONVERTED_MESHES:
                    raise InputError(f"robot {name}: {element.tag} mesh {uri!r} is a {suffix or 'suffix-less'} "
                                     f"file; stdm-drake reads {', '.join(readable + CONVERTED_MESHES)}")
                path = mesh_as_obj(path, f"robot {name}")
                converted += [uri] if uri not in converted else []
            references.append((mesh, uri_element, path))
    (renamed, undefined, forward), massless = repair_materials(root), zero_massless_inertia(root)
    set_joint_limits(root, limits or {})
    for element in dropped:
        parents[element].remove(element)
    for mesh, uri_element, path in references:   # file:// + the plain path: Drake does not percent-decode
        uri = "file://" + str(path.resolve())
        if uri_element is None:
            mesh.set("filename", uri)
        else:
            uri_element.text = uri
    unknown = remove_undefined_sdf_elements(root, package_paths) if root.tag == "sdf" else []
    relative = []   # (a relative <include>: from the file's folder, where SDFormat would look in the working folder)
    for uri in (include.find("uri") for include in root.iter("include")) if root.tag == "sdf" else ():
        if uri is not None and uri.text and "://" not in uri.text and not pathlib.Path(uri.text.strip()).is_absolute():
            uri.text, relative = str((model_path.parent / uri.text.strip()).resolve()), [*relative, uri.text]
    if not (missing or missing_collisions or converted or limits or renamed or undefined or forward or massless
            or unknown or relative):
        return LoadableModel(None, [], [])
    return LoadableModel(ElementTree.tostring(root, encoding="unicode"), missing, converted, renamed + undefined, massless,
                         missing_collisions, unknown, sorted(unmapped))


# Drake's SDFormat parser refuses an element the SDFormat specification does not define where it stands (a
# simulator's own extension, such as pybullet's <contact> in a <link>); its message names it and its parent.
UNDEFINED_SDF_ELEMENT = re.compile(r"XML Element\[(\w+)\], child of element\[(\w+)\], not defined in SDF")


def remove_undefined_sdf_elements(root, package_paths: dict, attempts: int = 20) -> list[str]:
    """Remove from a parsed SDF tree (its mesh references already file:// URIs) the elements Drake's parser
    refuses as undefined by SDFormat (UNDEFINED_SDF_ELEMENT), kind by kind as a trial parse names them;
    they mean nothing to Drake. Returns "<child> in <parent>" per kind removed. The trial parses print nothing: the
    parse that loads the robot prints Drake's warnings, with the toolbox's own filters (a trial's warnings were
    Drake's several-line inertia warning the toolbox leaves out)."""
    import xml.etree.ElementTree as ElementTree
    removed = []
    for _ in range(attempts):
        plant = MultibodyPlant(0.0)   # (kept alive while the parser uses it)
        parser = offline_parser(plant)
        for name, path in package_paths.items():
            parser.package_map().Add(name, str(path))
        drake = logging.getLogger("drake")
        drake.filters.insert(0, silent := lambda record: False)
        try:
            parser.AddModelsFromString(ElementTree.tostring(root, encoding="unicode"), "sdf")
            return removed
        except (RuntimeError, ValueError) as error:
            match = UNDEFINED_SDF_ELEMENT.search(str(error))
        finally:
            drake.removeFilter(silent)
        if match is None:
            return removed   # (another problem: Drake's message when the robot is loaded)
        child, parent = match.groups()
        for element in list(root.iter(parent)):
            for found in element.findall(child):
                element.remove(found)
        removed.append(f"<{child}> in <{parent}>")
    return removed
