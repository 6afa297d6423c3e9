"""Masses from geometry (`robot init --masses-from-geometry`, issue 58 item 3): mass properties of solids filling a
link's collision shapes and meshes, checked against the closed-form formulas of a cylinder and a box, STL (binary,
ASCII), OBJ and COLLADA meshes, a mesh that is not closed (its convex hull), the default density against the shipped arms'
own, and the command end to end on a kinematic description."""
import os
import pathlib
import re
import struct
import subprocess
import sys

import numpy as np
import pytest

from stdm_drake.errors import InputError
from stdm_drake.robots import geometry_masses as gm

ROOT = pathlib.Path(__file__).resolve().parent.parent
ENV = dict(os.environ, DRAKE_ALLOW_NETWORK="meshcat")


def kinematic(urdf: str) -> str:
    """The description with every <inertial> removed (a kinematic file, as published ones without dynamics are)."""
    return re.sub(r"<inertial>.*?</inertial>", "", urdf, flags=re.S)


def rotation(rpy):
    roll, pitch, yaw = rpy
    cx, sx, cy, sy, cz, sz = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    return (np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]]) @ np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
            @ np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]]))


def cylinder_link(elements, density):
    """(mass, centre of mass, inertia about it) of solid cylinders [(radius, length, xyz, rpy)], by the textbook
    formulas and the parallel-axis theorem, in numpy (no Drake)."""
    masses, centers, inertias = [], [], []
    for radius, length, xyz, rpy in elements:
        mass = density * np.pi * radius ** 2 * length
        side = mass * (3 * radius ** 2 + length ** 2) / 12
        R = rotation(rpy)
        masses.append(mass), centers.append(np.array(xyz)), inertias.append(R @ np.diag([side, side, mass * radius ** 2 / 2]) @ R.T)
    total = sum(masses)
    center = sum(m * c for m, c in zip(masses, centers)) / total
    inertia = sum(I + m * (np.dot(c - center, c - center) * np.eye(3) - np.outer(c - center, c - center))
                  for m, c, I in zip(masses, centers, inertias))
    return total, center, inertia


def test_the_ur10s_cylinders_give_the_textbook_masses_and_inertias(tmp_path):
    """The UR-10 description made kinematic: each link's mass, centre of mass and inertia about it equal the solid
    cylinders' of its collision elements (placed and turned by their origins) to 1e-9."""
    import xml.etree.ElementTree as ElementTree
    text = (ROOT / "models/ur10.urdf").read_text()
    path = tmp_path / "ur10_kinematic.urdf"
    path.write_text(kinematic(text))
    found = {mass.link: mass for mass in gm.geometry_masses(path, {}, density=1000.0)}
    links = {link.get("name"): link for link in ElementTree.fromstring(text).findall("link")}
    assert set(found) == {name for name, link in links.items() if link.find("collision") is not None}
    for name, mass in found.items():
        elements = []
        for element in links[name].findall("collision"):
            origin, shape = element.find("origin"), element.find("geometry/cylinder")
            elements.append((float(shape.get("radius")), float(shape.get("length")),
                             [float(v) for v in (origin.get("xyz") or "0 0 0").split()],
                             [float(v) for v in (origin.get("rpy") or "0 0 0").split()]))
        total, center, inertia = cylinder_link(elements, 1000.0)
        assert mass.source == "collision" and mass.hulls == []
        assert mass.mass == pytest.approx(total, rel=1e-9)
        np.testing.assert_allclose(mass.center, center, atol=1e-9)
        np.testing.assert_allclose(mass.inertia, inertia, atol=1e-9 * np.abs(inertia).max())


def moving_density(urdf: pathlib.Path) -> float:
    """The arm's moving links' masses (as the file states them) over the volume of their collision geometry."""
    import xml.etree.ElementTree as ElementTree
    root = ElementTree.parse(urdf).getroot()
    children = {joint.find("child").get("link") for joint in root.findall("joint") if joint.get("type") != "fixed"}
    stated = {link.get("name"): float(link.find("inertial/mass").get("value")) for link in root.findall("link")
              if link.find("inertial") is not None}
    path = urdf.parent / f"kinematic_{urdf.name}"
    path.write_text(kinematic(urdf.read_text()))
    try:
        volumes = {mass.link: mass.mass for mass in gm.geometry_masses(path, {}, density=1.0)}
    finally:
        path.unlink()
    moving = [name for name in volumes if name in children]
    return sum(stated[name] for name in moving) / sum(volumes[name] for name in moving)


def test_the_default_density_lies_between_the_shipped_arms_own(tmp_path):
    """DEFAULT_DENSITY against the UR-10's and the Panda's moving links (the links a non-fixed joint moves
    directly): 1,570 and 1,120 kg/m³ (the module's docstring); the default lies between them."""
    import shutil
    for name in ("ur10.urdf", "panda.urdf"):
        shutil.copy(ROOT / "models" / name, tmp_path / name)
    ur10, panda = moving_density(tmp_path / "ur10.urdf"), moving_density(tmp_path / "panda.urdf")
    assert ur10 == pytest.approx(1570, rel=0.01) and panda == pytest.approx(1120, rel=0.01)
    assert panda < gm.DEFAULT_DENSITY < ur10


def box_triangles(size, offset):
    """(corners (12, 3, 3)) of a closed box wound outward."""
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float) * size + offset
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return np.array([corners[[a, b, c]] for a, b, c, d in faces] + [corners[[a, c, d]] for a, b, c, d in faces])


def write_stl(path, triangles, ascii_format=False):
    if ascii_format:
        lines = ["solid box"] + [line for triangle in triangles for line in (
            "facet normal 0 0 0", "outer loop", *[f"vertex {x:.9g} {y:.9g} {z:.9g}" for x, y, z in triangle], "endloop",
            "endfacet")] + ["endsolid box"]
        path.write_text("\n".join(lines))
    else:
        path.write_bytes(b"\0" * 80 + struct.pack("<I", len(triangles)) + b"".join(
            struct.pack("<12fH", 0, 0, 0, *np.asarray(triangle, dtype=np.float32).ravel(), 0) for triangle in triangles))


def link_urdf(mesh: str, origin='xyz="0.1 0 0" rpy="0 0 0.5"', scale=""):
    return (f'<robot name="one"><link name="base"/><link name="arm"><collision><origin {origin}/><geometry>'
            f'<mesh filename="{mesh}"{scale}/></geometry></collision></link><joint name="j" type="revolute">'
            '<parent link="base"/><child link="arm"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="10" '
            'velocity="1"/></joint></robot>')


@pytest.mark.parametrize("kind", ["binary stl", "ascii stl", "obj", "dae", "ply"])
def test_a_closed_box_mesh_has_the_boxs_mass_properties(tmp_path, kind):
    """A 0.2 x 0.1 x 0.05 m box mesh whose corner is at (0.01, 0.02, 0.03) in its file, placed by its origin and
    scaled by 2 along x: mass density x volume, centre the box's centre placed, inertia the box's turned."""
    size, offset = np.array([0.2, 0.1, 0.05]), np.array([0.01, 0.02, 0.03])
    triangles = box_triangles(size, offset)
    if kind in ("dae", "ply"):   # (written by trimesh: a COLLADA scene and a PLY, as CAD exports give them)
        import trimesh
        corners = triangles.reshape(-1, 3)
        trimesh.Trimesh(corners, np.arange(len(corners)).reshape(-1, 3), process=False).export(tmp_path / f"box.{kind}")
        name = f"box.{kind}"
    elif kind == "obj":
        lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for triangle in triangles for x, y, z in triangle]
        lines += [f"f {3 * i + 1} {3 * i + 2} {3 * i + 3}" for i in range(len(triangles))]
        (tmp_path / "box.obj").write_text("\n".join(lines))
        name = "box.obj"
    else:
        write_stl(tmp_path / "box.stl", triangles, ascii_format=kind == "ascii stl")
        name = "box.stl"
    (tmp_path / "one.urdf").write_text(link_urdf(name, scale=' scale="2 1 1"'))
    [mass] = gm.geometry_masses(tmp_path / "one.urdf", {}, density=2000.0)
    scaled = size * [2, 1, 1]
    expected_mass = 2000.0 * np.prod(scaled)
    R = rotation([0, 0, 0.5])
    a, b, c = scaled
    box = expected_mass / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    assert mass.hulls == [] and mass.mass == pytest.approx(expected_mass, rel=1e-6)
    np.testing.assert_allclose(mass.center, np.array([0.1, 0, 0]) + R @ ((offset + size / 2) * [2, 1, 1]), atol=1e-7)
    np.testing.assert_allclose(mass.inertia, R @ box @ R.T, atol=1e-6 * box.max())


def test_a_mesh_that_is_not_closed_takes_its_convex_hull_and_says_so(tmp_path):
    """One triangle of the box missing: the box's convex hull stands in (the same box here), named in the note."""
    triangles = box_triangles(np.array([0.2, 0.1, 0.05]), np.zeros(3))
    write_stl(tmp_path / "open.stl", triangles[1:])
    (tmp_path / "one.urdf").write_text(link_urdf("open.stl"))
    [mass] = gm.geometry_masses(tmp_path / "one.urdf", {}, density=1000.0)
    assert mass.hulls == ["open.stl"] and mass.mass == pytest.approx(1000.0 * 0.2 * 0.1 * 0.05, rel=1e-6)
    note = gm.MassesFromGeometry().note([mass], tmp_path / "one_masses.urdf")
    assert "convex hulls for meshes that are not closed: open.stl" in note and "1300 kg/m³" in note


def test_total_mass_scales_every_link(tmp_path):
    path = tmp_path / "ur10_kinematic.urdf"
    path.write_text(kinematic((ROOT / "models/ur10.urdf").read_text()))
    by_density = gm.geometry_masses(path, {}, density=1000.0)
    by_total = gm.geometry_masses(path, {}, total_mass=30.0)
    assert sum(mass.mass for mass in by_total) == pytest.approx(30.0)
    scale = by_total[0].mass / by_density[0].mass
    for a, b in zip(by_density, by_total):
        assert b.mass == pytest.approx(scale * a.mass) and np.allclose(b.inertia, scale * a.inertia)
        np.testing.assert_allclose(a.center, b.center)


@pytest.mark.parametrize("mesh, message", [
    ("part.vtk", "mesh part.vtk is a .vtk; masses from geometry read STL, OBJ, COLLADA, PLY and OFF"),
    ("part.dae", "part.dae cannot be read"),
    ("missing.stl", "mesh 'missing.stl' not found"),
    ("package://nowhere/part.stl", "is in package 'nowhere', which was not found"),
])
def test_meshes_these_rules_cannot_read_are_one_line(tmp_path, mesh, message):
    (tmp_path / "part.dae").write_text("<COLLADA/>")
    (tmp_path / "part.vtk").write_text("# vtk DataFile Version 2.0")
    (tmp_path / "one.urdf").write_text(link_urdf(mesh))
    with pytest.raises(InputError, match=re.escape(message)):
        gm.geometry_masses(tmp_path / "one.urdf", {})


@pytest.mark.slow
def test_robot_init_writes_the_description_with_masses_and_a_config_that_names_it(tmp_path):
    """End to end, as a user runs it: a kinematic UR-10 whose links carry STL boxes in a meshes/ folder beside it,
    the YAML written into another folder: the copy beside the YAML holds an <inertial> per link with geometry,
    its mesh paths rewritten relative to it, the YAML names it and says the dynamics are approximate, and
    `robot check` passes on the YAML."""
    source, out = tmp_path / "arm", tmp_path / "configs"
    (source / "meshes").mkdir(parents=True)
    out.mkdir()
    write_stl(source / "meshes" / "block.stl", box_triangles(np.array([0.08, 0.08, 0.08]), np.full(3, -0.04)))
    text = kinematic((ROOT / "models/ur10.urdf").read_text())
    text = text.replace("<collision><origin xyz=\"0 0 0.019\"/><geometry><cylinder radius=\"0.075\" length=\"0.038\"/>"
                        "</geometry></collision>",
                        "<collision><origin xyz=\"0 0 0.019\"/><geometry><mesh filename=\"meshes/block.stl\"/>"
                        "</geometry></collision>")
    assert "meshes/block.stl" in text
    (source / "ur10k.urdf").write_text(text)
    run = subprocess.run([sys.executable, "-m", "stdm_drake.cli", "robot", "init", str(source / "ur10k.urdf"), "-o",
                          str(out / "arm.yaml"), "--masses-from-geometry"], capture_output=True, text=True, env=ENV,
                         cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert "masses from geometry: 7 links" in run.stdout and "approximate" in run.stdout
    assert sorted(path.name for path in out.iterdir()) == ["arm.yaml", "ur10k_masses.urdf"]
    yaml_text = (out / "arm.yaml").read_text()
    assert "model: ur10k_masses.urdf" in yaml_text and "# NOTE: masses from geometry" in yaml_text
    copy = (out / "ur10k_masses.urdf").read_text()
    assert copy.count("<inertial>") == 7 and 'filename="../arm/meshes/block.stl"' in copy
    check = subprocess.run([sys.executable, "-m", "stdm_drake.cli", "robot", "check", str(out / "arm.yaml")],
                           capture_output=True, text=True, env=ENV)
    assert check.returncode == 0, check.stderr


def test_a_package_shipped_under_another_folder_name_is_found_by_its_files(tmp_path):
    """rtb-data's layout: package://abb_irb140_support/meshes/... in a folder named abb_irb140_description. The
    folder at or above the model's that holds every file the URIs name is the package; with one file missing it is
    not found (named among the missing)."""
    from stdm_drake.robots.starting_config import find_packages
    root = tmp_path / "arm_description"
    (root / "urdf").mkdir(parents=True)
    (root / "meshes" / "collision").mkdir(parents=True)
    write_stl(root / "meshes" / "collision" / "a.stl", box_triangles(np.full(3, 0.1), np.zeros(3)))
    write_stl(root / "meshes" / "collision" / "b.stl", box_triangles(np.full(3, 0.1), np.zeros(3)))
    urdf = root / "urdf" / "arm.urdf"
    urdf.write_text(link_urdf("package://arm_support/meshes/collision/a.stl").replace(
        "</robot>", '<link name="x"><visual><geometry><mesh filename="package://arm_support/meshes/collision/b.stl"/>'
                    "</geometry></visual></link></robot>"))
    assert find_packages(urdf) == ({"arm_support": root}, [], ["arm_support"])
    (root / "meshes" / "collision" / "b.stl").unlink()
    assert find_packages(urdf) == ({}, ["arm_support"], [])
    assert find_packages(urdf, given={"arm_support": tmp_path}) == ({"arm_support": tmp_path}, [], [])
