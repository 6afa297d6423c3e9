"""Plant effects (issue 22): each effect does to the dynamics what physics says, the affected plant
re-simulates its own data exactly while the nominal model does not, and the files are checked."""
import json
import pathlib

import numpy as np
import pytest

from presets import UR10
from stdm_drake.cli import main
from stdm_drake.data.dataset import load_dataset
from stdm_drake.errors import InputError
from stdm_drake.dynamics.physics import PlantModel
from stdm_drake.paths import MODELS_DIR
from stdm_drake.robots.effects import Payload, PlantEffects, load_plant_effects
from stdm_drake.robots.plant import Dynamics, PlantConfig, make_plant
from stdm_drake.robots.plant_effects_check import plant_effects_for

Q = np.array([0.3, -1.1, 1.4, -1.6, -1.4, 0.4])
V = np.array([0.4, -0.3, 0.5, 0.8, -0.6, 0.9])
TAU = np.array([5.0, -60.0, -20.0, 1.0, 0.5, -0.2])


def payload_gravity_torque(q, mass, center_of_mass):
    """Joint torques (n,) that hold a point mass at `center_of_mass` (tool frame) still: J_v^T m g, with J_v
    the Jacobian of that point on the nominal plant's tool frame."""
    from pydrake.multibody.tree import JacobianWrtVariable
    plant, _ = make_plant(PlantConfig.continuous(), robot=UR10)
    context = plant.CreateDefaultContext()
    plant.SetPositions(context, q)
    jacobian = plant.CalcJacobianTranslationalVelocity(context, JacobianWrtVariable.kV, plant.GetFrameByName("tool0"),
                                                       np.asarray(center_of_mass), plant.world_frame(),
                                                       plant.world_frame())
    return jacobian.T @ (mass * np.array([0.0, 0.0, 9.81]))


def test_each_effect_changes_the_dynamics_as_physics_says():
    nominal = Dynamics(UR10)
    M = nominal.mass_matrix(Q)
    base = nominal.acceleration(Q, V, TAU)
    viscous = np.array([21.0, 20.0, 10.0, 3.5, 2.5, 3.0])
    damped = Dynamics(UR10, PlantEffects(viscous_friction=viscous.tolist()))
    np.testing.assert_allclose(damped.acceleration(Q, V, TAU) - base, np.linalg.solve(M, -viscous * V), atol=1e-9)
    coulomb = Dynamics(UR10, PlantEffects(coulomb_friction=[12.0, 13.0, 5.0, 2.0, 2.7, 2.3],
                                          coulomb_velocity_scale=[0.05]))
    expected = np.linalg.solve(M, -np.array([12.0, 13.0, 5.0, 2.0, 2.7, 2.3]) * np.tanh(V / 0.05))
    np.testing.assert_allclose(coulomb.acceleration(Q, V, TAU) - base, expected, atol=1e-9)
    rotor = Dynamics(UR10, PlantEffects(rotor_inertia=[1e-4, 2e-4, 0.0, 0.0, 0.0, 3e-5], gear_ratio=[100.0]))
    np.testing.assert_allclose(rotor.mass_matrix(Q) - M, np.diag([1.0, 2.0, 0.0, 0.0, 0.0, 0.3]), atol=1e-12)
    loaded = Dynamics(UR10, PlantEffects(payload=Payload(mass=5.0, center_of_mass=[0.0, 0.0, 0.1])))
    np.testing.assert_allclose(loaded.gravity_torque(Q) - nominal.gravity_torque(Q),
                               payload_gravity_torque(Q, 5.0, [0.0, 0.0, 0.1]), atol=1e-9)
    heavier = Dynamics(UR10, PlantEffects(mass_scale={"wrist_3_link": 3.0}))
    link = nominal.plant.GetBodyByName("wrist_3_link")
    # two more copies of the link's mass at its centre of mass (wrist_3_link and tool0 are one rigid frame chain)
    nominal.plant.SetPositions(nominal.context, Q)
    com_in_tool = nominal.plant.CalcRelativeTransform(nominal.context, nominal.plant.GetFrameByName("tool0"),
                                                      link.body_frame()).multiply(link.default_com())
    np.testing.assert_allclose(heavier.gravity_torque(Q) - nominal.gravity_torque(Q),
                               payload_gravity_torque(Q, 2.0 * link.default_mass(), com_in_tool), atol=1e-9)


@pytest.fixture(scope="module")
def affected_dataset(tmp_path_factory):
    path = tmp_path_factory.mktemp("effects") / "affected.h5"
    assert main(["collect", "--protocol", "tracking", "--count", "2", "--seed", "4", "--workers", "1", "--quiet",
                 "--plant-effects", str(MODELS_DIR / "ur10_effects.yaml"), "-o", str(path)]) == 0
    return load_dataset(path)


def test_the_affected_plant_resimulates_its_data_exactly_and_the_nominal_model_does_not(affected_dataset):
    """x_{k+1} from (x_k, a_k): exact on the affected plant (its effects as the dataset records them),
    far off on the robot's description; the recorded accelerations are the affected plant's."""
    effects = affected_dataset.metadata.plant_effects
    assert effects == load_plant_effects(MODELS_DIR / "ur10_effects.yaml")
    true_plant = PlantModel(affected_dataset.sample_period, PlantConfig.discrete(0.001, effects=effects), robot=UR10)
    nominal = PlantModel(affected_dataset.sample_period, robot=UR10)
    assert (true_plant.name, nominal.name) == ("true-plant", "plant")
    traj = affected_dataset.trajectory(1)
    x = np.hstack([traj.q_true, traj.v_true])
    steps = range(0, len(traj.tau), 9)
    exact = max(np.abs(true_plant.step(x[k], traj.tau[k])[0] - x[k + 1]).max() for k in steps)
    nominal_error = max(np.abs(nominal.step(x[k], traj.tau[k])[0] - x[k + 1])[6:].max() for k in steps)
    assert exact == 0.0 and nominal_error > 0.5      # rad/s within one sample (the wrists, 1.3 here)
    truth = Dynamics(UR10, effects)
    np.testing.assert_allclose(traj.qdd[5], truth.acceleration(traj.q_true[5], traj.v_true[5], traj.tau[5]), atol=1e-9)


def test_the_true_plant_linearization_includes_the_effects(affected_dataset):
    """The affected plant's state Jacobian: what the effects change in it (A_affected - A_nominal) matches
    the same change in central differences of the two plants' steps to 10 %. Near rest (step 2) the Coulomb
    term's slope dominates the change (leaving it out of the AutoDiff dynamics is 60 % off); heavier links
    (mass scales as AutoDiff parameters) change it alone in the second case (100 % off without them)."""
    traj = affected_dataset.trajectory(0)
    nominal = PlantModel(affected_dataset.sample_period, robot=UR10)
    cases = [(affected_dataset.metadata.plant_effects, 2),
             (PlantEffects(mass_scale={"upper_arm_link": 2.0, "forearm_link": 2.0}), 20)]
    for effects, k in cases:
        affected = PlantModel(affected_dataset.sample_period, PlantConfig.discrete(0.001, effects=effects), robot=UR10)
        x, u = np.concatenate([traj.q_true[k], traj.v_true[k]]), traj.tau[k]

        def numeric(model):
            columns = []
            for i in range(12):
                dx = np.zeros(12)
                dx[i] = 1e-6
                columns.append((model.step(x + dx, u) - model.step(x - dx, u))[0] / 2e-6)
            return np.array(columns).T

        analytic = affected.jacobians(x[None], u[None])[0][0] - nominal.jacobians(x[None], u[None])[0][0]
        measured = numeric(affected) - numeric(nominal)
        assert np.linalg.norm(analytic - measured) < 0.1 * np.linalg.norm(measured), k


def test_dynamics_is_drakes_forward_dynamics_with_damping_and_friction():
    """Dynamics.acceleration (the recorded true accelerations) equals Drake's own forward dynamics of a
    continuous plant: with a description's joint damping (the acrobot's) and with every effect (the Coulomb
    friction fed as the applied generalized force)."""
    from stdm_drake.robots.effects import coulomb_torque
    from stdm_drake.robots.robot import load_robot
    acrobot = load_robot(MODELS_DIR / "acrobot.yaml")
    effects = load_plant_effects(MODELS_DIR / "ur10_effects.yaml")
    cases = [(acrobot, None, np.array([0.3, -0.5]), np.array([1.0, -2.0]), np.array([1.0])), (UR10, effects, Q, V, TAU)]
    for robot, plant_effects, q, v, tau in cases:
        config = PlantConfig.discrete(0.0, effects=plant_effects)
        plant, _ = make_plant(config, robot=robot)
        context = plant.CreateDefaultContext()
        config.set_parameters(plant, context)
        plant.SetPositionsAndVelocities(context, np.concatenate([q, v]))
        plant.get_actuation_input_port().FixValue(context, tau)
        if plant_effects is not None:
            n = robot.num_joints
            plant.get_applied_generalized_force_input_port().FixValue(context, coulomb_torque(
                v, *plant_effects.coulomb(n)))
        drake = plant.EvalTimeDerivatives(context).CopyToVector()[len(q):]
        np.testing.assert_allclose(Dynamics(robot, plant_effects).acceleration(q, v, tau), drake, rtol=1e-9, atol=1e-9)


def test_torque_noise_is_seeded_process_noise(tmp_path):
    """The same seed gives the same data; the noise reaches the plant (the recorded action alone no longer
    re-simulates the next state) and the recorded accelerations are those of the torque applied."""
    noisy = tmp_path / "noise.yaml"
    noisy.write_text("torque_noise_std: [1.0, 1.0, 0.5, 0.05, 0.02, 0.002]\n")
    paths = [tmp_path / f"{name}.h5" for name in ("a", "b")]
    for path in paths:
        assert main(["collect", "--protocol", "tracking", "--count", "1", "--seed", "2", "--workers", "1", "--quiet",
                     "--plant-effects", str(noisy), "-o", str(path)]) == 0
    first, second = (load_dataset(path).trajectory(0) for path in paths)
    assert all(np.array_equal(getattr(first, name), getattr(second, name)) for name in ("q", "v", "tau", "qdd"))
    model = PlantModel(0.01, robot=UR10)
    x = np.hstack([first.q_true, first.v_true])
    assert np.abs(model.step(x[3], first.tau[3])[0] - x[4]).max() > 1e-4
    recorded_torque = [Dynamics(UR10).acceleration(first.q_true[k], first.v_true[k], first.tau[k]) for k in range(5)]
    assert np.abs(np.array(recorded_torque) - first.qdd[:5]).max() > 1e-3   # qdd: the noisy torque's


@pytest.mark.slow
def test_closed_loops_meet_the_torque_noise_seeded_by_plan(affected_dataset):
    """With torque_noise_std the MPC's plant gets the controller's torque plus the held draws of
    default_rng(seed) (the same every run of that seed, so every model meets the same noise on a plan):
    each logged transition re-simulates exactly with them, and another seed gives another run."""
    from stdm_drake.closed_loop.mpc import MpcConfig, Reference, run_closed_loop
    std = np.array([2.0, 2.0, 1.0, 0.1, 0.05, 0.01])
    plant = PlantConfig.discrete(0.001, effects=PlantEffects(torque_noise_std=std.tolist()))
    traj = affected_dataset.trajectory(0)
    reference = Reference(q=traj.q_planned[:9], v=traj.v_planned[:9])
    model = PlantModel(0.01, robot=UR10)
    runs = [np.array(run_closed_loop(model, reference, MpcConfig(horizon=3), plant, robot=UR10, noise_seed=seed).state)
            for seed in (4, 4, 5)]
    quiet = np.array(run_closed_loop(model, reference, MpcConfig(horizon=3), PlantConfig.discrete(0.001), robot=UR10).state)
    assert np.array_equal(runs[0], runs[1]) and not np.allclose(runs[0], runs[2]) and not np.allclose(runs[0], quiet)
    log = run_closed_loop(model, reference, MpcConfig(horizon=3), plant, robot=UR10, noise_seed=4)
    noise = std * np.random.default_rng(4).standard_normal((len(reference.q), 6))
    states, torques = np.array(log.state), np.array(log.torque)
    stepped = model.step(states[:-1], torques[:-1] + noise[:len(torques) - 1])
    assert np.abs(stepped - states[1:]).max() < 1e-9


def test_effects_files_are_checked_against_the_robot(tmp_path):
    effects = load_plant_effects(MODELS_DIR / "ur10_effects.yaml")
    assert effects.source and plant_effects_for(effects, UR10, 0.001) is effects
    bad = {"viscous_friction: [1, 2]\n": "the robot has 6 joints",
           "coulomb_friction: [-1]\n": "non-negative",
           "gear_ratio: [100]\n": "gear_ratio needs rotor_inertia",
           "mass_scale: {elbow_link: 2}\n": "does not have: elbow_link",
           "mass_scale: {forearm_link: 0}\n": "> 0",
           "payload: {mass: 1, inertia: [1, 0, 0, 0, 0, 0]}\n": "not physically valid",
           "coulomb_friction: [40]\ncoulomb_velocity_scale: [0.001]\n": "is wider than the joint's speed range",
           "viscous_fiction: [1]\n": "malformed plant effects"}
    for number, (text, message) in enumerate(bad.items()):
        path = tmp_path / f"bad{number}.yaml"
        path.write_text(text)
        with pytest.raises(InputError, match=message) as caught:
            plant_effects_for(path, UR10, 0.001)
        assert "\n" not in str(caught.value) and str(path) in str(caught.value)


def test_the_panda_preset_loads_on_the_panda():
    """models/panda_effects.yaml on the Panda: its 1 kg payload hangs on the Panda's tool frame (J_v^T m g
    more holding torque, small beside the arm's limits) and its Coulomb friction acts on all 7 joints."""
    from pydrake.multibody.tree import JacobianWrtVariable

    from stdm_drake.robots.robot import load_robot
    panda = load_robot(MODELS_DIR / "panda.yaml")
    effects = plant_effects_for(MODELS_DIR / "panda_effects.yaml", panda, 0.001)
    assert len(effects.coulomb_friction) == panda.num_joints == 7 and effects.payload.mass == 1.0
    nominal, loaded = Dynamics(panda), Dynamics(panda, effects)
    q = panda.home
    nominal.plant.SetPositions(nominal.context, q)
    tool = nominal.plant.GetFrameByName(panda.tool_frame)
    jacobian = nominal.plant.CalcJacobianTranslationalVelocity(
        nominal.context, JacobianWrtVariable.kV, tool, np.array(effects.payload.center_of_mass),
        nominal.plant.world_frame(), nominal.plant.world_frame())
    payload_torque = loaded.gravity_torque(q) - nominal.gravity_torque(q)
    np.testing.assert_allclose(payload_torque, jacobian.T @ np.array([0.0, 0.0, 9.81]), atol=1e-9)
    assert 1.0 < np.abs(payload_torque).max() < 15
    v = np.linspace(-0.4, 0.5, 7)
    payload_only = Dynamics(panda, PlantEffects(payload=effects.payload))
    friction, scale = effects.coulomb(7)
    np.testing.assert_allclose(loaded.acceleration(q, v, np.zeros(7)) - payload_only.acceleration(q, v, np.zeros(7)),
                               np.linalg.solve(loaded.mass_matrix(q), -friction * np.tanh(v / scale)), atol=1e-9)


@pytest.mark.slow
def test_mpc_on_the_affected_plant_compares_the_nominal_and_the_true_plant_model(affected_dataset, tmp_path,
                                                                                capsys):
    """`mpc` on a dataset with effects: the closed loops run on the affected plant (it says so); the nominal
    plant model ("plant", what a user has) and the true plant ("true-plant") both track within the limits.
    (Which tracks better depends on the MPC cost: docs/reality_gap.md.)"""
    code = main(["mpc", str(affected_dataset.path), "--plans", "1", "--quiet", "-o", str(tmp_path / "mpc")])
    rows = {row["model"]: row for row in json.loads((tmp_path / "mpc" / "mpc.json").read_text())["summary"]}
    assert code == 0 and set(rows) == {"plant", "true-plant"}
    out, err = capsys.readouterr()
    assert "plant effects: as recorded in" in out and "plant effects" not in err   # quiet: in the table only
    for row in rows.values():
        assert row["q_mse_rad2"] < 1e-2 and row["limit_violations"] == 0
    assert rows["plant"]["q_mse_rad2"] != rows["true-plant"]["q_mse_rad2"]


def test_reproduce_collects_and_closes_the_loop_on_the_affected_plant(affected_dataset):
    """`reproduce --plant-effects`: every dataset's settings carry the effects; an MPC group runs the nominal
    plant ("plant") and the affected plant ("true-plant") on the affected plant."""
    from stdm_drake.closed_loop.comparison import held_out_references
    from stdm_drake.closed_loop.mpc import Reference
    from stdm_drake.experiments.reproduce import MpcGroup, _mpc_group, dataset_settings
    effects = affected_dataset.metadata.plant_effects
    settings = dataset_settings(UR10, effects)
    assert set(settings) == {"excitation", "local", "tracking", "identification"}
    assert all(entry["plant_effects"] is effects for entry in settings.values())
    assert settings["identification"]["controller"].name == "pid_dither_sized.yaml"   # sized for the affected plant
    assert dataset_settings(UR10)["identification"]["controller"].name == "pid_dither.yaml"
    references = [(i, Reference(q=r.q[:11], v=r.v[:11])) for i, r in held_out_references(affected_dataset, [], 1)]
    group = MpcGroup([("plant", None), ("true-plant", "true")], references, affected_dataset.sample_period, False,
                     UR10, PlantConfig.discrete(0.001, effects=effects))
    runs = _mpc_group(group)
    assert [run.model for run in runs] == ["plant", "true-plant"] and all(run.steps >= 10 for run in runs)


def test_the_affected_plant_tools_refuse_a_bad_effects_file_in_one_line(tmp_path, capsys):
    """`tools/study.py reality-gap` and `identification` (their shared command line)."""
    from tools_import import study
    bad = tmp_path / "bad.yaml"
    bad.write_text("viscous_friction: [1.0, 2.0]\n")
    for name in ("reality-gap", "identification"):
        assert study.main([name, "--allow-dirty", "--quick", "--plant-effects", str(bad), "-o", str(tmp_path / "out"),
                           "--data", str(tmp_path / "data")]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "bad.yaml" in err and not (tmp_path / "out").exists()


def test_each_model_gets_the_mpc_setting_it_tracks_best_with_inside_the_limits():
    """The reality gap's tuning rule: no limit violation on the validation plans first, then the lowest
    geometric-mean q MSE; if every setting violates, the fewest violations."""
    from tools_import import reality_gap
    choose_settings = reality_gap.choose_settings
    grid = ((1.0, 1.0), (1e-2, 0.0), (1e-4, 0.3))

    def runs(model, setting, mses, violations):
        return [dict(model=model, effort_scale=setting[0], observer_gain=setting[1], q_mse_rad2=mse,
                     limit_violations=v) for mse, v in zip(mses, violations)]
    found = (runs("DD seed 0", grid[0], [1e-4, 1e-4], [0, 0]) + runs("DD seed 0", grid[1], [1e-6, 1e-6], [0, 1])
             + runs("DD seed 0", grid[2], [1e-5, 4e-5], [0, 0])
             + runs("plant", grid[0], [1e-3, 1e-3], [2, 0]) + runs("plant", grid[1], [1e-2, 1e-2], [1, 0])
             + runs("plant", grid[2], [np.inf, 1.0], [3, 1]))
    assert choose_settings(found, grid) == {"DD seed 0": grid[2], "plant": grid[1]}


def test_tuning_plans_are_validation_plans_never_tracked_or_trained_on(affected_dataset):
    from stdm_drake.closed_loop.comparison import tuning_references

    class Split:   # a checkpoint trained on a 6-trajectory dataset
        def split_indices(self, dataset, part):
            return dict(train=[0, 1], val=[4, 2], test=[3, 5])[part]

    class Five:
        num_trajectories, protocol, path = 6, "tracking", "five.h5"
        trajectory = staticmethod(lambda index: affected_dataset.trajectory(index % 2))
    assert [index for index, _ in tuning_references(Five(), [Split()], 2, held_out=[3, 2])] == [4, 5]
    with pytest.raises(InputError, match="--tune 3: five.h5 has only 2 plans"):
        tuning_references(Five(), [Split()], 3, held_out=[3, 2])


def test_the_goal_verdict_follows_the_interval_and_the_violations():
    from tools_import import reality_gap
    verdict = reality_gap.verdict

    def summary(low, high, violations, ratio=3.0):
        row = dict(setting="tuned", model="DD", models=5, plans=20, limit_violations=violations,
                   nominal_over_model=dict(ratio=ratio, low=low, high=high, seeds=5))
        return [row, dict(row, model="D", nominal_over_model=dict(ratio=0.5, low=0.4, high=0.6, seeds=5)),
                dict(row, setting="shipped", nominal_over_model=dict(ratio=9.0, low=8.0, high=10.0, seeds=5))]
    assert verdict(summary(2.5, 3.5, 0))["met"] and verdict(summary(2.5, 3.5, 0))["best"] == "DD"
    assert not verdict(summary(2.5, 3.5, 1))["met"] and "left the limits" in verdict(summary(2.5, 3.5, 1))["text"]
    assert not verdict(summary(1.5, 5.0, 0))["met"] and "below 2" in verdict(summary(1.5, 5.0, 0))["text"]
    assert "nominal model tracks better" in verdict(summary(0.2, 0.4, 0, ratio=0.3))["text"]


def test_sized_gains_follow_the_plant_they_drive(capsys):
    """A PID sized by bandwidth on an affected plant uses that plant's inertia (reflected rotor inertia,
    payload): the UR-10 wrist 3's gain grows with its rotor inertia (0.4365 kg m^2 against ~3e-4 bare),
    enough to break its 2.3 N m of Coulomb friction loose within 0.01 rad; collect records the sized gains."""
    from stdm_drake.collection.collect import collection_request
    from stdm_drake.paths import CONTROLLERS_DIR
    from stdm_drake.robots.control import Pid, smallest_effective_inertia
    effects = load_plant_effects(MODELS_DIR / "ur10_effects.yaml")
    nominal = Pid(bandwidth=[25.0]).for_robot(UR10)
    affected = Pid(bandwidth=[25.0]).for_robot(UR10, effects)
    assert affected.kp[5] > 500 * nominal.kp[5] and affected.kp[5] * 0.01 > effects.coulomb_friction[5]
    assert np.allclose(affected.kp, smallest_effective_inertia(UR10, effects) * 25.0 ** 2)
    request = collection_request("tracking", count=1, robot=UR10, controller=CONTROLLERS_DIR / "pid_dither_sized.yaml",
                                 plant_effects=effects, workers=1)
    assert request.settings.controller.kp == affected.kp
    assert capsys.readouterr().err == ""
    for controller, stiffness in (("pid.yaml", "0.42 N m/rad needs 5.47 rad"), ("inverse_dynamics.yaml", "")):
        collection_request("tracking", count=1, robot=UR10, plant_effects=effects, workers=1,
                           controller=CONTROLLERS_DIR / controller)   # gains made for the description
        warning = capsys.readouterr().err
        assert warning.count("\n") == 1 and f"wrist_3_joint: stiffness {stiffness}" in warning
        assert "pid_dither_sized.yaml" in warning and "shoulder_pan_joint" not in warning and controller in warning


def test_the_per_effect_plants_are_the_effects_a_file_has():
    from tools_import import reality_gap
    effect_plants = reality_gap.effect_plants
    from stdm_drake.robots.robot import load_robot
    panda = load_plant_effects(MODELS_DIR / "panda_effects.yaml")
    plants = effect_plants(panda, load_robot(MODELS_DIR / "panda.yaml"))
    assert list(plants) == ["friction", "payload", "all"] and plants["all"] is panda
    assert plants["payload"].payload == panda.payload and not plants["payload"].coulomb_friction
    ur10 = effect_plants(load_plant_effects(MODELS_DIR / "ur10_effects.yaml"), UR10)
    assert list(ur10) == ["friction", "rotor inertia", "payload", "all"]
    assert ur10["friction"].coulomb_velocity_scale[5] > 1.0   # wrist 3 without its rotor: made stable
    friction_only = PlantEffects(coulomb_friction=[1.0], rotor_inertia=[0.0], mass_scale={"forearm_link": 1.0})
    assert list(effect_plants(friction_only, UR10)) == ["friction", "all"]


@pytest.mark.slow
def test_the_reality_gap_reuses_models_only_of_the_same_data_and_settings(tmp_path):
    from tools_import import reality_gap
    dataset, train = reality_gap.dataset, reality_gap.train
    data = dataset(tmp_path, "closed_loop", load_plant_effects(MODELS_DIR / "ur10_effects.yaml"), 12, 0, UR10, 1)
    folder = str(tmp_path / "runs" / "D")
    first = train(str(data.path), "D", (1, 1, 1), 1, 1, folder)
    checkpoint = pathlib.Path(first) / "seed0" / "checkpoint.pt"
    stamp = checkpoint.stat().st_mtime_ns
    assert train(str(data.path), "D", (1, 1, 1), 1, 1, folder) == first and checkpoint.stat().st_mtime_ns == stamp
    other = train(str(data.path), "D", (1, 1, 1), 1, 2, folder)   # other epochs: another model
    assert other != first and (pathlib.Path(other) / "seed0" / "checkpoint.pt").exists()
    (pathlib.Path(first) / "summary.json").unlink()      # as if interrupted (a checkpoint, no summary): resumed
    assert train(str(data.path), "D", (1, 1, 1), 1, 1, folder) == first
    assert (pathlib.Path(first) / "summary.json").exists()
    assert data.sha256[:12] in first and data.metadata.section("controller")["kp"][5] > 100   # sized for the affected wrist


@pytest.mark.slow
def test_a_model_of_the_affected_plant_records_it_and_view_shows_the_nominal_model_beside_it(affected_dataset,
                                                                                            tmp_path, capsys):
    from stdm_drake.learning.checkpoint import load_checkpoint
    assert main(["train", str(affected_dataset.path), "--model", "D", "--epochs", "2", "--train", "1", "--val", "1",
                 "--per-group", "off", "--quiet", "-o", str(tmp_path / "run")]) == 0
    checkpoint = tmp_path / "run" / "seed0" / "checkpoint.pt"
    assert load_checkpoint(checkpoint).metadata.plant_effects == affected_dataset.metadata.plant_effects.record()
    capsys.readouterr()
    assert main(["view", str(checkpoint), str(affected_dataset.path), "--index", "1", "--html",
                 str(tmp_path / "view.html")]) == 0
    out = capsys.readouterr().out
    assert "plant effects of the data" in out and ": nominal plant " in out


@pytest.mark.slow
def test_mpc_tunes_each_model_on_validation_plans_before_tracking_the_held_out_ones(tmp_path, capsys):
    """`mpc --tune 1`: each model's setting is chosen on a validation plan of its checkpoint (never the
    tracked one), said in one line per model, recorded in mpc.json, and the tracked plans run with it."""
    data = tmp_path / "three.h5"
    assert main(["collect", "--protocol", "tracking", "--count", "3", "--seed", "5", "--workers", "1", "--quiet",
                 "--plant-effects", str(MODELS_DIR / "ur10_effects.yaml"), "-o", str(data)]) == 0
    assert main(["train", str(data), "--model", "D", "--epochs", "2", "--train", "1", "--val", "1", "--test", "1",
                 "--per-group", "off", "--quiet", "-o", str(tmp_path / "run")]) == 0
    capsys.readouterr()
    code = main(["mpc", str(data), "--no-plant", "--model", f"D={tmp_path / 'run' / 'seed0' / 'checkpoint.pt'}",
                 "--plans", "1", "--tune", "1", "--quiet", "-o", str(tmp_path / "mpc")])
    assert code in (0, 2)   # 2: a 2-epoch model may leave the limits
    from stdm_drake.learning.checkpoint import load_checkpoint
    split = load_checkpoint(tmp_path / "run" / "seed0" / "checkpoint.pt").split_indices(load_dataset(data), "val")
    record = json.loads((tmp_path / "mpc" / "mpc.json").read_text())
    chosen = tuple(record["tuning"]["chosen"]["D"])
    assert record["tuning"]["plans"] == split and record["runs"][0]["trajectory"] not in split
    assert len(record["tuning"]["runs"]) == 9 and chosen in {(r["effort_scale"], r["observer_gain"])
                                                             for r in record["tuning"]["runs"]}
    out, err = capsys.readouterr()
    assert "MPC setting of D" not in err   # quiet: the chosen settings are in the table
    assert f"D effort x {chosen[0]:g}, observer gain {chosen[1]:g}" in out
    assert "MPC settings chosen on the tuning plans (indices" in (tmp_path / "mpc" / "mpc.md").read_text()


def test_a_dataset_of_another_plant_is_not_reused():
    """reproduce reuses a dataset whose record agrees field by field; a plant with effects and one without
    never agree, whatever else they share."""
    from stdm_drake.experiments.datasets import _agrees
    nominal = {"plant": {"time_step": 0.001, "self_collision": True}}
    affected = {"plant": {"time_step": 0.001, "self_collision": True,
                          "effects": PlantEffects(viscous_friction=[1.0]).record()}}
    assert _agrees(nominal, dict(nominal)) and _agrees(affected, json.loads(json.dumps(affected)))
    assert not _agrees(nominal, affected) and not _agrees(affected, nominal)


def test_each_tuning_bar_names_its_setting(monkeypatch):
    """mpc --tune runs one bar per setting of the grid: each titled with the setting, not nine bars all "mpc"."""
    import stdm_drake.closed_loop.comparison as comparison
    from stdm_drake.closed_loop.mpc import load_mpc_config
    from stdm_drake.closed_loop.tuning import MPC_GRID, tune
    titles = []
    monkeypatch.setattr(comparison, "compare_controllers", lambda *arguments, title, **options: titles.append(title) or [])
    tune([], [], load_mpc_config(), None, robot=None)
    assert len(titles) == len(MPC_GRID) == len(set(titles))
    assert titles[0] == f"mpc --tune 1/{len(MPC_GRID)}: effort x {MPC_GRID[0][0]:g}, gain {MPC_GRID[0][1]:g}"


def test_a_slow_control_step_gets_its_rate_not_zero_hz():
    """A p95 of 195.5 ms allows 5.1 Hz, not "real time at 0 Hz" (issue 57: the sampling recipe printed that); one of
    50.91 ms allows 19 Hz, not "10 Hz" (newcomer pass 2): two digits at least, rounded down."""
    from stdm_drake.closed_loop.comparison import real_time_lines
    rows = [dict(model="D", solve_ms_mean=154.8, solve_ms_p95=195.5), dict(model="P", solve_ms_mean=1.0, solve_ms_p95=1.2),
            dict(model="S", solve_ms_mean=31.6, solve_ms_p95=50.91), dict(model="T", solve_ms_mean=20.0, solve_ms_p95=10.0)]
    slow, fast, sampler, exact = real_time_lines(rows, 0.01)
    assert slow.endswith("real time at 5.1 Hz by its p95") and "not real time (p95 19.6x the period)" in slow
    assert fast.endswith("real time at 830 Hz by its p95")
    assert sampler.endswith("real time at 19 Hz by its p95") and exact.endswith("real time at 100 Hz by its p95")


def test_values_held_out_run_31_found_refused_are_accepted_as_documented():
    """A rigid transmission (`transmission_stiffness: [0]`, documented as rigid) loads without a rotor inertia (it was
    refused as needing one); a rotor inertia below 1e-12 kg m² with no gear ratio, as a fit leaves one, loads and adds
    nothing (documented beside the gear-ratio rule, which refuses only a gear ratio that makes a motor vanish)."""
    from stdm_drake.robots.plant_effects_check import check_plant_effects
    for effects in (PlantEffects(transmission_stiffness=[0.0]), PlantEffects(rotor_inertia=[1e-300])):
        effects.validate()
        check_plant_effects(effects, UR10, 0.001)
    with pytest.raises(InputError, match="transmission_damping needs transmission_stiffness"):
        PlantEffects(transmission_stiffness=[0.0], transmission_damping=[5.0]).validate()


@pytest.mark.parametrize("inertia, payload, refused", [
    ([0.0] * 6, None, True),                                  # a point mass on wrist 3's axis
    ([0.01, 0.01, 0.0, 0.0, 0.0, 0.0], None, True),           # a rod along it
    ([0.01, 0.01, 0.0, 0.0, 0.0, 0.0], Payload(mass=1.0, center_of_mass=[0.05, 0.0, 0.1]), False),   # + a payload off it
    ([0.01, 0.01, 0.0, 0.0, 0.0, 0.0], Payload(mass=1.0), True),   # + a payload on it
])
def test_the_affected_plants_mass_matrix_is_checked_before_any_work(inertia, payload, refused):
    """Held-out run 32: a link_inertia that leaves wrist 3 turning nothing about its axis ended in "Singular matrix",
    a sized gain refused, or Drake's "not positive-definite" blamed on a heavy body. The affected plant's M(home) is
    now checked as a description's is; a payload off the axis gives the joint its inertia back, and loads."""
    from stdm_drake.robots.effects import RigidInertia
    from stdm_drake.robots.plant_effects_check import check_plant_effects
    effects = PlantEffects(link_inertia={"wrist_3_link": RigidInertia(mass=0.2, center_of_mass=[0.0, 0.0, 0.05],
                                                                      inertia=inertia)},
                           **({} if payload is None else {"payload": payload}))
    effects.validate()
    if not refused:
        check_plant_effects(effects, UR10, 0.001)
        return
    with pytest.raises(InputError) as error:
        check_plant_effects(effects, UR10, 0.001)
    message = str(error.value)
    assert message.startswith("plant effects on robot ur10: arm joint 'wrist_3_joint' moves no inertia about its axis "
                              "at home (the mass matrix M(home) is singular, smallest eigenvalue ")
    assert message.endswith("the links it moves need a mass, and for a revolute joint an inertia about the axis or a "
                            "centre of mass off it") and "\n" not in message


@pytest.mark.slow
def test_mpc_on_a_plant_no_torque_holds_names_gravity(tracking_dataset, tmp_path, capsys):
    """Held-out run 35: with a 200 kg payload every loop left the limits (the true plant's too) and each line named
    only its model; `collect` names gravity beyond the effort limit for the same plant. Each failure line of `mpc`
    now ends with it, on stderr alone under --quiet."""
    for line in mpc_failure_lines(tracking_dataset, tmp_path, capsys, "payload: {mass: 200.0}\n"):
        assert "; gravity pulls elbow_joint with up to " in line and "N m on the plans, beyond its effort limit 150 N m: " \
               "no torque holds the arm" in line, line


@pytest.mark.slow
def test_mpc_on_elastic_transmissions_names_the_springs(tracking_dataset, tmp_path, capsys):
    """Held-out run 37: undamped springs of 20,000 N m/rad behind motors of 0.5 kg m² on both shoulders; every loop
    left the limits and each line named only its model, where `collect` names the springs. Each line now names them
    with the least damped spring's ring and damping ratio, as `collect` does."""
    springs = "transmission_stiffness: [20000, 20000, 0, 0, 0, 0]\nrotor_inertia: [0.5, 0.5, 0, 0, 0, 0]\n"
    for line in mpc_failure_lines(tracking_dataset, tmp_path, capsys, springs):
        assert line.endswith("; the loops ran with the plant effects' transmission springs on shoulder_pan_joint, "
                             "shoulder_lift_joint (shoulder_pan_joint's motor rings at 31.8 Hz with damping ratio 0 "
                             "(transmission_damping); a ring shakes the joints it carries)"), line


def mpc_failure_lines(dataset, tmp_path, capsys, effects_text: str) -> list[str]:
    """`mpc --quiet` on one plan of `dataset` with the plant effects `effects_text` (YAML): its stderr lines, each
    asserted a model's failure line, with exit status 2."""
    effects = tmp_path / "effects.yaml"
    effects.write_text(effects_text)
    capsys.readouterr()
    code = main(["mpc", str(dataset), "--plans", "1", "--plant-effects", str(effects), "--quiet",
                 "-o", str(tmp_path / "mpc")])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and lines and all(line.startswith("stdm-drake mpc: error: model ") for line in lines), lines
    return lines


def test_a_learned_models_failure_line_names_the_model_where_the_plant_model_held_the_limits():
    """Held-out run 38: D left the limits on 195 of 200 steps and its line named nothing, while the table's plant row
    held them under the same MPC on the same plans. The line now names the model as the cause."""
    from types import SimpleNamespace
    from stdm_drake.closed_loop.comparison import closed_loop_failures
    from stdm_drake.closed_loop.failure_causes import model_notes
    results = [SimpleNamespace(model="plant", limit_violations=0, fallbacks=0, steps=100),
               SimpleNamespace(model="D", limit_violations=95, fallbacks=0, steps=100)]
    models = [dict(name="plant", kind="plant"), dict(name="D", kind="D")]
    lines = closed_loop_failures(results, note="the loops ran with X", model_notes=model_notes(results, models))
    assert lines == ["model D left the robot's joint limits on 95 of 100 steps (1 of 1 plans); the MPC with the plant "
                     "model held the limits on the same plans, so this model is not accurate enough for the "
                     "closed loop (train's one-step verdict is no closed-loop one); the loops ran with X"]
    results[0].limit_violations = 3   # (the plant model left them too: the model is not singled out)
    assert model_notes(results, models) == {}
