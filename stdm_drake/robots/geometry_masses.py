"""Mass properties from geometry, for a URDF whose links state none (`stdm-drake robot init
--masses-from-geometry`): a kinematic description (meshes and joints, no <inertial>) has no dynamics to
simulate, but its meshes give every link's volume.

The rule: each link without <inertial> that has geometry gets the mass properties of a solid of uniform
density filling its <collision> elements (its <visual> ones where it has no collision geometry): each
element's shape (box, cylinder, sphere, or a mesh in STL, OBJ, COLLADA, PLY or OFF as trimesh reads it,
`meshes.read_mesh`, scaled) placed by its <origin>, the elements' spatial inertias summed about the link's
origin (Drake's `CalcSpatialInertia` for each, shifted and re-expressed by Drake's `SpatialInertia`). A mesh is used as it is where it is closed (every edge
shared by exactly two triangles) and wound outward; otherwise its convex hull (scipy's Qhull) stands in,
and the note says so. Links without geometry (tool frames, a world link) stay massless frames.

Density: `--density` kg/m³, or `--total-mass` kg spread over the links that get masses (one density for
all). The default, DEFAULT_DENSITY, lies between the shipped arms' own: their moving links' masses over the
volume of their collision geometry, 1,570 kg/m³ for the UR-10 and 1,120 kg/m³ for the Panda (an arm is hollow
castings and motors, not solid metal). Elements that overlap are counted twice. The dynamics are approximate:
the YAML says so, and the maker's values replace them when known.
"""
from __future__ import annotations

import dataclasses
import pathlib

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.robots import xml_file
from stdm_drake.robots.xml_file import ASCII_SPACE
from stdm_drake.robots.meshes import read_mesh
from stdm_drake.robots.description import read_description
from stdm_drake.files import write_text_atomic

DEFAULT_DENSITY = 1300.0    # kg/m³: between the UR-10's 1,570 and the Panda's 1,120 (tests/test_geometry_masses.py)
MIN_DENSITY = 1e-3   # kg/m³: far below any solid's (air is 1.2)
MIN_TOTAL_MASS = 1e-6   # kg: a milligram, as a payload's or link's smallest mass
MAX_DENSITY = 1e5           # kg/m³ (osmium: 22,590)
MAX_TOTAL_MASS = 1e5        # kg
MESH_SUFFIXES = (".stl", ".obj", ".dae", ".ply", ".off")   # (trimesh's readers: `meshes.read_mesh`)


@dataclasses.dataclass
class MassesFromGeometry:
    """`robot init --masses-from-geometry`: density kg/m³ (None: DEFAULT_DENSITY) or total_mass kg over the links
    that get masses (one of the two)."""
    density: float | None = None
    total_mass: float | None = None

    @classmethod
    def from_options(cls, requested: bool, density: float | None, total_mass: float | None):
        """The settings of `robot init`'s options, or None without --masses-from-geometry (InputError for a
        density or total mass given without it: they would be ignored)."""
        if requested:
            return cls(density, total_mass)
        for option, value in (("--density", density), ("--total-mass", total_mass)):
            if value is not None:
                raise InputError(f"{option} sets the masses from geometry: it needs --masses-from-geometry")
        return None

    def validate(self) -> None:
        if self.density is not None and self.total_mass is not None:
            raise InputError("--density and --total-mass both set the masses from geometry: give one")
        # (lower bounds: a density of 1e-320 kg/m³ gave links of no mass, whose centres came out nan)
        for option, value, low, top in (("--density", self.density, MIN_DENSITY, MAX_DENSITY),
                                        ("--total-mass", self.total_mass, MIN_TOTAL_MASS, MAX_TOTAL_MASS)):
            if value is not None and not (np.isfinite(value) and low <= value <= top):
                raise InputError(f"{option} must be in [{low:g}, {top:g}], got {value}")

    def copy_path(self, model: pathlib.Path, folder: pathlib.Path) -> pathlib.Path:
        """Where the description with masses goes: beside the robot config."""
        return folder / f"{model.stem}_masses.urdf"

    def note(self, masses: list, copy: pathlib.Path) -> str:
        total = sum(mass.mass for mass in masses)
        rule = (f"scaled to {self.total_mass:g} kg in all" if self.total_mass is not None else
                f"at {self.density if self.density is not None else DEFAULT_DENSITY:g} kg/m³ "
                f"({f'{total:.3g}' if total < 1000 else f'{total:,.0f}'} kg in all)")
        hulls = sorted({name for mass in masses for name in mass.hulls})
        return (f"masses from geometry: {len(masses)} links without <inertial> given those of solids filling their "
                f"geometry, {rule}, in {copy.name}; the dynamics are approximate: replace them with the maker's "
                "values" + (f"; convex hulls for meshes that are not closed: {', '.join(hulls)}" if hulls else ""))


@dataclasses.dataclass
class LinkMass:
    """A link's mass properties from its geometry: mass kg, centre of mass (3,) m and rotational inertia about
    it (3, 3) kg m², in the link's frame; source "collision" or "visual"; hulls: the meshes whose convex hull
    stood in (not closed)."""
    link: str
    mass: float
    center: np.ndarray
    inertia: np.ndarray
    source: str
    hulls: list


def _numbers(text: str | None, count: int, what: str, default: list) -> np.ndarray:
    """The `count` numbers of an attribute (`default` where it is absent); each is already held to the number rule
    by `read_description` (`xml_file.check_numbers`), so what is left is their count and that they are finite."""
    if text is None:
        return np.array(default, dtype=float)
    parts = text.split()
    if len(parts) != count:
        raise InputError(f"{what} is {text.strip(ASCII_SPACE)!r}, not {count} number{'s' if count > 1 else ''} as URDF "
                         "writes them")
    values = np.array([float(part) for part in parts])
    if not np.all(np.isfinite(values)):
        raise InputError(f"{what} is {text.strip(ASCII_SPACE)!r}, not finite")
    return values


def _pose(element, what: str):
    """RigidTransform of an element's <origin> (URDF: xyz m, rpy rad, fixed axes X then Y then Z)."""
    from pydrake.math import RigidTransform, RollPitchYaw
    origin = element.find("origin")
    xyz = _numbers(origin.get("xyz") if origin is not None else None, 3, f"{what}: its origin xyz", [0, 0, 0])
    rpy = _numbers(origin.get("rpy") if origin is not None else None, 3, f"{what}: its origin rpy", [0, 0, 0])
    return RigidTransform(RollPitchYaw(rpy), xyz)


def read_triangles(path: pathlib.Path, what: str) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3), triangles (T, 3) indices) of a mesh file as `meshes.read_mesh` reads it (trimesh), its
    coincident vertices merged (a closed surface shares them)."""
    vertices, triangles = read_mesh(path, what)
    merged, index = np.unique(vertices, axis=0, return_inverse=True)
    return merged, index.reshape(-1)[triangles]


def _closed(triangles: np.ndarray) -> bool:
    """Every edge shared by exactly two triangles, once in each direction (a closed, consistently wound surface)."""
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    directed, counts = np.unique(edges, axis=0, return_counts=True)
    if np.any(counts != 1):
        return False
    reverse = {tuple(edge) for edge in directed}
    return all((b, a) in reverse for a, b in directed)


def _hull(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The convex hull of vertices (V, 3) as (vertices, triangles) wound outward. InputError for a flat mesh."""
    from scipy.spatial import ConvexHull, QhullError
    try:
        hull = ConvexHull(vertices)
    except QhullError:
        raise InputError("its vertices span no volume (a flat or degenerate mesh)") from None
    triangles = hull.simplices.copy()
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    outward = np.einsum("ij,ij->i", np.cross(b - a, c - a), hull.equations[:, :3]) > 0
    triangles[~outward] = triangles[~outward][:, [0, 2, 1]]
    return vertices, triangles


def _mesh_inertia(vertices: np.ndarray, triangles: np.ndarray, density: float):
    """Drake's SpatialInertia (about the mesh's origin, in its frame) of the solid a closed mesh bounds."""
    from pydrake.geometry import SurfaceTriangle, TriangleSurfaceMesh
    from pydrake.multibody.tree import CalcSpatialInertia
    mesh = TriangleSurfaceMesh([SurfaceTriangle(*map(int, row)) for row in triangles], list(vertices))
    return CalcSpatialInertia(mesh, density)


def _element_inertia(element, what: str, resolve, density: float, hulls: list):
    """SpatialInertia about the link's origin, in the link's frame, of one <collision> or <visual> element (None
    for one without a shape)."""
    from pydrake.geometry import Box, Cylinder, Sphere
    from pydrake.multibody.tree import CalcSpatialInertia
    geometry = element.find("geometry")
    shape = next(iter(geometry), None) if geometry is not None else None
    if shape is None:
        return None
    if shape.tag == "box":
        inertia = CalcSpatialInertia(Box(*_positive(_numbers(shape.get("size"), 3, f"{what}: its box size", None),
                                                    what)), density)
    elif shape.tag == "cylinder":
        radius, length = (_positive(_numbers(shape.get(key), 1, f"{what}: its cylinder {key}", None), what)[0]
                          for key in ("radius", "length"))
        inertia = CalcSpatialInertia(Cylinder(radius, length), density)
    elif shape.tag == "sphere":
        radius = _positive(_numbers(shape.get("radius"), 1, f"{what}: its sphere radius", None), what)[0]
        inertia = CalcSpatialInertia(Sphere(radius), density)
    elif shape.tag == "mesh":
        path = resolve(shape.get("filename") or "", what)
        scale = _numbers(shape.get("scale"), 3, f"{what}: its mesh scale", [1, 1, 1])
        vertices, triangles = read_triangles(path, what)
        vertices = vertices * scale
        if np.prod(scale) < 0:   # (a mirroring scale turns the winding inside out)
            triangles = triangles[:, [0, 2, 1]]
        inertia = None
        if _closed(triangles):
            try:
                inertia = _mesh_inertia(vertices, triangles, density)
            except RuntimeError:   # (wound inward, or not a solid: Drake finds it physically invalid)
                inertia = None
        if inertia is None or not inertia.get_mass() > 0:
            try:
                inertia = _mesh_inertia(*_hull(vertices), density)
            except InputError as error:
                raise InputError(f"{what}: mesh {path.name}: {error}") from None
            hulls.append(path.name)
    else:
        raise InputError(f"{what}: a <{shape.tag}> shape, which URDF does not have (box, cylinder, sphere, mesh)")
    pose = _pose(element, what)
    return inertia.ReExpress(pose.rotation()).Shift(-pose.translation())


def _positive(values, what: str):
    if values is None or np.any(values <= 0):
        raise InputError(f"{what}: a shape's size must be given and positive")
    return values


def mesh_resolver(model: pathlib.Path, packages: dict):
    """resolve(filename, what) -> the mesh file's path, as the robot's loading resolves it (`model_file.mesh_path`:
    package:// or model:// in `packages`, name -> folder; file:// or a path relative to the description);
    InputError for one that is missing or of a format not in MESH_SUFFIXES."""
    from stdm_drake.robots.model_file import mesh_path   # lazy: pydrake
    folders = {name: pathlib.Path(folder) for name, folder in packages.items()}

    def resolve(filename: str, what: str) -> pathlib.Path:
        path = mesh_path(filename, model, folders)
        if path is None:
            name = filename.split("://", 1)[1].partition("/")[0]
            raise InputError(f"{what}: mesh {filename!r} is in package {name!r}, which was not found near "
                             f"{model.name} (map it: --package {name}=FOLDER)")
        if path.suffix.lower() not in MESH_SUFFIXES:
            raise InputError(f"{what}: mesh {path.name} is a {path.suffix or 'file without suffix'}; masses from "
                             "geometry read STL, OBJ, COLLADA, PLY and OFF meshes (convert it, or give the link an "
                             "<inertial>)")
        if not path.is_file():
            raise InputError(f"{what}: mesh {filename!r} not found ({path})")
        return path
    return resolve


def geometry_masses(model: pathlib.Path, packages: dict, density: float | None = None,
                    total_mass: float | None = None) -> list[LinkMass]:
    """The LinkMass of every link of URDF `model` without <inertial> that has geometry, at `density` kg/m³ (default
    DEFAULT_DENSITY) or scaled so that their masses sum to `total_mass` kg. InputError for an SDF file, a shape
    these rules cannot read, or no link to give a mass."""
    from pydrake.multibody.tree import SpatialInertia
    if model.suffix.lower() != ".urdf":
        raise InputError(f"{model.name}: --masses-from-geometry reads URDF files (an SDF link without <inertial> has "
                         "SDFormat's 1 kg and unit inertia: give its links <inertial> elements)")
    description = read_description(model)   # (its entity, size and number checks first)
    resolve = mesh_resolver(model, packages)
    unit = 1.0 if total_mass is not None else (density if density is not None else DEFAULT_DENSITY)
    results = []
    for link in xml_file.parse(model).getroot().findall("link"):
        name = link.get("name")
        if description.links.get(name) is not None:
            continue
        for source in ("collision", "visual"):
            elements = link.findall(source)
            if elements:
                break
        hulls, total = [], SpatialInertia.Zero()
        for element in elements:
            inertia = _element_inertia(element, f"link {name!r}: its <{source}>", resolve, unit, hulls)
            if inertia is not None:
                total += inertia
        mass = total.get_mass()
        if not mass > 0:
            continue
        center = total.get_com()
        about_center = total.Shift(center).CalcRotationalInertia().CopyToFullMatrix3()
        results.append(LinkMass(name, mass, center, about_center, source, hulls))
    if not results:
        raise InputError(f"{model.name}: no link without <inertial> has geometry to take a mass from")
    if total_mass is not None:
        scale = total_mass / sum(result.mass for result in results)
        for result in results:
            result.mass, result.inertia = result.mass * scale, result.inertia * scale
    return results


def write_with_masses(model: pathlib.Path, output: pathlib.Path, masses: list[LinkMass]) -> None:
    """A copy of URDF `model` at `output` (written atomically) with an <inertial> for each of `masses`, and mesh
    paths relative to the model's folder rewritten relative to the copy's (package:// stays: the config's
    package_paths resolve it)."""
    import os
    import xml.etree.ElementTree as ElementTree
    tree = xml_file.parse(model)
    by_link = {mass.link: mass for mass in masses}
    for link in tree.getroot().findall("link"):
        mass = by_link.get(link.get("name"))
        if mass is not None:
            inertial = ElementTree.SubElement(link, "inertial")
            ElementTree.SubElement(inertial, "origin", xyz=" ".join(f"{value:.9g}" for value in mass.center),
                                   rpy="0 0 0")
            ElementTree.SubElement(inertial, "mass", value=f"{mass.mass:.9g}")
            i = mass.inertia
            ElementTree.SubElement(inertial, "inertia", ixx=f"{i[0, 0]:.9g}", ixy=f"{i[0, 1]:.9g}",
                                   ixz=f"{i[0, 2]:.9g}", iyy=f"{i[1, 1]:.9g}", iyz=f"{i[1, 2]:.9g}",
                                   izz=f"{i[2, 2]:.9g}")
        for shape in link.iter("mesh"):
            local = (shape.get("filename") or "").removeprefix("file://")
            if local and "://" not in local and not pathlib.Path(local).is_absolute():
                shape.set("filename", os.path.relpath(model.parent.resolve() / local, output.parent.resolve()))
    ElementTree.indent(tree)
    write_text_atomic(output, "<?xml version=\"1.0\"?>\n" + ElementTree.tostring(tree.getroot(), encoding="unicode")
                      + "\n")
