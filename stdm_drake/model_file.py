"""Robot description files as stdm-drake reads them, beside Drake's parser: the joint facts a URDF or
SDF states (limits, continuous joints, <mimic> pairs), visual meshes that are missing, an offline
Parser, and welding a joint at a position. Used by `stdm_drake.robot`."""
import os
import pathlib

import numpy as np

os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")

from pydrake.math import RigidTransform  # noqa: E402
from pydrake.multibody.parsing import Parser  # noqa: E402
from pydrake.multibody.plant import MultibodyPlant  # noqa: E402

from stdm_drake.errors import InputError  # noqa: E402


def joint_facts(path: pathlib.Path) -> tuple[dict, set, list]:
    """(per joint name, the limits the description file states: {"effort": N m, "velocity": ...}
    (URDF <limit effort= velocity=>, SDF <axis><limit><effort>/<velocity>); the names of URDF
    "continuous" joints, which have no position limits; the URDF <mimic> pairs (follower, leader)).
    An unparsable file gives ({}, set(), [])."""
    import xml.etree.ElementTree as ElementTree
    try:
        root = ElementTree.parse(path).getroot()
    except (ElementTree.ParseError, OSError):
        return {}, set(), []
    limits = {}
    continuous = {joint.get("name") for joint in root.iter("joint") if joint.get("type") == "continuous"}
    mimics = [(joint.get("name"), joint.find("mimic").get("joint")) for joint in root.iter("joint")
              if joint.find("mimic") is not None and joint.get("name") and joint.find("mimic").get("joint")]
    for joint in root.iter("joint"):
        name, values = joint.get("name"), {}
        urdf = joint.find("limit")
        if urdf is not None:
            values = {key: float(urdf.get(key)) for key in ("effort", "velocity") if urdf.get(key) is not None}
        sdf = joint.find("axis/limit")
        if sdf is not None:
            values = {key: float(sdf.findtext(key)) for key in ("effort", "velocity") if sdf.findtext(key)}
        if name and values:  # (a URDF <transmission> names its joint too, without limits)
            limits[name] = values
    return limits, continuous, mimics


def weld_joint_at(plant: MultibodyPlant, joint, position: float) -> None:
    """Replace a one-dof revolute or prismatic `joint` by a weld at `position` (rad or m)."""
    from pydrake.math import RotationMatrix
    from pydrake.common.eigen_geometry import AngleAxis
    kind = joint.type_name()
    if kind not in ("revolute", "prismatic"):
        raise InputError(f"locked joint {joint.name()!r} is {kind}; only revolute and prismatic joints can be locked")
    axis = np.asarray(joint.revolute_axis() if kind == "revolute" else joint.translation_axis(), dtype=float)
    X_FM = (RigidTransform(RotationMatrix(AngleAxis(position, axis / np.linalg.norm(axis))), np.zeros(3))
            if kind == "revolute" else RigidTransform(position * axis))
    parent, child = joint.frame_on_parent(), joint.frame_on_child()
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


def _mesh_path(uri: str, model_path: pathlib.Path, package_paths: dict) -> pathlib.Path | None:
    """The file a mesh reference names (package://, file:// or relative to the model), or None for a
    package the robot config does not map (Drake reports those itself)."""
    if uri.startswith("package://"):
        package, _, rest = uri[len("package://"):].partition("/")
        return package_paths[package] / rest if package in package_paths else None
    path = pathlib.Path(uri[len("file://"):] if uri.startswith("file://") else uri)
    return path if path.is_absolute() else model_path.parent / path

def without_missing_visual_meshes(name: str, model_path: pathlib.Path, package_paths: dict) -> tuple[str | None, list[str]]:
    """(the model text without the visuals whose mesh file is missing, with every other mesh path made a
    file:// URI; the missing files), or (None, []) when every visual mesh exists. A missing collision
    mesh is an InputError naming robot `name`: the dynamics and the self-collision check need it."""
    import xml.etree.ElementTree as ElementTree
    try:
        tree = ElementTree.parse(model_path)
    except ElementTree.ParseError:
        return None, []  # Drake's parser gives the precise error
    root = tree.getroot()
    parents = {child: parent for parent in root.iter() for child in parent}
    missing, references, dropped = [], [], []
    for element in [element for element in root.iter() if element.tag in ("visual", "collision")]:
        for mesh in element.iter("mesh"):
            uri_element = mesh.find("uri")
            uri = mesh.get("filename") if uri_element is None else (uri_element.text or "").strip()
            path = _mesh_path(uri, model_path, package_paths) if uri else None
            if path is None:
                continue
            references.append((mesh, uri_element, path))
            if not path.is_file():
                if element.tag == "collision":
                    raise InputError(f"robot {name}: collision mesh {uri!r} not found ({path})")
                missing += [uri] if uri not in missing else []
                dropped += [element] if element not in dropped else []
    if not missing:
        return None, []
    for element in dropped:
        parents[element].remove(element)
    for mesh, uri_element, path in references:   # Drake resolves only URIs in a model parsed from text
        if uri_element is None:
            mesh.set("filename", path.resolve().as_uri())
        else:
            uri_element.text = path.resolve().as_uri()
    return ElementTree.tostring(root, encoding="unicode"), missing
