"""Robot descriptions as published: STL and COLLADA meshes (converted once to OBJ in a cache), MoveIt SRDF
collision rules and filtered pairs, home checked for self-collision, and what the plant leaves out
(friction, gear ratios) reported. The mesh files are written in their real formats (binary STL by
trimesh, COLLADA by pycollada with a millimetre <unit>), as CAD exports and robot vendors ship them."""
import numpy as np
import pytest
from test_robot_config import GOOD, two_link_urdf, write_robot

from presets import UR10
from stdm_drake.errors import InputError
from stdm_drake.robots.plant import PlantConfig, SelfCollisionChecker, make_plant
from stdm_drake.robots.robot import load_robot

CYLINDER = '<visual><geometry><cylinder radius="0.04" length="0.3"/></geometry></visual>'


def box_stl(path, extents):
    """A binary STL of a box (m) centred on its frame's origin."""
    import trimesh
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(trimesh.creation.box(extents=extents).export(file_type="stl"))
    return path


def box_dae_millimetres(path, extents_mm, metre: float = 0.001):
    """A COLLADA file of a box given in millimetres (<unit meter="0.001">; `metre`=1.0: the same numbers
    in metres), corner at the origin, with a red material."""
    import collada
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float) * extents_mm
    triangles = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                          [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    document = collada.Collada()
    effect = collada.material.Effect("effect", [], "phong", diffuse=(0.8, 0.2, 0.2))
    material = collada.material.Material("material", "material", effect)
    document.effects.append(effect)
    document.materials.append(material)
    source = collada.source.FloatSource("vertices", corners.ravel(), ("X", "Y", "Z"))
    geometry = collada.geometry.Geometry(document, "box", "box", [source])
    inputs = collada.source.InputList()
    inputs.addInput(0, "VERTEX", "#vertices")
    geometry.primitives.append(geometry.createTriangleSet(triangles.ravel(), inputs, "material"))
    document.geometries.append(geometry)
    node = collada.scene.Node("box", children=[collada.scene.GeometryNode(
        geometry, [collada.scene.MaterialNode("material", material, inputs=[])])])
    document.scenes.append(collada.scene.Scene("scene", [node]))
    document.scene = document.scenes[0]
    document.assetInfo.unitmeter, document.assetInfo.unitname = metre, ("millimeter" if metre == 0.001 else "meter")
    path.parent.mkdir(parents=True, exist_ok=True)
    document.write(str(path))
    return path


def with_collision(urdf: str, link: str, geometry: str, origin: str = "0 0 0") -> str:
    """`urdf` with a collision element `geometry` (inner XML of <geometry>) on `link`."""
    opening = f'<link name="{link}">'
    head, _, tail = urdf.partition(opening)
    visual_end = tail.index("</visual>") + len("</visual>")
    collision = f'<collision><origin xyz="{origin}"/><geometry>{geometry}</geometry></collision>'
    return head + opening + tail[:visual_end] + collision + tail[visual_end:]


def collision_meshes(scene_graph) -> list:
    inspector = scene_graph.model_inspector()
    return [inspector.GetShape(geometry) for geometry in inspector.GetAllGeometryIds()
            if inspector.GetProximityProperties(geometry) is not None]


def test_stl_and_collada_meshes_load_through_cached_obj_copies(tmp_path, caplog):
    """STL collision and visual meshes and a COLLADA mesh in millimetres: the plant loads with OBJ copies
    in the cache (the COLLADA unit applied: a 100 mm box is 0.1 m); a COLLADA visual in metres stays as
    it is (Meshcat shows it, colors and all), one in millimetres goes through its OBJ copy (Meshcat
    would ignore its unit); a second load reuses the cache, and a Meshcat recording builds."""
    import trimesh
    from pydrake.systems.framework import DiagramBuilder
    from stdm_drake.robots.recorder import TrajectoryRecorder
    from stdm_drake.robots.meshes import mesh_cache_dir
    box_stl(tmp_path / "meshes" / "upper.stl", [0.08, 0.08, 0.3])
    box_dae_millimetres(tmp_path / "meshes" / "fore.dae", [60.0, 60.0, 100.0])
    urdf = two_link_urdf().replace(CYLINDER, '<visual><geometry><mesh filename="meshes/upper.stl"/></geometry></visual>', 2)
    urdf = urdf.replace(CYLINDER, '<visual><geometry><mesh filename="meshes/fore.dae"/></geometry></visual>', 1)
    box_dae_millimetres(tmp_path / "meshes" / "finger.dae", [0.02, 0.02, 0.05], metre=1.0)
    urdf = urdf.replace(CYLINDER, '<visual><geometry><mesh filename="meshes/finger.dae"/></geometry></visual>', 1)
    urdf = with_collision(urdf, "upper", '<mesh filename="meshes/upper.stl"/>', "0 0 0.15")
    urdf = with_collision(urdf, "fore", '<mesh filename="meshes/fore.dae"/>', "-0.03 -0.03 0.05")
    with caplog.at_level("INFO"):
        robot = load_robot(write_robot(tmp_path, urdf, GOOD))
    assert "2 meshes read through OBJ copies" in caplog.text      # upper.stl, fore.dae (finger.dae stays)
    plant, scene_graph = make_plant(PlantConfig(), builder=DiagramBuilder(), robot=robot)
    assert plant.num_positions() == 2
    paths = [pathlib_of(shape) for shape in collision_meshes(scene_graph)]
    assert len(paths) == 2 and all(path.suffix == ".obj" and path.parent == mesh_cache_dir() for path in paths)
    extents = sorted(tuple(np.round(trimesh.load(str(path), force="mesh").extents, 6)) for path in paths)
    assert extents == [(0.06, 0.06, 0.1), (0.08, 0.08, 0.3)]
    inspector = scene_graph.model_inspector()
    visuals = [pathlib_of(inspector.GetShape(geometry)) for geometry in inspector.GetAllGeometryIds()
               if inspector.GetIllustrationProperties(geometry) is not None
               and type(inspector.GetShape(geometry)).__name__ == "Mesh"]
    assert sorted(path.name for path in visuals if path.suffix == ".dae") == ["finger.dae"]
    assert len([path for path in visuals if path.parent == mesh_cache_dir()]) == 3   # base, upper (STL), fore (mm)
    stamps = [path.stat().st_mtime_ns for path in paths]
    load_robot(tmp_path / "two_link.yaml")
    assert [path.stat().st_mtime_ns for path in paths] == stamps
    recorder = TrajectoryRecorder(0.01, robot=robot)
    recorder.add(np.zeros((3, 2)))
    recorder.publish()
    recorder.write_html(tmp_path / "run.html")
    assert (tmp_path / "run.html").stat().st_size > 1000


def test_meshes_load_from_folders_with_spaces_and_accents_and_through_model_uris(tmp_path, monkeypatch):
    """The rewritten model names every mesh by a plain file:// path (Drake does not percent-decode
    URIs), so a description folder and a cache folder named "a b/é" work; an SDF-style model:// URI
    resolves through package_paths like package://."""
    from pydrake.systems.framework import DiagramBuilder
    from stdm_drake.robots.meshes import mesh_cache_dir
    folder = tmp_path / "a b" / "é"
    folder.mkdir(parents=True)
    monkeypatch.setenv("STDM_DRAKE_CACHE", str(tmp_path / "cache dir é"))
    box_stl(folder / "meshes" / "upper.stl", [0.08, 0.08, 0.3])
    (folder / "meshes" / "fore.obj").write_text(
        "v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nv 0 0 0.05\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    urdf = with_collision(two_link_urdf(), "upper", '<mesh filename="model://parts/meshes/upper.stl"/>', "0 0 0.15")
    urdf = urdf.replace(CYLINDER, '<visual><geometry><mesh filename="meshes/fore.obj"/></geometry></visual>', 1)
    robot = load_robot(write_robot(folder, urdf, GOOD + "package_paths: {parts: .}\n"))
    plant, scene_graph = make_plant(PlantConfig(), builder=DiagramBuilder(), robot=robot)
    assert plant.num_positions() == 2
    (shape,) = collision_meshes(scene_graph)
    assert pathlib_of(shape).parent == mesh_cache_dir() and "cache dir é" in str(mesh_cache_dir())


def pathlib_of(shape):
    import pathlib
    return pathlib.Path(str(shape.source().path()))


@pytest.mark.parametrize("name, content, message", [
    ("bad.stl", b"solid nothing here\nendsolid\n", "meshes/bad.stl cannot be read|has no triangles"),
    ("part.3ds", b"\x4d\x4d\x00\x00", "collision mesh 'meshes/part.3ds' is a .3ds file; stdm-drake reads"),
])
def test_an_unreadable_collision_mesh_is_a_one_line_error(tmp_path, name, content, message):
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / name).write_bytes(content)
    urdf = with_collision(two_link_urdf(), "upper", f'<mesh filename="meshes/{name}"/>')
    with pytest.raises(InputError, match=message) as error:
        load_robot(write_robot(tmp_path, urdf, GOOD))
    assert "\n" not in str(error.value)


def test_an_unwritable_mesh_cache_names_the_variable_that_moves_it(tmp_path, monkeypatch):
    box_stl(tmp_path / "meshes" / "upper.stl", [0.08, 0.08, 0.3])
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("a file where the cache folder would go")
    monkeypatch.setenv("STDM_DRAKE_CACHE", str(blocker))
    urdf = with_collision(two_link_urdf(), "upper", '<mesh filename="meshes/upper.stl"/>', "0 0 0.15")
    with pytest.raises(InputError, match="set STDM_DRAKE_CACHE to a writable folder"):
        load_robot(write_robot(tmp_path, urdf, GOOD))


# A tall collision box on the base reaches the forearm's box at home: links that are not adjacent touch.
TOUCHING = with_collision(with_collision(two_link_urdf(), "base", '<box size="0.3 0.3 1.2"/>', "0 0 0.6"),
                          "fore", '<box size="0.1 0.1 0.1"/>', "0 0 0.15")
SRDF = """<?xml version="1.0"?>
<robot name="two_link">
  <group name="arm"><chain base_link="base" tip_link="tool"/></group>
  <disable_collisions link1="base" link2="fore" reason="Never"/>
  <disable_collisions link1="fore" link2="gripper_pad" reason="Adjacent"/>
</robot>
"""


def test_home_in_self_collision_is_refused_in_one_line_before_any_work(tmp_path, capsys):
    from stdm_drake.cli import main
    robot = write_robot(tmp_path, TOUCHING, GOOD)
    with pytest.raises(InputError, match=r"home is in self-collision \(base/fore\)"):
        SelfCollisionChecker(load_robot(robot))
    for command in (["collect", "--protocol", "excitation", "--count", "2", "--workers", "1"],
                    ["collect", "--protocol", "excitation", "--count", "2", "--workers", "2"]):
        assert main(command + ["--robot", str(robot), "--quiet", "-o", str(tmp_path / "data.h5")]) == 2
        err = capsys.readouterr().err
        assert "home is in self-collision (base/fore)" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "data.h5").exists()


@pytest.mark.parametrize("extra", ["srdf: two_link.srdf\n", "disabled_collisions: [[fore, base]]\n"])
def test_srdf_and_config_pairs_disable_contact_between_links(tmp_path, caplog, extra):
    """The SRDF's <disable_collisions> pairs (those naming links the model lacks: left out with one
    warning) or the config's disabled_collisions allow the touching pair; the simulated plant's contact
    is filtered too, and pairs not listed still count (a box on the finger, welded to the forearm,
    touches the base)."""
    from pydrake.systems.framework import DiagramBuilder
    (tmp_path / "two_link.srdf").write_text(SRDF)
    with caplog.at_level("WARNING"):
        robot = load_robot(write_robot(tmp_path, TOUCHING, GOOD + extra))
        assert SelfCollisionChecker(robot).is_collision_free(robot.home)
    assert ("gripper_pad" in caplog.text) == extra.startswith("srdf")
    builder = DiagramBuilder()
    plant, _ = make_plant(PlantConfig(), builder=builder, robot=robot)
    diagram = builder.Build()
    context = plant.GetMyContextFromRoot(diagram.CreateDefaultContext())
    plant.SetPositions(context, robot.home)
    assert not plant.get_geometry_query_input_port().Eval(context).HasCollisions()
    finger = with_collision(TOUCHING, "finger", '<box size="0.05 0.05 0.05"/>')
    with pytest.raises(InputError, match=r"home is in self-collision \(base/finger\)"):
        SelfCollisionChecker(load_robot(write_robot(tmp_path, finger, GOOD + extra)))


@pytest.mark.parametrize("extra, message", [
    ("disabled_collisions: [[base, elbow_link]]\n", "disabled_collisions names 'elbow_link', not a link"),
    ("disabled_collisions: [[base]]\n", "each entry is two different link names"),
    ("srdf: missing.srdf\n", "srdf file not found"),
    ("srdf: two_link.urdf.broken\n", "is not well-formed XML"),
])
def test_bad_collision_rules_are_one_line_errors(tmp_path, extra, message):
    (tmp_path / "two_link.urdf.broken").write_text("<robot><disable_collisions link1=")
    with pytest.raises(InputError, match=message):
        SelfCollisionChecker(load_robot(write_robot(tmp_path, TOUCHING, GOOD + extra)))


def test_friction_and_gear_ratios_the_plant_leaves_out_are_reported(tmp_path, caplog):
    urdf = two_link_urdf().replace('<axis xyz="0 1 0"/>', '<axis xyz="0 1 0"/><dynamics damping="0.5" friction="2.0"/>', 1)
    urdf = urdf.replace("</robot>", '<transmission name="t"><type>transmission_interface/SimpleTransmission</type>'
                        '<joint name="elbow"><hardwareInterface>EffortJointInterface</hardwareInterface></joint>'
                        '<actuator name="m"><mechanicalReduction>100</mechanicalReduction></actuator></transmission>'
                        "</robot>")
    with caplog.at_level("WARNING", logger="stdm_drake.robots.robot"):
        load_robot(write_robot(tmp_path, urdf, GOOD))
    assert "joint friction (shoulder 2; N m, or N on a prismatic joint): the simulated joints have none" in caplog.text
    assert "gear ratios (elbow 100): the action is the joint torque itself" in caplog.text


@pytest.mark.slow
def test_derived_tracking_plans_fit_a_slow_arm(tmp_path, caplog, monkeypatch):
    """An arm with 0.628 rad/s joints (the UR-10's kinematics and inertia, a fifth of its speed): the
    derived final-pose box and angle shrink so that the 1 s plans stay within the planner's half of the
    velocity limits at the first draw (with the UR-10's box, as before, plans are rejected and redrawn);
    the UR-10's own speed keeps the full box (0.142 m, 0.3 rad)."""
    from stdm_drake.cli import main
    from stdm_drake.collection import plan
    from stdm_drake.collection.plan import derived_tracking_spec
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.robots.robot import MODELS_DIR
    slow = (MODELS_DIR / "ur10.yaml").read_text().partition("defaults:")[0]    # its settings derived, not the UR-10's files
    slow = slow.replace("name: ur10", "name: ur10_slow")
    slow = slow.replace("model: ur10.urdf", "model: stdm-drake:models/ur10.urdf")   # the shipped file, from here
    slow += "velocity_limits: {" + ", ".join(f"{joint}: 0.628" for joint in UR10.joint_names) + "}\n"
    (tmp_path / "slow.yaml").write_text(slow)
    fast_sampling = derived_tracking_spec(UR10).sampling
    with caplog.at_level("WARNING"):
        assert main(["collect", "--robot", str(tmp_path / "slow.yaml"), "--count", "8", "--workers", "1", "--quiet",
                     "-o", str(tmp_path / "slow.h5")]) == 0
    dataset = load_dataset(tmp_path / "slow.h5")
    sampling = dataset.metadata.record["task_space_sampling"]
    assert sampling["position_offset"][0] < 0.5 * fast_sampling.position_offset[0]
    assert sampling["orientation_max_angle"] < 0.5 * fast_sampling.orientation_max_angle
    assert "rejected" not in caplog.text
    caplog.clear()
    monkeypatch.setattr(plan, "speed_fitted_scale", lambda *args, **kwargs: 1.0)   # the UR-10's box as it was
    with caplog.at_level("WARNING"):
        assert main(["collect", "--robot", str(tmp_path / "slow.yaml"), "--count", "8", "--workers", "1", "--quiet",
                     "-o", str(tmp_path / "unscaled.h5")]) == 0
    assert "exceeds its limit 0.314 rad/s" in caplog.text


@pytest.mark.slow
def test_derived_tracking_plans_fit_a_large_arms_task_space_limits(tmp_path, caplog, monkeypatch):
    """The UR-10 with its joints three times farther apart (4.2 m of reach, as rtb-data's IRB 140 file is four times
    ABB's arm): the derived box of 0.1 x reach (0.43 m) asks for moves the quintic's task-space limits (the UR-10
    file's) cannot make in the plan's 1 s. The box shrinks until they can (the robot corpus's run 2 stopped there);
    with the box as it was, no final pose is found."""
    import re
    from stdm_drake.cli import main
    from stdm_drake.collection import plan
    from stdm_drake.collection.plan import derived_tracking_spec
    from stdm_drake.robots.robot import MODELS_DIR, load_robot
    text = (MODELS_DIR / "ur10.urdf").read_text()

    def tripled(joint):
        return re.sub(r'<origin xyz="([^"]*)"', lambda m: '<origin xyz="' + " ".join(
            f"{3 * float(value):.6g}" for value in m[1].split()) + '"', joint[0])

    (tmp_path / "ur10_large.urdf").write_text(re.sub(r"<joint .*?</joint>", tripled, text, flags=re.S))
    config = (MODELS_DIR / "ur10.yaml").read_text().partition("defaults:")[0]
    (tmp_path / "large.yaml").write_text(config.replace("name: ur10", "name: ur10_large").replace(
        "model: ur10.urdf", "model: ur10_large.urdf"))
    spec = derived_tracking_spec(load_robot(tmp_path / "large.yaml"))
    assert spec.sampling.position_offset[0] < 0.5 * 0.1 * 4.2
    assert main(["collect", "--robot", str(tmp_path / "large.yaml"), "--count", "4", "--workers", "1", "--quiet",
                 "-o", str(tmp_path / "large.h5")]) == 0
    monkeypatch.setattr(plan, "speed_fitted_scale", lambda *args, **kwargs: 1.0)   # the box as it was
    assert main(["collect", "--robot", str(tmp_path / "large.yaml"), "--count", "4", "--workers", "1", "--quiet",
                 "-o", str(tmp_path / "unscaled.h5")]) == 2


def test_shipped_files_are_named_from_any_folder_with_the_stdm_drake_prefix(tmp_path, monkeypatch, capsys):
    """`stdm-drake:controllers/NAME` (and `--option=stdm-drake:...`) name the files shipped with the
    package, wherever the command runs; an unknown one is a one-line error listing the folder."""
    from stdm_drake.cli import main
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.paths import CONTROLLERS_DIR
    monkeypatch.chdir(tmp_path)
    assert main(["collect", "--count", "1", "--workers", "1", "--quiet", "--controller",
                 "stdm-drake:controllers/pid_dither_sized.yaml", "--sensor=stdm-drake:controllers/sensor_ideal.yaml",
                 "-o", "ident.h5"]) == 0
    metadata = load_dataset(tmp_path / "ident.h5").metadata.record
    assert metadata["controller"]["kind"] == "pid" and len(metadata["controller"]["dither_std"]) == 6
    assert metadata["sensor"]["position_noise_std"] == 0.0
    assert main(["collect", "--count", "1", "--controller", "stdm-drake:controllers/pid_fast.yaml",
                 "-o", "other.h5"]) == 2
    err = capsys.readouterr().err
    assert "stdm-drake:controllers/pid_fast.yaml: no such shipped file; controllers/ holds" in err
    assert "pid_dither_sized.yaml" in err and len(err.strip().splitlines()) == 1
    assert (CONTROLLERS_DIR / "pid_dither_sized.yaml").is_file() and not (tmp_path / "other.h5").exists()


def test_period_acceleration_gives_the_next_velocity_where_damping_outpaces_the_period(tmp_path):
    """A joint damped faster than the 10 ms period (damping 40 N m s/rad on the two-link's light arm):
    v + T φ̄ (the period-mean acceleration) lands near the plant's next velocity, where v + T q̈ (the
    instantaneous nominal acceleration) overshoots by far; on the UR-10 the two agree to O(T). Its
    rates equal a finer central difference, a zero tangent has a zero rate, and its Jacobian (Ψ held
    constant) matches finite differences in v and τ."""
    from stdm_drake.dynamics.physics import NominalAcceleration, PeriodAcceleration, PlantModel
    urdf = two_link_urdf().replace('<axis xyz="0 1 0"/>', '<axis xyz="0 1 0"/><dynamics damping="40.0"/>')
    stiff = load_robot(write_robot(tmp_path, urdf, GOOD))
    q, v, tau = np.array([[0.3, -0.6], [0.1, 0.2]]), np.array([[0.5, -0.4], [-1.0, 0.3]]), np.array([[3.0, -1.0], [0.5, 2.0]])
    nominal, period = NominalAcceleration(stiff), PeriodAcceleration(stiff, 0.01)
    plant_next = PlantModel(0.01, robot=stiff).step(np.hstack([q, v]), tau)[:, 2:]
    euler_error = np.abs(v + 0.01 * nominal.values(q, v, tau) - plant_next).max()
    period_error = np.abs(v + 0.01 * period.values(q, v, tau) - plant_next).max()
    assert period_error < 0.05 * euler_error, (period_error, euler_error)
    assert period_error < 0.05 * np.abs(plant_next - v).max()       # the linearization over the period: 2 %
    # rates: a central difference 100x finer agrees; a zero tangent gives zero
    q_rate, v_rate, tau_rate = v, np.array([[2.0, -1.0], [0.5, 0.5]]), np.array([[10.0, 0.0], [0.0, -5.0]])
    rates = period.rates(q, v, tau, q_rate, v_rate, tau_rate)
    h = 1e-7
    finer = (period.values(q + h * q_rate, v + h * v_rate, tau + h * tau_rate)
             - period.values(q - h * q_rate, v - h * v_rate, tau - h * tau_rate)) / (2 * h)
    np.testing.assert_allclose(rates, finer, rtol=1e-4, atol=1e-6 * np.abs(finer).max())
    assert not period.rates(q, v, tau, 0 * q, 0 * v, 0 * tau).any()
    values, jacobian = period.values_and_jacobians(q, v, tau)
    np.testing.assert_array_equal(values, period.values(q, v, tau))
    numeric = np.empty_like(jacobian)
    z = np.hstack([q, v, tau])
    for j in range(6):
        up, down = z.copy(), z.copy()
        up[:, j] += 1e-6
        down[:, j] -= 1e-6
        numeric[:, :, j] = (period.values(up[:, :2], up[:, 2:4], up[:, 4:]) - period.values(down[:, :2], down[:, 2:4],
                                                                                             down[:, 4:])) / 2e-6
    # Ψ held constant: the v and τ columns agree to 1 % of the largest entry (Ψ moves with them only
    # through the inertia's slope); the q columns leave out dΨ/dq f, which is not small, and are not checked
    assert np.abs(jacobian[:, :, 2:] - numeric[:, :, 2:]).max() < 0.01 * np.abs(numeric).max()
    ur10_q, ur10_v = UR10.home[None], np.full((1, 6), 0.2)
    ur10_tau = np.array([[5.0, -60.0, -20.0, 1.0, 0.5, 0.1]])
    instantaneous = NominalAcceleration(UR10).values(ur10_q, ur10_v, ur10_tau)
    mean = PeriodAcceleration(UR10, 0.01).values(ur10_q, ur10_v, ur10_tau)
    assert np.abs(mean - instantaneous).max() < 0.05 * np.abs(instantaneous).max()


def test_derivative_training_warns_about_joints_damped_faster_than_the_period(tmp_path, capsys):
    """Damping 40 N m s/rad on the two-link's light joints stops them in a few ms (M_eff / d at home),
    under the 10 ms period: `train --model DD` says so in one warning line and names D; D trains quietly."""
    from stdm_drake.cli import main
    from stdm_drake.robots.plant import Dynamics
    urdf = two_link_urdf().replace('<axis xyz="0 1 0"/>', '<axis xyz="0 1 0"/><dynamics damping="40.0"/>')
    robot_path = write_robot(tmp_path, urdf, GOOD)
    robot = load_robot(robot_path)
    dynamics = Dynamics(robot)
    constants = dynamics.damping_time_constants()
    np.testing.assert_allclose(constants, dynamics.effective_inertia(robot.home) / 40.0)
    assert np.all(constants < 0.01)
    assert np.all(np.isinf(Dynamics(UR10).damping_time_constants()))                   # the UR-10 has no damping
    data = tmp_path / "data.h5"
    assert main(["collect", "--protocol", "excitation", "--robot", str(robot_path), "--count", "4", "--workers", "1",
                 "--quiet", "-o", str(data)]) == 0
    capsys.readouterr()
    for model, warned in (("DD", True), ("D", False)):
        assert main(["train", str(data), "--robot", str(robot_path), "--model", model, "--epochs", "2", "--train", "2",
                     "--val", "1", "--quiet", "-o", str(tmp_path / model)]) == 0
        err = capsys.readouterr().err
        assert ("stops these joints faster than the 10 ms period" in err and "train --model D" in err) == warned, err


@pytest.mark.slow
def test_stl_and_collada_visuals_render_in_chromium(tmp_path):
    """Meshcat shows an STL visual and a millimetre COLLADA visual (both through OBJ copies, colored by
    the URDF's <material>) in a real browser, at their size: without the conversion the STL link would
    be missing from the page, and the COLLADA box, its unit ignored by Meshcat, 1000 times too large."""
    from test_visualize import rendered_pixels
    from stdm_drake.robots.recorder import TrajectoryRecorder
    box_stl(tmp_path / "meshes" / "upper.stl", [0.2, 0.2, 0.3])
    box_dae_millimetres(tmp_path / "meshes" / "fore.dae", [200.0, 200.0, 300.0])
    blue_material = '<material name="blue"><color rgba="0.1 0.2 0.95 1"/></material>'
    urdf = two_link_urdf().replace(CYLINDER, "<visual><geometry></geometry></visual>", 1)   # the base: nothing
    urdf = urdf.replace("<visual><geometry></geometry></visual>", "", 1)
    urdf = urdf.replace(CYLINDER, f'<visual><origin xyz="0 0 0.15"/><geometry><mesh filename="meshes/upper.stl"/>'
                                  f'</geometry>{blue_material}</visual>', 1)
    red_material = '<material name="red"><color rgba="0.95 0.1 0.1 1"/></material>'
    urdf = urdf.replace(CYLINDER, '<visual><origin xyz="-0.1 -0.1 0"/><geometry><mesh filename="meshes/fore.dae"/>'
                                  f'</geometry>{red_material}</visual>', 1)
    recorder = TrajectoryRecorder(0.01, robot=load_robot(write_robot(tmp_path, urdf, GOOD)))
    recorder.add(np.tile([0.3, -0.6], (5, 1)))
    pixels = rendered_pixels(recorder, tmp_path)
    red, green, blue_channel = pixels[..., 0], pixels[..., 1], pixels[..., 2]
    assert np.count_nonzero((blue_channel > red + 0.25) & (blue_channel > green + 0.1)) > 100, "the STL link is missing"
    reddish = np.count_nonzero((red > blue_channel + 0.25) & (red > green + 0.25))
    assert 100 < reddish < 0.2 * red.size, f"the COLLADA link is missing or out of scale ({reddish} pixels)"


def test_a_robot_config_names_its_default_files_and_the_rest_is_derived(tmp_path):
    """`defaults:` in a robot config names the files commands use when not told otherwise (the UR-10
    preset names its five); a robot naming none gets derived settings; a named file that is missing is
    a one-line error."""
    from stdm_drake.closed_loop.mpc import MpcConfig, load_mpc_config, mpc_config_for
    from stdm_drake.collection.excitation import Excitation
    from stdm_drake.collection.collect import collection_request
    from stdm_drake.paths import CONTROLLERS_DIR, TRAJECTORIES_DIR
    assert UR10.default_file("tracking") == TRAJECTORIES_DIR / "tracking.yaml"
    assert UR10.default_file("mpc") == CONTROLLERS_DIR / "mpc.yaml"
    (tmp_path / "exc.yaml").write_text("num_steps: 7\namplitude_max: [2.0, 1.0]\noffset_max: [1.0]\n"
                                       "initial_position_lower: [-1.0, -1.5]\ninitial_position_upper: [1.0, 1.5]\n")
    (tmp_path / "mpc.yaml").write_text("horizon: 4\nposition_weight: [100.0]\nvelocity_weight: [1.0]\n"
                                       "effort_weight: [0.01]\n")
    named = load_robot(write_robot(tmp_path, two_link_urdf(), GOOD + "defaults: {excitation: exc.yaml, mpc: mpc.yaml}\n"))
    request = collection_request("excitation", count=1, robot=named, workers=1)
    assert request.excitation.num_steps == 7
    assert mpc_config_for(named) == load_mpc_config(tmp_path / "mpc.yaml")
    plain = load_robot(write_robot(tmp_path, two_link_urdf(), GOOD))
    assert collection_request("excitation", count=1, robot=plain, workers=1).excitation == Excitation.derived_for(plain)
    assert mpc_config_for(plain) == MpcConfig.derived_for(plain)
    missing = load_robot(write_robot(tmp_path, two_link_urdf(), GOOD + "defaults: {mpc: gone.yaml}\n"))
    with pytest.raises(InputError, match="robot two_link: defaults.mpc file not found"):
        mpc_config_for(missing)
