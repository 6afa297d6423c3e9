"""MPC: iLQR against exact LQR, the plant as model, timing inside a Drake diagram, fallback."""
import dataclasses

import numpy as np
import pytest

from presets import UR10, free_limits
from stdm_drake.errors import InputError
from stdm_drake.closed_loop.ilqr import Ilqr, IlqrSolver
from stdm_drake.closed_loop.optimizer import OptimizerResult, TrajectoryOptimizer
from stdm_drake.closed_loop.mpc import MpcConfig, Reference, load_mpc_config, run_closed_loop
from stdm_drake.dynamics.model import DynamicsModel
from stdm_drake.dynamics.physics import PlantModel, zero_order_hold_discretization


class LinearModel(DynamicsModel):
    """x_next = A x + B u (12 states, 6 inputs): iLQR must find the exact LQR solution at once."""
    name, state_dim, action_dim, sample_period = "linear", 12, 6, 0.01

    def __init__(self, seed=0):
        rng = np.random.default_rng(seed)
        self.A = np.eye(12) + 0.01 * rng.normal(size=(12, 12))
        self.B = 0.01 * rng.normal(size=(12, 6))

    def step(self, x, u):
        return x @ self.A.T + u @ self.B.T

    def jacobians(self, x, u):
        return np.repeat(self.A[None], len(x), axis=0), np.repeat(self.B[None], len(x), axis=0)


def exact_lqr_controls(model, config, x0, reference, u_ff):
    """Minimize the MPC cost for a linear model as one least-squares problem over all torques."""
    horizon = config.horizon
    Q = np.diag(np.concatenate([config.position_weight, config.velocity_weight]))
    R = np.diag(config.effort_weight)
    # x_k+1 = A^(k+1) x0 + sum_j A^(k-j) B u_j
    blocks, rows_u, free = [], [], []
    for k in range(horizon):
        weight = config.terminal_factor if k == horizon - 1 else 1.0
        row = np.zeros((12, 6 * horizon))
        for j in range(k + 1):
            row[:, 6 * j:6 * j + 6] = np.linalg.matrix_power(model.A, k - j) @ model.B
        root = np.sqrt(weight) * np.sqrt(Q)
        blocks.append(root @ row)
        free.append(root @ (reference[k + 1] - np.linalg.matrix_power(model.A, k + 1) @ x0))
        select = np.zeros((6, 6 * horizon))
        select[:, 6 * k:6 * k + 6] = np.sqrt(R)
        rows_u.append(select)
        free.append(np.sqrt(R) @ u_ff[k])
    target = np.concatenate(free[0::2] + free[1::2])  # state residuals, then effort residuals
    matrix = np.vstack(blocks + rows_u)
    return np.linalg.lstsq(matrix, target, rcond=None)[0].reshape(horizon, 6)


def test_ilqr_equals_exact_lqr_on_a_linear_model():
    model = LinearModel()
    config = MpcConfig(horizon=8, optimizer=Ilqr(max_iterations=2, regularization=0.0))
    rng = np.random.default_rng(1)
    x0, reference = rng.normal(size=12), rng.normal(size=(9, 12))
    u_ff = rng.normal(size=(8, 6))
    solver = config.solver(model, free_limits(1e9))
    assert isinstance(solver, IlqrSolver)
    result = solver.solve(x0, np.zeros((8, 6)), reference, u_ff)
    expected = exact_lqr_controls(model, config, x0, reference, u_ff)
    np.testing.assert_allclose(result.u, expected, rtol=1e-6, atol=1e-8)
    assert result.finite and result.cost == pytest.approx(solver.cost(solver.rollout(x0, expected), expected,
                                                                      reference, u_ff), rel=1e-9)


def test_torques_are_clipped_to_effort_limits():
    model = LinearModel()
    config = MpcConfig(horizon=5)
    solver = IlqrSolver(model, config.cost(6), np.full(6, 0.5), Ilqr())
    result = solver.solve(np.zeros(12), np.zeros((5, 6)), np.full((6, 12), 100.0), np.zeros((5, 6)))
    assert np.abs(result.u).max() <= 0.5 + 1e-12 and np.abs(result.u).max() == pytest.approx(0.5)


@pytest.mark.parametrize("damping", [0.0, 1.0, 2000.0])
def test_zero_order_hold_discretization_is_exact_for_stiff_damped_joints(damping):
    """Against scipy's expm of the augmented matrix, from no damping to joint damping with a time constant
    of about 0.2 ms beside the 10 ms period (|A T| above 10, where a truncated series is far off)."""
    from scipy.linalg import expm
    rng = np.random.default_rng(2)
    n = 6
    A_c, B_c = np.zeros((2 * n, 2 * n)), np.zeros((2 * n, n))
    A_c[:n, n:] = np.eye(n)
    A_c[n:, :n] = rng.normal(size=(n, n))
    inverse_inertia = np.array([1.0, 1.0, 3.0, 100.0, 1000.0, 3000.0])     # 1/(kg m²): the UR-10's wrist is light
    A_c[n:, n:] = -damping * np.diag(inverse_inertia) / 1000.0 * (1 + rng.uniform(size=n)) + 0.1 * rng.normal(size=(n, n))
    B_c[n:] = np.diag(inverse_inertia)
    generator = np.zeros((3 * n, 3 * n))
    generator[:2 * n] = np.hstack([A_c, B_c])
    exact = expm(generator * 0.01)
    A_d, B_d = zero_order_hold_discretization(A_c, B_c, 0.01)
    np.testing.assert_allclose(A_d, exact[:2 * n, :2 * n], rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(B_d, exact[:2 * n, 2 * n:], rtol=1e-9, atol=1e-11)
    if damping == 2000.0:   # the stiff regime is really exercised
        assert np.abs(A_c * 0.01).sum(axis=0).max() > 10
    A_c[0, 0] = np.inf          # a diverged state: NaN matrices (the MPC's fallback), no exception
    assert all(np.isnan(matrix).all() for matrix in zero_order_hold_discretization(A_c, B_c, 0.01))


@pytest.fixture(scope="module")
def plant_model():
    return PlantModel(0.01, robot=UR10, integrator="rk4")


def test_plant_model_jacobians_match_finite_differences(plant_model):
    """The plant model for control: its Jacobians are exact (the RK4 stages' analytic derivatives chained),
    equal to central differences of its own step to 1e-5 relative."""
    x = np.array([0.1, -1.4, 1.6, -1.7, -1.5, 0.2, 0.5, 0.2, -0.4, 0.3, 0.6, 0.1])
    u = np.array([1.0, -60.0, -30.0, -2.0, 0.1, 0.0])
    A, B = plant_model.jacobians(x[None], u[None])
    z, eps, J = np.concatenate([x, u]), 1e-6, np.zeros((12, 18))
    for i in range(18):
        up, down = z.copy(), z.copy()
        up[i] += eps
        down[i] -= eps
        J[:, i] = (plant_model.step(up[None, :12], up[None, 12:]) - plant_model.step(down[None, :12], down[None, 12:]))[0] / (2 * eps)
    assert np.abs(A[0] - J[:, :12]).max() < 1e-5 * np.abs(J[:, :12]).max()
    assert np.abs(B[0] - J[:, 12:]).max() < 1e-5 * np.abs(J[:, 12:]).max()


def quintic_reference(duration_steps=30):
    """A joint-space quintic move of 0.1 rad on every joint from a typical pose, 10 ms samples."""
    tau = np.linspace(0, 1, duration_steps + 1)[:, None]
    start = np.array([0.0, -1.5, 1.6, -1.7, -1.57, 0.0])
    s = 10 * tau ** 3 - 15 * tau ** 4 + 6 * tau ** 5
    ds = (30 * tau ** 2 - 60 * tau ** 3 + 30 * tau ** 4) / (duration_steps * 0.01)
    return Reference(q=start + 0.1 * s, v=0.1 * ds * np.ones(6))


@pytest.mark.slow
def test_mpc_with_the_plant_tracks_and_applies_each_torque_for_a_whole_period(plant_model):
    reference = quintic_reference()
    log = run_closed_loop(plant_model, reference, load_mpc_config(), robot=UR10)
    states, torques = np.array(log.state), np.array(log.torque)
    assert len(states) == 30 and not any(log.fallback)
    np.testing.assert_allclose(log.time, np.concatenate([[0.0], np.arange(1, 30) * 0.01 - 0.0005]), atol=1e-12)
    # the torque decided from x_k is what the plant integrates over [t_k, t_k+1): exact re-simulation by the
    # simulator's own discrete plant (the MPC's plant model, RK4 steps, differs from it by ~1e-5 rad here)
    simulator = PlantModel(0.01, robot=UR10)
    np.testing.assert_allclose(simulator.step(states[:-1], torques[:-1]), states[1:], atol=1e-12)
    rms_error = np.sqrt(np.mean((states[:, :6] - reference.q[:30]) ** 2))
    assert rms_error < 0.02 * 0.1  # within 2% of the 0.1 rad move, planned in 0.3 s


class BrokenModel(LinearModel):
    def step(self, x, u):
        return np.full_like(x, np.nan)


def test_non_finite_model_falls_back_to_gravity_compensation():
    from stdm_drake.robots.plant import Dynamics
    reference = quintic_reference(5)
    log = run_closed_loop(BrokenModel(), reference, MpcConfig(horizon=3), robot=UR10)
    assert all(log.fallback)
    gravity = Dynamics(UR10).gravity_torque(log.state[1][:6])
    np.testing.assert_allclose(log.torque[1], gravity, rtol=1e-9)


def test_bad_mpc_config(tmp_path):
    path = tmp_path / "mpc.yaml"
    path.write_text("horizon: 20\neffort_weight: [1, 1, 1, 1, 1, 0]\n")
    with pytest.raises(InputError, match="effort_weight must be > 0"):
        load_mpc_config(path)
    path.write_text("horizon: [\n")
    with pytest.raises(InputError, match="malformed MPC config"):
        load_mpc_config(path)


class BiasedPlantModel(DynamicsModel):
    """The plant as model, but its velocity predictions are off by a constant (a wrong gravity model,
    say): 0.01 rad/s per step on the shoulder and elbow."""
    name, state_dim, action_dim = "biased", 12, 6

    def __init__(self, plant_model):
        self.plant_model = plant_model
        self.sample_period = plant_model.sample_period
        self.bias = np.zeros(12)
        self.bias[7:9] = 0.01

    def step(self, x, u):
        return self.plant_model.step(x, u) + self.bias

    def jacobians(self, x, u):
        return self.plant_model.jacobians(x, u)


@pytest.mark.slow
def test_disturbance_estimate_removes_a_constant_model_bias(plant_model):
    """Offset-free MPC: with the last one-step error added to its predictions, the biased model's
    closed loop follows the exact model's closed loop; without it, it drifts 10x further."""
    reference = quintic_reference()
    exact = np.array(run_closed_loop(plant_model, reference, load_mpc_config(), robot=UR10).state)
    deviation = {}
    for gain in (0.0, 1.0):
        config = dataclasses.replace(load_mpc_config(), disturbance_gain=gain)
        states = np.array(run_closed_loop(BiasedPlantModel(plant_model), reference, config, robot=UR10).state)
        deviation[gain] = np.abs(states[:, :6] - exact[:, :6]).max()
    assert deviation[1.0] < 0.2 * deviation[0.0]
    assert deviation[1.0] < 5e-4  # rad; what is left is the first step, taken before any estimate


def test_disturbance_gain_is_checked(tmp_path):
    path = tmp_path / "mpc.yaml"
    path.write_text("disturbance_gain: 1.5\n")
    with pytest.raises(InputError, match="disturbance_gain must be in"):
        load_mpc_config(path)


class FiniteDifferencePlant:
    """d x_next / d tau by central differences of the plant's exact discrete step (Drake's simulation of
    the held torque) with steps of 1e-3 of each torque's scale, apart from the model's own Jacobians."""

    def __init__(self, plant_model):
        self.plant_model = plant_model

    def jacobians(self, x, u):
        B = np.empty((len(x), x.shape[1], u.shape[1]))
        for j in range(u.shape[1]):
            step = 1e-3 * max(1e-3, float(np.abs(u[:, j]).max()))
            up, down = u.copy(), u.copy()
            up[:, j] += step
            down[:, j] -= step
            B[:, :, j] = (self.plant_model.step(x, up) - self.plant_model.step(x, down)) / (2 * step)
        return None, B


def test_jacobian_accuracy_tool_agrees_with_the_plants_own_torque_response(tracking_dataset):
    """The tool's reference (the simulator plant's own torque Jacobian) against finite differences of the
    plant's simulated step of another size: within 2 % per joint, so a learned model's percentages are
    measured against the real torque response."""
    from tools_import import jacobian_accuracy

    from stdm_drake.data.dataset import load_dataset
    dataset, simulator = load_dataset(tracking_dataset), PlantModel(0.01, robot=UR10)
    errors = jacobian_accuracy.torque_jacobian_errors(FiniteDifferencePlant(simulator), simulator, dataset, [0],
                                                      stride=25)
    assert errors.shape == (6,) and np.all(errors < 0.02), errors


def test_a_long_comparison_announces_its_time_estimate_after_each_models_first_plan():
    """After a model's first plan, one line gives its time per control step and the time its other plans
    will take, when that passes the threshold (20 s by default; 0 here), with or without progress bar."""
    from stdm_drake.closed_loop.comparison import compare_controllers
    config = dataclasses.replace(load_mpc_config(), horizon=3)
    references = [(0, quintic_reference(4)), (1, quintic_reference(4)), (2, quintic_reference(4))]
    lines = []
    results = compare_controllers([BrokenModel(), BrokenModel()], references, config, progress=False, robot=UR10,
                                  announce=lines.append, announce_after=0.0)
    assert len(results) == 6 and len(lines) == 2
    assert all(line.startswith("mpc: model linear: ") and "ms per control step); about" in line
               and line.endswith("min more for its other 2 plans") for line in lines)
    silent = []
    compare_controllers([BrokenModel()], references, config, progress=False, robot=UR10, announce=silent.append)
    assert silent == []


def test_plant_simulator_start_equals_a_fresh_simulator():
    """`start` resets the state variables only (not the parameters): after other runs, the steps of a
    simulator in use equal those of a freshly built one, bitwise."""
    from stdm_drake.robots.plant import PlantSimulator
    rng = np.random.default_rng(4)
    pairs = [(np.concatenate([UR10.home + rng.normal(0, 0.1, 6), rng.normal(0, 0.5, 6)]), rng.normal(0, 5, 6))
             for _ in range(4)]
    used = PlantSimulator(robot=UR10)
    for x, tau in pairs[::-1]:      # runs before, in another order
        used.start(x, tau)
        used.advance_to(0.03)
    for x, tau in pairs:
        fresh = PlantSimulator(robot=UR10)
        fresh.start(x, tau)
        used.start(x, tau)
        np.testing.assert_array_equal(used.advance_to(0.02), fresh.advance_to(0.02))


class HoldFeedforward(TrajectoryOptimizer):
    """Another optimizer, for the plug test: returns the feedforward torques unchanged."""

    def solve(self, x0, u_init, reference, u_ff, offset=None):
        x = self.rollout(x0, u_ff, offset)
        return OptimizerResult(u_ff.copy(), x, self.cost(x, u_ff, reference, u_ff), 0, bool(np.isfinite(x).all()))


def test_another_optimizer_plugs_into_the_controller_unchanged(plant_model):
    """MpcController takes any TrajectoryOptimizer: with one that returns the feedforward, every applied
    torque is the reference's gravity torque at that step (the controller is not touched)."""
    from stdm_drake.robots.plant import Dynamics
    config = dataclasses.replace(load_mpc_config(), horizon=3)
    reference = quintic_reference(5)
    optimizer = HoldFeedforward(plant_model, config.cost(6), np.full(6, 1e3))
    log = run_closed_loop(plant_model, reference, config, robot=UR10, optimizer=optimizer)
    gravity = Dynamics(UR10)
    assert not any(log.fallback) and len(log.torque) == 5
    for k, torque in enumerate(log.torque):
        np.testing.assert_allclose(torque, gravity.gravity_torque(reference.q[k]), rtol=1e-12)
