"""The compiled control step (closed_loop/compiled.py, core/) against the numpy reference it replaces:
every model kind's step and linearization, the real-time iteration's torques on recorded states in every
constraint mode, the settings that choose it, and what it says about the models it does not cover."""
import dataclasses

import numpy as np
import pytest

from presets import UR10
from test_export import random_rows, synthetic_checkpoint
from stdm_drake.dynamics import compiled_core
from stdm_drake.closed_loop.constraints import Constraints, CondensedQp
from stdm_drake.closed_loop.mpc import load_mpc_config, run_closed_loop
from stdm_drake.closed_loop.rti import Rti, RtiSolver
from stdm_drake.dynamics.physics import PlantModel
from stdm_drake.errors import InputError
from stdm_drake.learning.learned_model import LearnedModel
from stdm_drake.learning.structure import DEFAULT, PAPER, ModelStructure
from stdm_drake.robots.plant import JointLimits

EFFORT = np.array([330.0, 330.0, 150.0, 54.0, 54.0, 54.0])
# tight limits around the states the tests visit, so that the QP's rows bind on most steps
TIGHT = JointLimits(np.full(6, -1.0), np.full(6, 1.0), np.full(6, 1.5), EFFORT)

STRUCTURES = [  # (structure, model type, activation): every structure the compiled step covers, every activation
    (DEFAULT, "D", "swish"), (PAPER, "PE", "tanh"), (ModelStructure("state", "nominal_acceleration"), "DE", "gelu"),
    (ModelStructure("velocity", "raw"), "P", "elu"), (PAPER, "D", "sigmoid"), (DEFAULT, "D", "softplus"),
    (PAPER, "D", "relu"), (PAPER, "D", "leaky_relu"), (DEFAULT, "DE", "selu")]


@pytest.fixture(scope="module")
def plant_model():
    return PlantModel(0.01, robot=UR10, integrator="rk4")


@pytest.fixture(scope="module")
def affected_plant_model():
    """The plant with the shipped effects file's friction (viscous and Coulomb), rotor inertia and payload."""
    from stdm_drake.paths import MODELS_DIR
    from stdm_drake.robots.plant import PlantConfig
    from stdm_drake.robots.plant_effects_check import plant_effects_for
    config = PlantConfig.discrete(0.001, effects=plant_effects_for(MODELS_DIR / "ur10_effects.yaml", UR10, 0.001))
    model = PlantModel(0.01, config, robot=UR10, integrator="rk4")
    assert model.dynamics.coulomb is not None and np.any(model.dynamics.damping > 0)
    return model


@pytest.mark.parametrize("structure, kind, activation", STRUCTURES)
def test_the_compiled_networks_step_and_linearization_are_the_numpy_models(tmp_path, structure, kind, activation):
    """float32 networks: the next states to 1e-7 of their scale, the Jacobians to 1e-6 (float32's precision, the
    sums in another order: reverse mode here, forward mode in numpy)."""
    model = LearnedModel(synthetic_checkpoint(tmp_path / "model.pt", structure, model_type=kind, activation=activation),
                         robot=UR10)
    core, x, a, expected = linearizations_agree(model, 3, 1e-7, UR10.num_joints)
    for row in range(3):
        np.testing.assert_allclose(core.step(x[row], a[row]), model.step_single(x[row], a[row]), rtol=0,
                                   atol=1e-7 * np.abs(expected).max())


def linearizations_agree(model, seed: int, tolerance: float, joints: int):
    """The compiled core of `model` (of an arm of `joints`) linearizes 20 random rows (seed) as the numpy model does:
    next states to `tolerance` of their scale, Jacobians to 10 x `tolerance` of theirs; (core, x, a, next states)."""
    core, why_not = compiled_core.compiled_model(model)
    assert core is not None, why_not
    x, a = random_rows(20, seed, joints)
    expected, A, B = model.linearize(x, a)
    following, core_A, core_B = core.linearize(x, a)
    np.testing.assert_allclose(following, expected, rtol=0, atol=tolerance * np.abs(expected).max())
    np.testing.assert_allclose(core_A.reshape(A.shape), A, rtol=0, atol=10 * tolerance * np.abs(A).max())
    np.testing.assert_allclose(core_B.reshape(B.shape), B, rtol=0, atol=10 * tolerance * np.abs(B).max())
    return core, x, a, expected


@pytest.mark.parametrize("width, structure, kind, arm", [(29, DEFAULT, "D", "ur10"), (100, PAPER, "PE", "ur10"),
                                                       (3, PAPER, "D", "ur10"), (13, DEFAULT, "D", "panda")])
def test_the_compiled_linearization_holds_at_every_width(tmp_path, width, structure, kind, arm):
    """The hidden layers' products in register blocks of 16, 8 and 4 columns and one by one (core/small_gemm.hpp):
    29 = 16 + 8 + 4 + 1 columns, the default width of 100 (6 x 16 + 4), 3 (one by one only); the horizon's 20 input
    rows (the forward pass: 3 blocks of 6 rows and 2 rows left) times the outputs, 120 or 240 rows for the UR-10,
    140 for the Panda's 7 velocities (23 blocks and 2 rows left, each scaled by its slopes)."""
    from stdm_drake.paths import MODELS_DIR
    from stdm_drake.robots.robot import load_robot
    robot = UR10 if arm == "ur10" else load_robot(MODELS_DIR / "panda.yaml")
    model = LearnedModel(synthetic_checkpoint(tmp_path / "model.pt", structure, model_type=kind, hidden_width=width,
                                              robot=robot), robot=robot)
    core, x, a, expected = linearizations_agree(model, 5, 1e-6, robot.num_joints)   # (width 100: more float32 terms)
    np.testing.assert_allclose(core.step_rows(x, a), expected, rtol=0, atol=1e-6 * np.abs(expected).max())


@pytest.mark.parametrize("which", ["plant_model", "affected_plant_model"])
def test_the_compiled_plant_model_is_the_numpy_plant_model(request, which):
    """The plant as model (RK4 over Pinocchio's ABA and its analytic derivatives; damping and Coulomb friction in
    the affected plant): equal to rounding."""
    model = request.getfixturevalue(which)
    core, _ = compiled_core.compiled_model(model)
    x, a = random_rows(20, 4)
    expected, A, B = model.linearize(x, a)
    following, core_A, core_B = core.linearize(x, a)
    np.testing.assert_allclose(following, expected, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(core_A.reshape(A.shape), A, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(core_B.reshape(B.shape), B, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(core.step(x[0], a[0]), model.step_single(x[0], a[0]), rtol=1e-10, atol=1e-10)


def recorded_comparison(model, mode: str, iterations: int, steps: int = 12, seed: int = 0, limits=TIGHT,
                        start=(0.7, 0.95), target=0.9, jacobian_refresh="all"):
    """Both implementations on the same recorded inputs: the states of a loop that the numpy reference closes
    (the plant stepped by its torque, with noise, near tight limits), each step started from the reference's own
    warm start (each solver keeping its own Jacobians under a partial `jacobian_refresh`). Returns [(numpy result,
    compiled result, whether either QP fell back to the box)] per step."""
    base = load_mpc_config()
    configs = [dataclasses.replace(base, optimizer=Rti(iterations=iterations, implementation=implementation,
                                                       jacobian_refresh=jacobian_refresh),
                                   constraints=Constraints(mode=mode)) for implementation in ("numpy", "compiled")]
    reference_solver, compiled_solver = (config.solver(model, limits) for config in configs)
    assert isinstance(reference_solver, RtiSolver) and compiled_solver.implementation == "compiled"
    fallbacks = []
    original = CondensedQp._box_only

    def counted(self, *arguments):
        fallbacks.append(1)
        return original(self, *arguments)

    plant = PlantModel(0.01, robot=UR10, integrator="rk4")
    rng = np.random.default_rng(seed)
    horizon = base.horizon
    x = np.concatenate([rng.uniform(*start, 6), rng.uniform(0.5, 1.4, 6)])
    warm, nodes, rows = np.zeros((horizon, 6)), None, []
    CondensedQp._box_only = counted
    try:
        for step in range(steps):
            reference = np.tile(np.concatenate([np.full(6, target + 0.01 * step), np.zeros(6)]), (horizon + 1, 1))
            before = (len(fallbacks), compiled_solver._core.unsettled)
            offset = 1e-3 * np.ones(12)
            expected = reference_solver.solve(x, warm, reference, np.zeros((horizon, 6)), offset, x_init=nodes)
            result = compiled_solver.solve(x, warm, reference, np.zeros((horizon, 6)), offset, x_init=nodes)
            fell_back = len(fallbacks) > before[0] or compiled_solver._core.unsettled > before[1]
            rows.append((expected, result, fell_back))
            warm, nodes = np.vstack([expected.u[1:], expected.u[-1:]]), np.vstack([expected.x[1:], expected.x[-1:]])
            x = plant.step_single(x, expected.u[0]) + rng.normal(0.0, 0.01, 12)
    finally:
        CondensedQp._box_only = original
    return rows


@pytest.mark.parametrize("mode", ["soft", "hard", "off"])
@pytest.mark.parametrize("iterations", [1, 2])
def test_with_the_plant_as_model_the_compiled_torques_are_the_references(plant_model, mode, iterations):
    """Double precision throughout: the torques to 1e-9 of the effort limit on every recorded step, limits active
    on most of them (the QP's rows and the torque box), the same cost, constraint flag and slack. (Hard mode with
    two iterations is the exception measured: DAQP keeps hard rows to its own feasibility tolerance, the dual
    method here to round-off, and the second iteration carries the difference: up to 2e-4 of the torque.)"""
    rows = recorded_comparison(plant_model, mode, iterations)
    tolerance = 1e-9 if (mode, iterations) != ("hard", 2) else 1e-3
    compared = [(a, b) for a, b, fell_back in rows if not fell_back]
    assert len(compared) >= len(rows) // 2
    for expected, result in compared:
        np.testing.assert_allclose(result.u, expected.u, rtol=0, atol=tolerance * EFFORT.max())
        np.testing.assert_allclose(result.x, expected.x, rtol=0, atol=tolerance * 10)
        assert result.constraint_active == expected.constraint_active
        assert result.slack == pytest.approx(expected.slack, abs=1e-7)
        assert result.cost == pytest.approx(expected.cost, rel=max(tolerance, 1e-9))
    if mode != "off":
        assert sum(result.constraint_active for _, result in compared) >= len(compared) // 2


def test_a_closed_loop_with_the_compiled_step_is_the_numpy_loop(plant_model):
    """The whole MPC in a Drake diagram (observer, warm start, limits on) with the plant as model: the same torques
    on every control step, and the log says which step ran."""
    from test_mpc import quintic_reference
    reference = quintic_reference(30)
    config = load_mpc_config()
    assert config.optimizer.implementation == "compiled"
    numpy_config = dataclasses.replace(config, optimizer=dataclasses.replace(config.optimizer, implementation="numpy"))
    compiled_log = run_closed_loop(plant_model, reference, config, robot=UR10)
    numpy_log = run_closed_loop(plant_model, reference, numpy_config, robot=UR10)
    np.testing.assert_allclose(np.array(compiled_log.torque), np.array(numpy_log.torque), rtol=0, atol=1e-9 * EFFORT.max())
    assert compiled_log.implementation == "compiled" and numpy_log.implementation == "numpy"


def test_the_one_call_control_step_is_the_numpy_step_with_its_memory_and_fallback(plant_model):
    """policy.MpcStep over the compiled solver runs each step in one C++ call (`_core.ControlStep`); on recorded
    states (a non-finite measurement among them: the gravity fallback) its torques, statuses and every part of
    the memory it carries are the numpy step's."""
    from test_mpc import quintic_reference
    from stdm_drake.closed_loop.policy import MpcStep
    from stdm_drake.robots.plant import Dynamics, joint_limits
    reference = quintic_reference(30)
    config = load_mpc_config()
    dynamics = Dynamics(UR10)
    limits = joint_limits(dynamics.plant)
    steps = {}
    for implementation in ("compiled", "numpy"):
        chosen = dataclasses.replace(config, optimizer=dataclasses.replace(config.optimizer,
                                                                           implementation=implementation))
        solver = chosen.solver(plant_model, limits, UR10.joint_names)
        steps[implementation] = MpcStep(solver, reference, dynamics.gravity_torque, config.horizon,
                                        config.disturbance_gain, limits.effort, True)
    assert steps["compiled"].compiled is not None and steps["numpy"].compiled is None
    memories = {name: step.first_memory() for name, step in steps.items()}
    x = np.concatenate([reference.q[0] + 0.01, reference.v[0]])
    fallbacks = 0
    for k in range(12):
        measured = x.copy()
        if k == 6:
            measured[2] = np.nan          # a lost measurement
        outcome = {}
        for name, step in steps.items():
            torque, memories[name], status = step(k, measured, memories[name])
            outcome[name] = (torque, status)
        (torque, status), (expected, expected_status) = outcome["compiled"], outcome["numpy"]
        np.testing.assert_allclose(torque, expected, rtol=0, atol=1e-9 * EFFORT.max())
        assert status.fallback == expected_status.fallback
        assert status.constraint_active == expected_status.constraint_active
        fallbacks += status.fallback
        for part in ("predicted", "disturbance", "plan", "nodes"):
            np.testing.assert_allclose(getattr(memories["compiled"], part), getattr(memories["numpy"], part),
                                       rtol=0, atol=1e-7, err_msg=f"{part} at step {k}")
        x = plant_model.step_single(x, expected)
    assert fallbacks == 1


def test_a_model_the_compiled_step_does_not_cover_runs_numpy_and_says_why(tmp_path):
    structure = ModelStructure("velocity", "plant_step", plant_integrator="rk4")
    grey_box = LearnedModel(synthetic_checkpoint(tmp_path / "grey.pt", structure), robot=UR10)
    solver = load_mpc_config().solver(grey_box, TIGHT)
    assert isinstance(solver, RtiSolver)
    assert solver.implementation == "numpy (the compiled step does not cover plant-step inputs)"


def test_the_settings_choose_the_implementation_and_refuse_others_in_one_line(plant_model):
    assert Rti().implementation == "compiled"
    numpy_solver = dataclasses.replace(load_mpc_config(), optimizer=Rti(implementation="numpy")).solver(plant_model, TIGHT)
    assert type(numpy_solver) is RtiSolver and numpy_solver.implementation == "numpy"
    with pytest.raises(InputError, match="implementation must be one of compiled, numpy, got 'fast'"):
        Rti(implementation="fast").validate()


def test_a_missing_compiled_step_is_one_line_naming_the_fix(monkeypatch):
    """No silent fall-back to the numpy step where the extension is not built: one line saying how to get it or
    choose numpy."""
    import builtins
    real_import = builtins.__import__

    def without_core(name, globals=None, locals=None, fromlist=(), level=0):
        if fromlist and "_core" in fromlist:
            raise ImportError("cannot import name '_core'")
        return real_import(name, globals, locals, fromlist, level)

    monkeypatch.setattr(builtins, "__import__", without_core)
    with pytest.raises(InputError) as error:
        compiled_core.core_module()
    message = str(error.value)
    assert "\n" not in message and "pip install" in message and "implementation: numpy" in message


SLACK_ROUNDING = 1e-12   # rad or rad/s: a state row's slack below this is the QP's rounding, not a crossing


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["D", "PE"])
def test_trained_networks_compiled_torques_are_the_references_on_recorded_states(tmp_path, tracking_dataset, kind):
    """Networks trained on tracking data (the default D; the paper's PE, 5 members), on the states the dataset
    recorded (a test trajectory, tracking its own recorded states as the plan), position limits 0.01 rad inside
    the trajectory's range (so that the QP's rows bind where it turns, with slack), one iteration: the torques agree to 1e-5 of
    the effort limit (float32 networks: their Jacobians agree to 2e-7, and the QP's Hessian amplifies that), on
    every step where neither QP fell back to the torque box. The multi-level iteration (`jacobian_refresh: 5`,
    each solver keeping its own Jacobians) on the same states with the numpy reference over the compiled network's
    own steps and Jacobians (`CoreAsModel`: the same float32 numbers, so that only the algorithm is compared; end
    to end, its inexact steps amplify float32's differences beyond what a tolerance can state): to 1e-9 of the
    effort limit on every step where neither QP fell back."""
    from test_multilevel_iteration import CoreAsModel
    from stdm_drake.dynamics.compiled_core import compiled_model
    from stdm_drake.cli import main
    from stdm_drake.data.dataset import load_dataset
    options = [] if kind == "D" else ["--predicts", "state", "--inputs", "raw", "--ensemble-size", "5"]
    assert main(["train", str(tracking_dataset), "--model", kind, *options, "--epochs", "200", "--train", "6",
                 "--val", "2", "--per-group", "off", "--seeds", "0", "--quiet", "-o", str(tmp_path / kind)]) == 0
    model = LearnedModel(tmp_path / kind / "seed0" / "checkpoint.pt", robot=UR10)
    trajectory = load_dataset(tracking_dataset).trajectory(7)
    states = np.hstack([trajectory.q, trajectory.v])
    low, high = states[:, :6].min(axis=0), states[:, :6].max(axis=0)
    middle = 0.5 * (low + high)          # (a joint that barely moves keeps 0.05 rad either side)
    limits = JointLimits(np.minimum(low + 0.01, middle - 0.05), np.maximum(high - 0.01, middle + 0.05), np.full(6, 3.0),
                         EFFORT)
    horizon = load_mpc_config().horizon
    core_model, _ = compiled_model(model)
    for mode, refresh in (("soft", "all"), ("off", "all"), ("soft", 5)):
        configs = [dataclasses.replace(load_mpc_config(), optimizer=Rti(implementation=implementation,
                                                                        jacobian_refresh=refresh),
                                       constraints=Constraints(mode=mode)) for implementation in ("numpy", "compiled")]
        reference_solver, compiled_solver = (config.solver(model if refresh == "all" or name == "compiled" else
                                                           CoreAsModel(core_model, model), limits)
                                             for config, name in zip(configs, ("numpy", "compiled")))
        warm, nodes, compared, active = np.zeros((horizon, 6)), None, 0, 0
        for step in range(0, len(states) - horizon - 1, 3):
            reference = states[step:step + horizon + 1]
            before = compiled_solver._core.unsettled
            expected = reference_solver.solve(states[step], warm, reference, np.zeros((horizon, 6)), x_init=nodes)
            result = compiled_solver.solve(states[step], warm, reference, np.zeros((horizon, 6)), x_init=nodes)
            warm, nodes = np.vstack([expected.u[1:], expected.u[-1:]]), np.vstack([expected.x[1:], expected.x[-1:]])
            # (a step where either QP fell back to the torque box: the compiled one counts it; the reference's shows
            # as slack the other lacks. A slack of 1e-16 is rounding, not a crossing: on one CPU the compiled QP
            # settled with 1.2e-16 where the reference fell back with 0.029, and the two were compared)
            if compiled_solver._core.unsettled > before or (expected.slack > SLACK_ROUNDING) != (result.slack > SLACK_ROUNDING):
                continue
            np.testing.assert_allclose(result.u, expected.u, rtol=0, atol=(1e-5 if refresh == "all" else 1e-9)
                                       * EFFORT.max())
            assert result.cost == pytest.approx(expected.cost, rel=1e-4)
            compared += 1
            active += expected.constraint_active
        # (the inexact steps leave more QPs unsettled at these tight limits: 4-6 of 26 steps compared, not 8+)
        assert compared >= (8 if refresh == "all" else 4)
        if mode == "soft":
            assert active >= 1


@pytest.mark.slow
def test_a_machine_without_a_compiler_stops_the_install_in_one_line(tmp_path):
    """setup.py: no C++ compiler is one line saying so (and what to install), before any work; no package is built
    without the compiled step."""
    import os
    import pathlib
    import subprocess
    import sys
    from filelock import FileLock
    root = pathlib.Path(__file__).resolve().parents[1]
    (root / "build").mkdir(exist_ok=True)
    env = dict(os.environ, CC="no-such-compiler", CXX="no-such-compiler")
    with FileLock(str(root / "build" / ".test-wheel.lock"), timeout=900):   # (conftest.regular_install's lock)
        result = subprocess.run([sys.executable, "-m", "pip", "--disable-pip-version-check", "wheel", "--no-deps",
                                 "--no-build-isolation", "-w", str(tmp_path), str(root)], env=env, cwd=tmp_path,
                                capture_output=True, text=True, timeout=600)
    assert result.returncode != 0 and not list(tmp_path.glob("*.whl"))
    lines = [line.strip() for line in (result.stdout + result.stderr).splitlines() if "stdm-drake:" in line]
    assert lines == ["stdm-drake: no C++ compiler ('no-such-compiler' not found): the compiled MPC control step needs "
                     "one (Debian/Ubuntu: apt-get install g++); see docs/guides/install.md"], result.stderr[-2000:]
