"""Mesh files as stdm-drake reads them: the formats Drake and Meshcat take, and the OBJ copies (in a cache
named by each file's SHA-256) of the STL, COLLADA, PLY and OFF meshes they do not. Used by
`stdm_drake.robots.model_file`."""
import os
import pathlib

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.files import write_text_atomic


# Mesh formats Drake reads as collision geometry (it takes their convex hull), and as visuals Meshcat shows.
DRAKE_COLLISION_MESHES = (".obj", ".vtk", ".gltf")
MESHCAT_VISUAL_MESHES = (".obj", ".gltf", ".dae")
CONVERTED_MESHES = (".stl", ".dae", ".ply", ".off")   # read by trimesh (COLLADA through pycollada)
MESH_CACHE_VERSION = "1"   # part of every cached file's name: bump when the conversion changes


def mesh_cache_dir() -> pathlib.Path:
    """Where converted meshes are kept: $STDM_DRAKE_CACHE/meshes, else $XDG_CACHE_HOME/stdm-drake/meshes,
    else ~/.cache/stdm-drake/meshes."""
    root = os.environ.get("STDM_DRAKE_CACHE")
    if not root:
        root = pathlib.Path(os.environ.get("XDG_CACHE_HOME") or pathlib.Path.home() / ".cache") / "stdm-drake"
    return pathlib.Path(root) / "meshes"


def mesh_as_obj(path: pathlib.Path, what: str) -> pathlib.Path:
    """The Wavefront OBJ copy of mesh file `path` (STL, COLLADA, PLY or OFF) in the mesh cache, converted
    once with trimesh and named by the SHA-256 of the file's bytes. Coordinates keep the file's own
    length unit, except that a COLLADA <unit meter=...> is applied (as ROS tools do), so a URDF
    `scale` means what it meant; the COLLADA up_axis is not applied. Every part of the file's scene is
    placed by its node transforms and merged into one mesh (Drake takes a collision mesh's convex hull
    anyway). InputError, naming `what`, for a file trimesh cannot read or one without triangles."""
    import hashlib
    digest = hashlib.sha256(path.read_bytes()).hexdigest()[:32]
    target = mesh_cache_dir() / f"{digest}-v{MESH_CACHE_VERSION}.obj"
    if target.is_file():
        return target
    import trimesh
    vertices, faces = read_mesh(path, what)
    lines = [f"# {path.name} converted by stdm-drake (trimesh {trimesh.__version__})"]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    try:
        return write_text_atomic(target, "\n".join(lines) + "\n")
    except OSError as error:
        raise InputError(f"{what}: cannot write the converted mesh cache {target.parent} ({error.strerror}); "
                         "set STDM_DRAKE_CACHE to a writable folder") from None


def read_mesh(path: pathlib.Path, what: str) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3), triangles (T, 3) vertex indices) of mesh file `path` (STL, COLLADA, PLY, OFF or OBJ) as
    trimesh reads it: a COLLADA <unit meter=...> applied, every part of the scene placed by its node transforms
    and merged into one mesh. InputError, naming `what`, for a file trimesh cannot
    read or one without triangles with finite vertices."""
    import trimesh
    try:
        scene = trimesh.load(str(path), force="scene")
        if scene.units not in (None, "m", "meter", "meters"):
            scene = scene.convert_units("m")
        mesh = scene.to_mesh()
    except Exception as error:  # trimesh and pycollada raise many kinds on a malformed file
        raise InputError(f"{what}: mesh {path} cannot be read ({type(error).__name__}: "
                         f"{str(error).splitlines()[0] if str(error) else 'no detail'})") from None
    vertices, faces = np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces)
    if len(faces) == 0 or not np.isfinite(vertices).all():
        raise InputError(f"{what}: mesh {path} has no triangles with finite vertices")
    return vertices, faces


def collada_in_metres(path: pathlib.Path) -> bool:
    """Whether a COLLADA file states its lengths in metres (or states no unit): what Meshcat shows as
    written. Meshcat's loader ignores <unit>, so other COLLADA visuals go through an OBJ copy with the
    unit applied (their own colors lost; a URDF <material> still applies)."""
    import xml.etree.ElementTree as ElementTree
    try:
        root = ElementTree.parse(path).getroot()
        unit = next((element for element in root.iter() if element.tag.rsplit("}", 1)[-1] == "unit"), None)
        return unit is None or float(unit.get("meter") or 1.0) == 1.0
    except (ElementTree.ParseError, OSError, ValueError):
        return False   # the conversion reports what is wrong with it
