"""The multi-level iteration (`Rti(jacobian_refresh=K)`, closed_loop/rti.py, core/control_step.hpp): which nodes'
Jacobians each control step computes, that the others are the last solve's shifted by one period, the compiled step
equal to the numpy reference for every model kind, K = all unchanged to the bit, and its settings refused in one
line."""
import dataclasses

import numpy as np
import pytest

from presets import UR10
from test_compiled_step import EFFORT, STRUCTURES, TIGHT, recorded_comparison
from test_export import synthetic_checkpoint
from test_mpc import quintic_reference
from stdm_drake.closed_loop.constraints import Constraints
from stdm_drake.closed_loop.mpc import load_mpc_config, run_closed_loop
from stdm_drake.closed_loop.rti import Rti, RtiSolver
from stdm_drake.dynamics.physics import PlantModel
from stdm_drake.errors import InputError
from stdm_drake.learning.learned_model import LearnedModel


@pytest.fixture(scope="module")
def plant_model():
    return PlantModel(0.01, robot=UR10, integrator="rk4")


def solver_for(model, refresh, implementation="numpy", mode="soft"):
    config = dataclasses.replace(load_mpc_config(), optimizer=Rti(jacobian_refresh=refresh,
                                                                  implementation=implementation),
                                 constraints=Constraints(mode=mode))
    return config.solver(model, TIGHT)


@pytest.mark.parametrize("refresh, expected", [(1, [0, 19]), (2, [0, 10, 19]), (5, [0, 4, 8, 12, 16, 19]),
                                               (7, [0, 3, 6, 9, 12, 15, 18, 19]), (20, list(range(20))),
                                               ("all", list(range(20)))])
def test_the_refreshed_nodes_are_every_pth_position_and_the_newest(plant_model, refresh, expected):
    assert solver_for(plant_model, refresh).refreshed_nodes(20).tolist() == expected


@pytest.mark.parametrize("refresh", [1, 2, 5, 7])
def test_every_node_is_refreshed_at_least_every_p_steps_as_it_moves_down_the_horizon(plant_model, refresh):
    """A node enters as the newest (H - 1) and moves down one position per control step: its Jacobians are never
    older than P - 1 periods, P = ceil(H / K)."""
    horizon, period = 20, -(-20 // refresh)
    nodes = set(solver_for(plant_model, refresh).refreshed_nodes(horizon).tolist())
    age = None                              # periods since its Jacobians were computed (None: never)
    for position in range(horizon - 1, -1, -1):
        age = 0 if position in nodes else age + 1
        assert age <= period - 1


class CountingModel:
    """A model that records the rows each linearization and each forward step gets."""

    def __init__(self, model):
        self.model, self.linearized, self.stepped = model, [], []
        self.state_dim, self.action_dim, self.sample_period = model.state_dim, model.action_dim, model.sample_period

    def step(self, x, u):
        self.stepped.append(len(x))
        return self.model.step(x, u)

    def step_single(self, x, u):
        return self.model.step_single(x, u)

    def jacobians(self, x, u):
        return self.model.jacobians(x, u)

    def linearize(self, x, u):
        self.linearized.append(len(x))
        return self.model.linearize(x, u)


def test_a_warm_started_step_linearizes_only_the_refreshed_nodes_and_keeps_the_shifted_others(plant_model):
    """The first step (no warm start) linearizes all 20 nodes; then each step the 6 nodes of K = 5 and steps the
    other 14 forward; the kept Jacobians of node k are the last solve's of node k + 1, exactly."""
    counting = CountingModel(plant_model)
    solver = RtiSolver(counting, load_mpc_config().cost(6), EFFORT, Rti(jacobian_refresh=5, implementation="numpy"))
    horizon = 20
    x = np.concatenate([np.full(6, 0.3), np.zeros(6)])
    reference = np.tile(np.concatenate([np.full(6, 0.35), np.zeros(6)]), (horizon + 1, 1))
    result = solver.solve(x, np.zeros((horizon, 6)), reference, np.zeros((horizon, 6)))
    assert counting.linearized == [20]
    first_A, first_B = solver._kept
    warm, nodes = np.vstack([result.u[1:], result.u[-1:]]), np.vstack([result.x[1:], result.x[-1:]])
    counting.linearized.clear()
    counting.stepped.clear()
    captured = {}
    original = RtiSolver._step

    def capture(self, x, u, reference, u_ff, predicted, A, B, mu):
        captured["A"], captured["B"], captured["predicted"] = A.copy(), B.copy(), predicted.copy()
        return original(self, x, u, reference, u_ff, predicted, A, B, mu)

    RtiSolver._step = capture
    try:
        solver.solve(result.x[1], warm, reference, np.zeros((horizon, 6)), x_init=nodes)
    finally:
        RtiSolver._step = original
    assert counting.linearized == [6] and 14 in counting.stepped
    refreshed = solver.refreshed_nodes(horizon)
    kept = np.setdiff1d(np.arange(horizon), refreshed)
    np.testing.assert_array_equal(captured["A"][kept], first_A[kept + 1])
    np.testing.assert_array_equal(captured["B"][kept], first_B[kept + 1])
    start = nodes.copy()
    start[0] = result.x[1]
    following, A, B = plant_model.linearize(start[:-1], warm)
    np.testing.assert_allclose(captured["A"][refreshed], A[refreshed], rtol=0, atol=1e-12)
    np.testing.assert_allclose(captured["predicted"], following, rtol=0, atol=1e-12)   # every node predicted


def test_k_equal_to_the_horizon_is_the_exact_step_to_the_bit(plant_model):
    reference = quintic_reference(30)
    config = load_mpc_config()
    logs = [run_closed_loop(plant_model, reference, dataclasses.replace(
        config, optimizer=dataclasses.replace(config.optimizer, jacobian_refresh=refresh)), robot=UR10)
        for refresh in ("all", config.horizon)]
    np.testing.assert_array_equal(np.array(logs[0].torque), np.array(logs[1].torque))


@pytest.mark.parametrize("mode", ["soft", "off"])
@pytest.mark.parametrize("refresh, iterations", [(1, 1), (5, 1), (5, 2)])
def test_the_compiled_multilevel_torques_are_the_references_with_the_plant_as_model(plant_model, mode, refresh,
                                                                                      iterations):
    """On recorded states near tight limits, each implementation keeping its own Jacobians from its own last
    solve: the torques to 1e-9 of the effort limit, and they differ from the exact step's."""
    rows = recorded_comparison(plant_model, mode, iterations, jacobian_refresh=refresh)
    exact = recorded_comparison(plant_model, mode, iterations)
    compared = [(a, b) for a, b, fell_back in rows if not fell_back]
    assert len(compared) >= len(rows) // 2
    for expected, result in compared:
        np.testing.assert_allclose(result.u, expected.u, rtol=0, atol=1e-9 * EFFORT.max())
        assert result.constraint_active == expected.constraint_active
    assert max(np.abs(a.u - b.u).max() for (a, _, _), (b, _, _) in zip(rows, exact)) > 1e-6


class CoreAsModel:
    """The compiled core's copy of a model behind the numpy model interface (its `step_rows`, `step`, `linearize`),
    so that the numpy reference and the compiled step see the same float32 numbers and differ only in the
    algorithm."""

    def __init__(self, core, model):
        self.core, self.state_dim, self.action_dim = core, model.state_dim, model.action_dim
        self.sample_period = model.sample_period

    def step(self, x, u):
        return self.core.step_rows(np.ascontiguousarray(x), np.ascontiguousarray(u))

    def step_single(self, x, u):
        return self.core.step(x, u)

    def linearize(self, x, u):
        following, A, B = self.core.linearize(np.ascontiguousarray(x), np.ascontiguousarray(u))
        return following, A.reshape(len(x), self.state_dim, self.state_dim), B.reshape(len(x), self.state_dim, -1)


@pytest.mark.parametrize("structure, kind, activation", STRUCTURES[:4])
def test_the_compiled_multilevel_step_is_the_reference_for_every_network_kind(tmp_path, structure, kind, activation):
    """Every structure the compiled step covers (next state or velocity, raw or nominal-acceleration inputs, one
    member or five), K = 1, 5 and all, one and two iterations: the numpy reference over the compiled network's own
    steps and Jacobians (`CoreAsModel`) gives the compiled step's torques to 1e-9 of the effort limit on recorded
    states, each solver keeping its own Jacobians. (Limits off: random weights drive the limited QP to the
    torque-box fallback on most steps, where the two QP methods may part; the trained networks of
    tests/test_compiled_step.py cover the limits, end to end.)"""
    from stdm_drake.dynamics.compiled_core import compiled_model
    checkpoint = synthetic_checkpoint(tmp_path / "m.pt", structure, model_type=kind, activation=activation)
    model = LearnedModel(checkpoint, robot=UR10)
    core, _ = compiled_model(model)
    for refresh, iterations in ((1, 1), (5, 1), (5, 2), ("all", 1)):
        solvers = {}
        for implementation in ("numpy", "compiled"):
            config = dataclasses.replace(load_mpc_config(), optimizer=Rti(
                iterations=iterations, jacobian_refresh=refresh, implementation=implementation),
                constraints=Constraints(mode="off"))
            solvers[implementation] = config.solver(CoreAsModel(core, model) if implementation == "numpy" else model,
                                                    TIGHT)
        assert type(solvers["numpy"]) is RtiSolver and solvers["compiled"].implementation == "compiled"
        horizon = load_mpc_config().horizon
        rng = np.random.default_rng(1)
        x = np.concatenate([rng.uniform(0.2, 0.4, 6), rng.uniform(-0.2, 0.2, 6)])
        warm, nodes = np.zeros((horizon, 6)), None
        for step in range(8):
            reference = np.tile(np.concatenate([np.full(6, 0.3 + 0.01 * step), np.zeros(6)]), (horizon + 1, 1))
            expected, result = (solvers[name].solve(x, warm, reference, np.zeros((horizon, 6)), x_init=nodes)
                                for name in ("numpy", "compiled"))
            assert expected.finite and result.finite
            np.testing.assert_allclose(result.u, expected.u, rtol=0, atol=1e-9 * EFFORT.max())
            warm, nodes = np.vstack([expected.u[1:], expected.u[-1:]]), np.vstack([expected.x[1:], expected.x[-1:]])
            x = expected.x[1] + rng.normal(0.0, 0.003, 12)


@pytest.mark.parametrize("text, message", [
    ("optimizer: !Rti {jacobian_refresh: 0}\n", "jacobian_refresh must be all or a number of nodes from 1 to the "
                                               "horizon, got 0"),
    ("optimizer: !Rti {jacobian_refresh: -3}\n", "got -3"),
    ("optimizer: !Rti {jacobian_refresh: some}\n", "got 'some'"),
    ("optimizer: !Rti {jacobian_refresh: 21}\n", "jacobian_refresh 21 is beyond the horizon's 20 nodes"),
    ("horizon: 4\noptimizer: !Rti {jacobian_refresh: 5}\n", "jacobian_refresh 5 is beyond the horizon's 4 nodes")])
def test_a_refresh_setting_the_step_cannot_run_is_one_line(tmp_path, text, message):
    """(and "all", quoted or not, loads: the setting takes text)"""
    for written in ("all", '"all"', "!!str all"):
        (tmp_path / "all.yaml").write_text(f"optimizer: !Rti {{jacobian_refresh: {written}}}\n")
        assert load_mpc_config(tmp_path / "all.yaml").optimizer.jacobian_refresh == "all"
    path = tmp_path / "mpc.yaml"
    path.write_text(text)
    with pytest.raises(InputError, match=message) as error:
        load_mpc_config(path).validate()
    assert "\n" not in str(error.value)
