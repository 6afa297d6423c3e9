"""The robot's limits inside the MPC's optimizers (closed_loop/constraints.py): the QPs against an independent
solver (Drake's Clarabel), the textbook constrained linear MPC, bit-for-bit equality with the unconstrained
controller where nothing binds, slack where a limit cannot be met, the samplers' penalty, the settings."""
import dataclasses

import numpy as np
import pytest

from presets import UR10, free_limits
from test_mpc import LinearModel, quintic_reference
from stdm_drake.closed_loop.constraints import Constraints, CondensedQp, StateBounds, box_qp
from stdm_drake.closed_loop.ilqr import Ilqr
from stdm_drake.closed_loop.mpc import MpcConfig, load_mpc_config, run_closed_loop
from stdm_drake.closed_loop.rti import Rti
from stdm_drake.errors import InputError
from stdm_drake.robots.plant import JointLimits


def clarabel(hessian, gradient, lower, upper, rows=None, row_lower=None, row_upper=None, slack_weight=None):
    """min 1/2 z^T hessian z + gradient^T z (+ slack_weight sum(s + s^2/2)) over lower <= z <= upper and
    row_lower - s <= rows z <= row_upper + s, s >= 0 (without slack_weight: s = 0), by Drake's Clarabel."""
    from pydrake.solvers import ClarabelSolver, MathematicalProgram, SolverOptions
    program = MathematicalProgram()
    count = len(gradient)
    z = program.NewContinuousVariables(count, "z")
    program.AddQuadraticCost(hessian, gradient, z, is_convex=True)
    program.AddBoundingBoxConstraint(lower, upper, z)
    if rows is not None and len(rows):
        if slack_weight is None:
            keep = np.isfinite(row_lower) | np.isfinite(row_upper)
            program.AddLinearConstraint(rows[keep], row_lower[keep], row_upper[keep], z)
        else:
            s = program.NewContinuousVariables(len(rows), "s")
            program.AddQuadraticCost(slack_weight * np.eye(len(rows)), np.full(len(rows), slack_weight), s, is_convex=True)
            program.AddBoundingBoxConstraint(0, np.inf, s)
            for i in range(len(rows)):
                if np.isfinite(row_upper[i]):
                    program.AddLinearConstraint(np.append(rows[i], -1.0), -np.inf, row_upper[i], np.append(z, s[i]))
                if np.isfinite(row_lower[i]):
                    program.AddLinearConstraint(np.append(rows[i], 1.0), row_lower[i], np.inf, np.append(z, s[i]))
    options = SolverOptions()
    for name in ("tol_gap_abs", "tol_gap_rel", "tol_feas", "tol_ktratio"):
        options.SetOption(ClarabelSolver.id(), name, 1e-11)
    result = ClarabelSolver().Solve(program, solver_options=options)
    assert result.is_success(), result.get_solution_result()
    return result.GetSolution(z)


def condensed_problem(seed: int, horizon: int = 6):
    """A random stable linear arm's condensed tracking QP: (hessian, gradient, response G, prediction c)."""
    model, config = LinearModel(seed), MpcConfig(horizon=horizon)
    rng = np.random.default_rng(seed)
    S, m = 12, 6
    G = np.zeros((horizon * S, horizon * m))
    for k in range(horizon):
        for j in range(k + 1):
            G[k * S:(k + 1) * S, j * m:(j + 1) * m] = np.linalg.matrix_power(model.A, k - j) @ model.B
    c = np.concatenate([np.linalg.matrix_power(model.A, k + 1) @ (0.3 * rng.normal(size=S)) for k in range(horizon)])
    weights = np.tile(np.diag(config.cost(6).Q), horizon)
    hessian = G.T @ (weights[:, None] * G) + np.diag(np.tile(np.diag(config.cost(6).R), horizon)) + 1e-3 * np.eye(horizon * m)
    gradient = G.T @ (weights * (c - 0.5 * rng.normal(size=horizon * S)))
    return hessian, gradient, G, c


@pytest.mark.parametrize("seed", range(4))
def test_the_box_qp_equals_an_independent_solvers(seed):
    hessian, gradient, _, _ = condensed_problem(seed)
    free = np.linalg.solve(hessian, -gradient)
    bound = 0.5 * np.abs(free).max()          # half the unconstrained step's largest torque: several bounds bind
    d, clamped = box_qp(hessian, gradient, np.full(len(free), -bound), np.full(len(free), bound))
    expected = clarabel(hessian, gradient, np.full(len(free), -bound), np.full(len(free), bound))
    np.testing.assert_allclose(d, expected, atol=1e-6 * bound)
    assert clamped.any() and not clamped.all()
    np.testing.assert_array_equal(clamped, np.abs(np.abs(expected) - bound) < 1e-6 * bound)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("hard", [False, True])
def test_the_condensed_qp_equals_an_independent_solvers(seed, hard):
    """Torque box and state rows (soft: with the exact penalty's slack; hard: feasible bounds, no slack)."""
    hessian, gradient, G, c = condensed_problem(seed)
    free = np.linalg.solve(hessian, -gradient)
    states = c + G @ free
    S = 12
    spread = np.abs(states.reshape(-1, S)).max(axis=0)
    bounds = StateBounds(lower=-0.6 * spread, upper=0.6 * spread, hard=hard, penalty_weight=10.0)
    torque = np.full(len(free), 0.8 * np.abs(free).max())
    solution = CondensedQp(bounds, 6).solve(hessian, gradient, -torque, torque, G, c)
    lower_rows, upper_rows = np.tile(bounds.lower, len(c) // S) - c, np.tile(bounds.upper, len(c) // S) - c
    weight = 0.5 * bounds.penalty_weight     # (the QP is half the MPC's cost: the penalty enters halved)
    expected = clarabel(hessian, gradient, -torque, torque, G, lower_rows, upper_rows, None if hard else weight)
    if hard:      # the hard bounds may be infeasible: then the step is the soft problem's
        try:
            expected = clarabel(hessian, gradient, -torque, torque, G, lower_rows, upper_rows)
        except AssertionError:
            expected = clarabel(hessian, gradient, -torque, torque, G, lower_rows, upper_rows, weight)
    np.testing.assert_allclose(solution.delta, expected, atol=1e-6 * np.abs(expected).max())
    assert solution.active


def test_the_slack_is_exact_where_the_limits_can_be_met():
    """The exact penalty: with a weight beyond the constraints' multipliers the soft QP's solution is the hard
    one's, and no slack is used."""
    hessian, gradient, G, c = condensed_problem(7)
    states = c + G @ np.linalg.solve(hessian, -gradient)
    spread = np.abs(states.reshape(-1, 12)).max(axis=0)
    torque = np.full(len(gradient), 1e6)
    soft = CondensedQp(StateBounds(-0.9 * spread, 0.9 * spread, False, 1e7), 6).solve(hessian, gradient, -torque,
                                                                                       torque, G, c)
    hard = CondensedQp(StateBounds(-0.9 * spread, 0.9 * spread, True, 1e7), 6).solve(hessian, gradient, -torque,
                                                                                      torque, G, c)
    assert soft.slack < 1e-12 and hard.slack == 0.0
    np.testing.assert_allclose(soft.delta, hard.delta, atol=1e-7 * np.abs(hard.delta).max())


def textbook_constrained_mpc(model, config, x0, reference, u_ff, effort, lower, upper, penalty):
    """The constrained linear MPC as one QP over all torques (x_k+1 = A^(k+1) x0 + sum_j A^(k-j) B u_j), its state
    limits softened with the exact penalty, solved by Clarabel."""
    horizon, S, m = config.horizon, 12, 6
    G = np.zeros((horizon * S, horizon * m))
    for k in range(horizon):
        for j in range(k + 1):
            G[k * S:(k + 1) * S, j * m:(j + 1) * m] = np.linalg.matrix_power(model.A, k - j) @ model.B
    free = np.concatenate([np.linalg.matrix_power(model.A, k + 1) @ x0 for k in range(horizon)])
    weights = np.concatenate([np.diag(config.cost(6).Q) * (config.terminal_factor if k == horizon - 1 else 1.0)
                              for k in range(horizon)])
    R = np.tile(np.diag(config.cost(6).R), horizon)
    # the cost (x - r)^T W (x - r) + (u - u_ff)^T R (u - u_ff): half of it in 1/2 z^T H z + g^T z form, so the
    # penalty (not halved in the MPC's cost) enters with half its weight
    hessian = G.T @ (weights[:, None] * G) + np.diag(R)
    gradient = G.T @ (weights * (free - reference[1:].ravel())) - R * u_ff.ravel()
    rows_lower, rows_upper = np.tile(lower, horizon) - free, np.tile(upper, horizon) - free
    u = clarabel(hessian, gradient, np.full(horizon * m, -effort), np.full(horizon * m, effort), G, rows_lower,
                 rows_upper, 0.5 * penalty)
    return u.reshape(horizon, m)


@pytest.mark.parametrize("optimizer", [Rti(iterations=1, regularization=0.0),
                                       Ilqr(max_iterations=30, regularization=0.0, line_search=[1.0, 0.5, 0.25, 0.1, 0.05])])
def test_on_a_linear_arm_the_constrained_mpc_is_the_textbook_constrained_lqr(optimizer):
    """One real-time iteration is the whole QP on a linear model; box-DDP's iterations reach it too."""
    model = LinearModel(3)
    config = MpcConfig(horizon=8, optimizer=optimizer)
    rng = np.random.default_rng(5)
    x0, reference, u_ff = 0.1 * rng.normal(size=12), rng.normal(size=(9, 12)), np.zeros((8, 6))
    unconstrained = config.solver(model, free_limits(1e9)).solve(x0, np.zeros((8, 6)), reference, u_ff)
    effort = 0.5 * np.abs(unconstrained.u).max()
    position = 0.7 * np.abs(unconstrained.x[1:, :6]).max()
    limits = JointLimits(np.full(6, -position), np.full(6, position), np.full(6, np.inf), np.full(6, effort))
    bounds_config = dataclasses.replace(config, constraints=Constraints(position_margin=0.0, velocity_margin=0.0,
                                                                        penalty_weight=1e3))
    solver = bounds_config.solver(model, limits)
    result = solver.solve(x0, np.zeros((8, 6)), reference, u_ff)
    lower = np.concatenate([np.full(6, -position), np.full(6, -np.inf)])
    upper = np.concatenate([np.full(6, position), np.full(6, np.inf)])
    expected = textbook_constrained_mpc(model, config, x0, reference, u_ff, effort, lower, upper, 1e3)
    tolerance = 1e-6 if isinstance(optimizer, Rti) else 3e-4   # (box-DDP's iterations on the penalty's kink: near it)
    np.testing.assert_allclose(result.u, expected, atol=tolerance * effort)
    assert np.abs(result.u).max() <= effort + 1e-12 and result.constraint_active
    assert np.abs(unconstrained.u).max() > 1.5 * effort     # the limits changed the answer


@pytest.mark.parametrize("optimizer", [Rti(), Ilqr(max_iterations=3)])
def test_with_no_constraint_active_the_torques_are_the_unconstrained_controllers_bit_for_bit(optimizer):
    model = LinearModel(1)
    rng = np.random.default_rng(2)
    x0, reference, u_ff = 0.1 * rng.normal(size=12), 0.1 * rng.normal(size=(9, 12)), np.zeros((8, 6))
    config = MpcConfig(horizon=8, optimizer=optimizer)
    limits = JointLimits(np.full(6, -100.0), np.full(6, 100.0), np.full(6, 100.0), np.full(6, 1e6))
    off = dataclasses.replace(config, constraints=Constraints(mode="off")).solver(model, limits)
    soft = config.solver(model, limits)
    hard = dataclasses.replace(config, constraints=Constraints(mode="hard")).solver(model, limits)
    u = np.zeros((8, 6))
    for _ in range(3):     # warm-started steps
        results = [solver.solve(x0, u, reference, u_ff) for solver in (off, soft, hard)]
        assert all(np.array_equal(results[0].u, result.u) for result in results[1:])
        assert not any(result.constraint_active for result in results)
        u = np.vstack([results[0].u[1:], results[0].u[-1:]])


def test_the_ur10_closed_loop_is_bit_for_bit_todays_where_nothing_binds(plant_model):
    """The plant as model on a plan far from every limit: the constrained default's torques are those of the
    controller before constraints (mode off), bit for bit, and no step reports a constraint."""
    reference = quintic_reference(30)
    config = load_mpc_config()
    soft = run_closed_loop(plant_model, reference, config, robot=UR10)
    off = run_closed_loop(plant_model, reference, dataclasses.replace(config, constraints=Constraints(mode="off")),
                          robot=UR10)
    assert config.constraints.mode == "soft"
    np.testing.assert_array_equal(np.array(soft.torque), np.array(off.torque))
    assert not any(soft.constraint_active) and not any(np.array(soft.slack) > 0)


@pytest.fixture(scope="module")
def plant_model():
    from stdm_drake.dynamics.physics import PlantModel
    return PlantModel(0.01, robot=UR10, integrator="rk4")


@pytest.mark.parametrize("mode", ["soft", "hard"])
@pytest.mark.parametrize("optimizer", [Rti(), Ilqr(max_iterations=3)])
def test_a_state_limit_that_cannot_be_met_uses_slack_and_never_fails_the_solve(mode, optimizer):
    """The arm starts at 2 rad/s toward a position limit 0.05 rad away, with torques too weak to stop it in time:
    the solve succeeds, its torques stay in the box, it brakes with all it has and reports the slack."""
    model = LinearModel(0)
    model.A = np.eye(12)
    model.A[:6, 6:] = 0.01 * np.eye(6)
    model.B = np.vstack([0.5e-4 * np.eye(6), 0.01 * np.eye(6)])
    x0 = np.concatenate([np.full(6, 0.95), np.full(6, 2.0)])
    reference = np.tile(np.concatenate([np.full(6, 0.95), np.zeros(6)]), (9, 1))     # hold where it starts
    limits = JointLimits(np.full(6, -1.0), np.full(6, 1.0), np.full(6, 3.0), np.full(6, 20.0))
    config = MpcConfig(horizon=8, optimizer=optimizer, effort_weight=[1e-4],
                       constraints=Constraints(mode=mode, position_margin=0.0, velocity_margin=0.0))
    result = config.solver(model, limits).solve(x0, np.zeros((8, 6)), reference, np.zeros((8, 6)))
    assert result.finite and np.all(np.isfinite(result.u))
    assert result.slack > 0.01 and result.constraint_active
    np.testing.assert_allclose(result.u[0], -20.0)        # full braking (0.2 rad/s per step: 0.1 rad to stop)
    assert np.abs(result.u).max() <= 20.0


def test_the_samplers_price_state_limit_crossings_and_keep_torques_in_the_box():
    from stdm_drake.closed_loop.sampling import Icem
    model = LinearModel(0)
    x0, reference = np.zeros(12), np.tile(np.concatenate([np.full(6, 0.5), np.zeros(6)]), (9, 1))
    cost = MpcConfig().cost(6)
    bounds = Constraints(position_margin=0.0, velocity_margin=0.0).bounds(np.full(6, -0.1), np.full(6, 0.1),
                                                                          np.full(6, np.inf))
    settings = Icem(samples=20, iterations=2)
    free = settings.solver(model, cost, np.full(6, 3.0), 8)
    bound = settings.solver(model, cost, np.full(6, 3.0), 8, bounds)
    u = np.random.default_rng(0).normal(scale=100.0, size=(5, 8, 6))
    gain = np.zeros((6, 12))
    plain, _ = free.costs(x0, u, gain, reference, np.zeros((8, 6)), np.zeros(12))
    priced, states = bound.costs(x0, u, gain, reference, np.zeros((8, 6)), np.zeros(12), keep_states=True)
    crossing = bounds.violation(states[:, 0]).sum(axis=(0, 2))         # (K,)
    np.testing.assert_allclose(priced - plain, bounds.penalty_weight * (
        crossing + 0.5 * (bounds.violation(states[:, 0]) ** 2).sum(axis=(0, 2))), rtol=1e-9)
    assert np.all(crossing > 0)
    result = bound.solve(x0, np.zeros((8, 6)), reference, np.zeros((8, 6)))
    assert np.abs(result.u).max() <= 3.0


@pytest.mark.parametrize("fields, message", [
    (dict(mode="clip"), "mode must be one of soft, hard, off"),
    (dict(position_margin=-0.1), "position_margin must be a number >= 0"),
    (dict(velocity_margin=float("nan")), "velocity_margin must be a number >= 0"),
    (dict(penalty_weight=0.0), "penalty_weight must be in"),
    (dict(penalty_weight=1e300), "penalty_weight must be in"),
])
def test_constraint_settings_no_optimizer_can_use_are_refused_in_one_line(fields, message):
    with pytest.raises(InputError, match=message):
        MpcConfig(constraints=Constraints(**fields)).validate()


def test_a_margin_that_leaves_a_joint_no_room_names_the_joint():
    config = MpcConfig(constraints=Constraints(position_margin=0.2))
    limits = JointLimits(np.r_[-1.0, -0.1, -1, -1, -1, -1], np.r_[1.0, 0.1, 1, 1, 1, 1], np.full(6, 2.0), np.full(6, 10.0))
    with pytest.raises(InputError, match=r"position_margin leaves joint 'shoulder_lift_joint' no room inside its "
                                         r"position limits \[-0.1, 0.1\] \(0.2 on each side\)"):
        config.solver(LinearModel(), limits, UR10.joint_names)
    huge = MpcConfig(constraints=Constraints(position_margin=1e300))   # (held-out run 15: it printed "[0, 0]")
    with pytest.raises(InputError, match=r"'shoulder_pan_joint' no room inside its position limits \[-1, 1\] "
                                         r"\(1e\+300 on each side\)"):
        huge.solver(LinearModel(), limits, UR10.joint_names)


def test_the_settings_file_sets_the_constraints(tmp_path):
    path = tmp_path / "mpc.yaml"
    path.write_text("constraints: {mode: hard, position_margin: 0.05}\n")
    config = load_mpc_config(path)
    assert config.constraints == Constraints(mode="hard", position_margin=0.05)
    assert load_mpc_config().constraints == Constraints()       # the shipped file: the defaults, soft
    path.write_text("constraints: {mode: off}\n")          # (a bare `off`, which YAML reads as false)
    config = load_mpc_config(path)
    config.validate()
    assert config.constraints.mode == "off" and config.record()["constraints"]["mode"] == "off"
    assert config.solver(LinearModel(), free_limits(10.0)).bounds is None
    path.write_text("constraints: {mode: on}\n")              # (YAML 1.1's true, no mode)
    with pytest.raises(InputError, match="mode is written on, which YAML 1.1 reads as a boolean; write one of soft, "
                                         "hard, off"):
        load_mpc_config(path).validate()
    path.write_text("constraints: {mode: sometimes}\n")
    with pytest.raises(InputError, match="constraints mode must be one of"):
        load_mpc_config(path).validate()


def test_the_controllers_limits_are_the_robots_with_its_configs_overrides(tmp_path, plant_model):
    """The MPC LeafSystem's state bounds: the plant's limits with the robot YAML's overrides, less the margins."""
    from stdm_drake.closed_loop.mpc import MpcController
    from stdm_drake.paths import MODELS_DIR
    from stdm_drake.robots.robot import load_robot
    text = (MODELS_DIR / "ur10.yaml").read_text().replace("model: ur10.urdf", f"model: {MODELS_DIR / 'ur10.urdf'}")
    path = tmp_path / "ur10.yaml"
    path.write_text(text + "position_limits: {elbow_joint: [-1.0, 2.5]}\nvelocity_limits: {wrist_3_joint: 1.5}\n")
    robot = load_robot(path)
    controller = MpcController(plant_model, quintic_reference(5), load_mpc_config(), 0.001, robot)
    bounds, margins = controller.solver.bounds, load_mpc_config().constraints
    assert bounds.lower[2] == pytest.approx(-1.0 + margins.position_margin)
    assert bounds.upper[2] == pytest.approx(2.5 - margins.position_margin)
    assert bounds.upper[6 + 5] == pytest.approx(1.5 - margins.velocity_margin)
    assert bounds.upper[0] == pytest.approx(2 * np.pi - margins.position_margin)


def test_a_qp_whose_rows_do_not_settle_keeps_the_torque_box_and_reports_the_crossings(monkeypatch):
    """Bounded work: when DAQP cannot settle the state rows within its iterations (an untrained model's predictions
    far outside every limit), the step is the torque box's QP alone and its crossings are reported as slack."""
    import stdm_drake.closed_loop.constraints as constraints
    hessian, gradient, G, c = condensed_problem(2)
    states = c + G @ np.linalg.solve(hessian, -gradient)
    spread = np.abs(states.reshape(-1, 12)).max(axis=0)
    bounds = StateBounds(-0.3 * spread, 0.3 * spread, False, 10.0)
    torque = np.full(len(gradient), 1e6)
    settled = CondensedQp(bounds, 6).solve(hessian, gradient, -torque, torque, G, c)
    monkeypatch.setattr(constraints, "MAX_QP_ITERATIONS", 1)
    bounded = CondensedQp(bounds, 6).solve(hessian, gradient, -torque, torque, G, c)
    box_only = box_qp(hessian, gradient, -torque, torque)[0]
    np.testing.assert_allclose(bounded.delta, box_only, atol=1e-9 * np.abs(box_only).max())
    crossing = bounds.violation((c + G @ bounded.delta).reshape(-1, 12)).max()
    assert bounded.active and bounded.slack == pytest.approx(crossing) and crossing > settled.slack


def test_a_push_acts_beside_the_actuators_and_keeps_the_plant_effects_friction(plant_model):
    """JointPush: a zero push leaves the closed loop bit for bit as it was (the friction the effects feed into the
    same input still acts, through the adder); a push on the wrist moves it, beyond what its effort limit allows."""
    from stdm_drake.closed_loop.push import JointPush
    from stdm_drake.paths import MODELS_DIR
    from stdm_drake.robots.plant import PlantConfig
    from stdm_drake.robots.plant_effects_check import plant_effects_for
    reference, config = quintic_reference(10), load_mpc_config()
    affected = PlantConfig.discrete(0.001, effects=plant_effects_for(MODELS_DIR / "ur10_effects.yaml", UR10, 0.001))
    plain = run_closed_loop(plant_model, reference, config, affected, robot=UR10)
    zero = run_closed_loop(plant_model, reference, config, affected, robot=UR10,
                           push=JointPush(np.zeros(6), 0.03, 0.02))
    np.testing.assert_array_equal(np.array(plain.state), np.array(zero.state))
    pushed = run_closed_loop(plant_model, reference, config, affected, robot=UR10,
                             push=JointPush(np.r_[0, 0, 0, 0, 0, 200.0], 0.03, 0.02))    # 200 N m: 3.6x the limit
    difference = np.abs(np.array(pushed.state) - np.array(plain.state)).max(axis=0)
    assert difference[11] > 1.0 and difference[:5].max() < difference[5]
