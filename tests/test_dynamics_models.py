"""The model contract: learned models beside the physics baselines, the structures that make them learn,
their Jacobians, and the chain rule of derivative learning checked against the plant."""
import numpy as np
import pytest

from presets import UR10
from stdm_drake.cli import main
from stdm_drake.data.dataset import load_dataset
from stdm_drake.dynamics.model import DynamicsModel
from stdm_drake.learning.evaluate import compare_with_baselines, physics_baselines, trajectory_rollout_data
from stdm_drake.learning.learned_model import LearnedModel
from stdm_drake.dynamics.physics import ConstantVelocity, NominalAcceleration, PlantModel, StaysPut
from stdm_drake.learning.settings import TrainingConfig
from stdm_drake.learning.structure import DEFAULT, PAPER, ModelStructure
from stdm_drake.learning.problem import training_problem
from stdm_drake.learning.alpha_selection import fit_model


@pytest.fixture(scope="module")
def excitation(tmp_path_factory):
    """40 trajectories of the default excitation protocol (seed 7)."""
    path = tmp_path_factory.mktemp("excitation") / "excitation.h5"
    assert main(["collect", "--protocol", "excitation", "--count", "40", "--seed", "7", "-o", str(path),
                 "--quiet"]) == 0
    return load_dataset(path)


def trained(dataset, structure, *, epochs=150, seed=0):
    split = dict(train=list(range(20)), val=list(range(20, 30)), test=list(range(30, 40)))
    problem = training_problem(dataset, split, model_type="D", structure=structure, robot=UR10)
    result, _ = fit_model(problem.model_config, TrainingConfig(seed=seed, max_epochs=epochs), problem.train,
                          problem.val)
    return LearnedModel(result.model, name=structure.label, robot=UR10, structure=structure, sample_period=dataset.sample_period)


@pytest.mark.slow
def test_the_default_model_learns_and_the_paper_black_box_does_not(excitation):
    """On 20 training trajectories the default structure beats the Euler step (q) and "v unchanged" (v)
    by >= 3x on held-out trajectories; the paper's black box on the same data fails the 2x gate."""
    test = list(range(30, 40))
    transitions = excitation.transitions(test)
    rollouts = trajectory_rollout_data(excitation, test, 20)
    baselines = physics_baselines(excitation.sample_period, 12, 6, plant=False)
    default, = compare_with_baselines([trained(excitation, DEFAULT)] + baselines, transitions, rollouts)[:1]
    assert default.ratio_q >= 3 and default.ratio_v >= 3, (default.ratio_q, default.ratio_v)
    assert default.verdict == "learned"
    paper, = compare_with_baselines([trained(excitation, PAPER)] + baselines, transitions, rollouts)[:1]
    assert paper.verdict == "has not learned the dynamics", (paper.ratio_q, paper.ratio_v)


@pytest.mark.slow
@pytest.mark.parametrize("structure", [ModelStructure("velocity", "nominal_acceleration"),
                                       ModelStructure("state", "nominal_acceleration"),
                                       ModelStructure("velocity", "raw"), PAPER])
def test_structured_jacobians_equal_finite_differences_of_the_step(excitation, structure):
    model = trained(excitation, structure, epochs=3)
    transitions = excitation.transitions([31])
    x, u = transitions.state[:4], transitions.action[:4]
    A, B = model.jacobians(x, u)
    z = np.hstack([x, u])
    everything = excitation.transitions()
    spread = np.hstack([everything.state, everything.action]).std(axis=0)   # wrist torques: ~1e-4 N m
    numeric = np.empty((len(x), 12, 18))
    for j in range(18):
        step = 1e-2 * spread[j]      # small against the data's scale, large against float32 rounding
        up, down = z.copy(), z.copy()
        up[:, j] += step
        down[:, j] -= step
        numeric[:, :, j] = (model.step(up[:, :12], up[:, 12:]) - model.step(down[:, :12], down[:, 12:])) / (2 * step)
    analytic = np.concatenate([A, B], axis=2)
    scale = np.abs(numeric).max(axis=2, keepdims=True) + 1e-9     # per output row: float32 network, FD noise
    assert np.all(np.abs(analytic - numeric) <= 5e-2 * scale + 1e-4), np.abs(analytic - numeric).max()


def test_nominal_acceleration_rates_are_its_time_derivative(excitation):
    """φ̇ by AutoDiff along (q̇, q̈, τ̇) equals the central difference of φ along the same tangent, and φ
    at a sample equals the plant's recorded acceleration there."""
    features = NominalAcceleration(UR10)
    traj = excitation.trajectory(3)
    q, v, tau = traj.q_true[:5], traj.v_true[:5], traj.tau[:5]
    np.testing.assert_allclose(features.values(q, v, tau), traj.qdd[:5], rtol=1e-9, atol=1e-9)
    q_rate, v_rate, tau_rate = v, traj.qdd[:5], np.random.default_rng(0).normal(size=tau.shape)
    h = 1e-6
    numeric = (features.values(q + h * q_rate, v + h * v_rate, tau + h * tau_rate)
               - features.values(q - h * q_rate, v - h * v_rate, tau - h * tau_rate)) / (2 * h)
    np.testing.assert_allclose(features.rates(q, v, tau, q_rate, v_rate, tau_rate), numeric, rtol=1e-4, atol=1e-6)


def test_chain_rule_identity_against_the_plant(excitation):
    """Derivative learning's identity d x_{k+1}/dt = ∂x_{k+1}/∂x_k ẋ_k (torque held) holds for the plant:
    its Jacobian times the recorded [q̇_k, q̈_k] gives the recorded [q̇_{k+1}, q̈_{k+1}^-] to 1 %."""
    plant = PlantModel(excitation.sample_period, robot=UR10)
    traj = excitation.trajectory(5)
    x = np.hstack([traj.q_true, traj.v_true])
    A, _ = plant.jacobians(x[10:20], traj.tau[10:20])
    rate = np.hstack([traj.v_true[10:20], traj.qdd[10:20]])
    target = np.hstack([traj.v_true[11:21], traj.qdd_end[10:20]])
    predicted = np.einsum("kij,kj->ki", A, rate)
    assert np.linalg.norm(predicted - target) / np.linalg.norm(target) < 1e-2


def test_baselines_are_dynamics_models_with_exact_jacobians():
    x = np.random.default_rng(1).normal(size=(3, 12))
    u = np.zeros((3, 6))
    for model in (ConstantVelocity(12, 6, 0.01), StaysPut(12, 6, 0.01)):
        assert isinstance(model, DynamicsModel) and not model.learned
        A, B = model.jacobians(x, u)
        np.testing.assert_allclose(np.einsum("kij,kj->ki", A, x), model.step(x, u))
        assert not B.any()
    np.testing.assert_allclose(ConstantVelocity(12, 6, 0.01).step(x, u)[:, :6], x[:, :6] + 0.01 * x[:, 6:])
    rolled = StaysPut(12, 6, 0.01).rollout(x, np.zeros((3, 4, 6))).mean
    np.testing.assert_allclose(rolled[:, -1, :6], x[:, :6])


@pytest.mark.slow
def test_evaluate_prints_the_baselines_and_the_verdict(excitation, tmp_path, capsys):
    output = tmp_path / "run"
    assert main(["train", str(excitation.path), "-o", str(output), "--model", "D", "--train", "20", "--val", "10",
                 "--test", "10", "--epochs", "100", "--quiet"]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(output / "seed0" / "checkpoint.pt"), str(excitation.path), "--horizon", "20"]) == 0
    printed = capsys.readouterr().out
    for name in ("Euler step", "stays put", "plant"):
        assert f"\n  {name}" in printed
    assert "-> learned" in printed
    assert "next velocity, q by trapezoid, nominal-acceleration inputs" in printed


def test_the_gate_counts_a_model_at_the_noise_floor_as_learned():
    from stdm_drake.dynamics.verdict import learning_verdict
    assert learning_verdict(3.0, 2.5) == "learned"
    assert learning_verdict(1.1, 1.9) == "has not learned the dynamics"
    assert learning_verdict(1.1, 1.9, floor_ratio_q=1.3, floor_ratio_v=1.0) == "learned (at the noise floor)"
    assert learning_verdict(1.1, 1.9, floor_ratio_q=1.6, floor_ratio_v=1.0) == "has not learned the dynamics"
    # worse than the baseline, within 1.5x of the floor: not learned (the floor counts only for a model that beats it)
    assert learning_verdict(0.9, 2.5, floor_ratio_q=1.2) == "has not learned the dynamics"
    # a "floor" 10x above 'v unchanged''s MSE (a sensor's moving average over a torque dithered every sample; the
    # deploy guide's data): the model is 1.2x better than 'v unchanged' and at 0.07x of it, but that is no floor
    assert learning_verdict(2.5, 1.2, floor_ratio_v=0.072) == "has not learned the dynamics"
    assert learning_verdict(2.5, 1.2, floor_ratio_v=1.2) == "learned (at the noise floor)"   # the floor below v's baseline
    from stdm_drake.dynamics.verdict import floor_not_held_note
    assert "noise floor of v is above the 'v unchanged''s MSE" in floor_not_held_note(2.5, 1.2, 0.5, 0.072)
    assert floor_not_held_note(2.5, 1.2, 0.5, 1.2) == floor_not_held_note(2.5, 1.2, None, None) == ""


def test_ratios_read_as_better_or_worse_by_their_value():
    """A ratio baseline/model below 1 is the model doing worse: 0.181 reads "5.52x worse", never "0.181x better"."""
    from stdm_drake.learning.evaluate import times_better
    assert times_better(2.5) == "2.5x better" and times_better(1.0) == "1x better"
    assert times_better(0.181) == "5.52x worse" and times_better(0.5) == "2x worse"
    assert times_better(float("inf")) == "infinitely better" and times_better(0.0) == "infinitely worse"
    assert times_better(float("nan")) == "not comparable (NaN)"


def test_a_derivative_checkpoint_that_kept_naive_training_is_named_for_it():
    """A DD whose alpha grid kept alpha 0 trained like a D: tables call it "DD-naive"; a DD at alpha > 0 and a
    D stay as they are."""
    import types
    from stdm_drake.learning.learned_model import trained_name

    def checkpoint(model_type, alpha):
        return types.SimpleNamespace(metadata=types.SimpleNamespace(model_type=model_type),
                                     training_config=types.SimpleNamespace(alpha=alpha))
    assert trained_name(checkpoint("DD", 0.0)) == "DD-naive" and trained_name(checkpoint("PED", 0.0)) == "PED-naive"
    assert trained_name(checkpoint("DD", 1e-3)) == "DD" and trained_name(checkpoint("D", 0.0)) == "D"
    assert trained_name(checkpoint("GD", 0.0)) == "GD-naive" and trained_name(checkpoint(None, 0.0)) == "model"


def test_a_model_named_for_its_type_takes_its_trained_name(monkeypatch):
    """`mpc --model DD=FILE` on a DD whose alpha grid kept naive training names it "DD-naive" in the tables (the
    newcomer pass saw plain "DD" in mpc.md while `view` said "DD-naive"); any other name is the user's."""
    import types
    from stdm_drake.learning import learned_model
    monkeypatch.setattr(learned_model, "LearnedModel", lambda checkpoint, name, robot, **options:
                        types.SimpleNamespace(name=name))
    kept_naive = types.SimpleNamespace(metadata=types.SimpleNamespace(model_type="DD"),
                                       training_config=types.SimpleNamespace(alpha=0.0))
    assert learned_model.checkpoint_model(kept_naive, None, name="DD").name == "DD-naive"
    assert learned_model.checkpoint_model(kept_naive, None).name == "DD-naive"
    assert learned_model.checkpoint_model(kept_naive, None, name="mine").name == "mine"


@pytest.mark.slow
def test_noise_floor_is_that_of_the_sensor_model(tmp_path):
    """White velocity noise σ through a w-sample moving average: the floor is 2σ²/w² (a model that knows the
    true change of state still misses the sample entering and the one leaving the average); 0 for the
    ideal sensor."""
    from stdm_drake.data.inspect import noise_floor
    path = tmp_path / "tracking.h5"
    assert main(["collect", "--count", "8", "--seed", "2", "--workers", "1", "--quiet", "-o", str(path)]) == 0
    floor = noise_floor(load_dataset(path))
    sigma_v, sigma_q, window = 0.02, 2e-4, 4                  # controllers/sensor.yaml
    # 10 % above 2σ²/w²: the average starts with fewer samples in each trajectory's first w - 1 steps
    assert floor["v"] == pytest.approx(2 * sigma_v ** 2 / window ** 2, rel=0.15)
    assert floor["q"] == pytest.approx(2 * sigma_q ** 2, rel=0.1)


def test_noise_floor_of_an_ideal_sensor_is_zero(excitation):
    from stdm_drake.data.inspect import noise_floor
    assert noise_floor(excitation) == {"q": 0.0, "v": 0.0}


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["default", "euler"])
def test_the_leaf_system_steps_any_dynamics_model_as_its_rollout(excitation, kind):
    """LearnedDynamicsSystem takes any DynamicsModel: a physics-structured network (its features from
    Drake inside a Drake diagram) and a baseline; 10 steps under held torques equal the model's rollout. The system
    steps the network by numpy and the rollout runs the compiled core: two implementations of a float32 network,
    whose sums round differently with the CPU (at most a few 1e-7 over 100 steps: BENCHMARKS.md, "Open-loop
    rollout"), so equal here means to 1e-6 rad or rad/s (a velocity near 0.005 rad/s differed by 4e-8 on one CPU,
    1.4e-6 of itself)."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import TrajectorySource
    from pydrake.trajectories import PiecewisePolynomial

    from stdm_drake.closed_loop.learned_system import LearnedDynamicsSystem
    model = trained(excitation, DEFAULT, epochs=5) if kind == "default" else ConstantVelocity(12, 6, 0.01)
    traj = excitation.trajectory(33)
    x0, torques = np.concatenate([traj.q[0], traj.v[0]]), traj.tau[:10]
    times = np.arange(11) * model.sample_period
    builder = DiagramBuilder()
    system = builder.AddSystem(LearnedDynamicsSystem(model))
    source = builder.AddSystem(TrajectorySource(PiecewisePolynomial.ZeroOrderHold(
        times, np.vstack([torques, torques[-1:]]).T)))
    builder.Connect(source.get_output_port(), system.get_torque_input_port())
    simulator = Simulator(builder.Build())
    context = system.GetMyContextFromRoot(simulator.get_mutable_context())
    system.set_initial_state(context, x0)
    simulator.Initialize()
    states = []
    for k in range(1, 11):
        simulator.AdvanceTo(times[k])
        states.append(system.get_state_output_port().Eval(context).copy())
    expected = model.rollout(x0[None], torques[None]).mean[0]
    np.testing.assert_allclose(np.array(states), expected, rtol=1e-6, atol=1e-6)


def test_the_rk4_plant_model_steps_close_to_the_simulator(excitation):
    """The plant model for control (RK4 steps of the continuous dynamics) against the simulator's discrete
    plant on recorded (x, u) of the excitation data (no contact): velocity errors far below the one-step
    change. (Its Jacobians are exact: tests/test_realtime_dynamics.py.)"""
    rk4 = PlantModel(excitation.sample_period, robot=UR10, integrator="rk4")
    plant = PlantModel(excitation.sample_period, robot=UR10)
    transitions = excitation.transitions([2, 3])
    x, u = transitions.state[::10], transitions.action[::10]
    exact = plant.step(x, u)
    change = np.abs(exact - x)[:, 6:].mean()
    assert np.abs(rk4.step(x, u) - exact)[:, 6:].mean() < 0.05 * change


class _Pendulums(DynamicsModel):
    """Test model: n independent pendulums, one explicit Euler step (exact Jacobians, nonlinear in q)."""
    name, state_dim, action_dim, sample_period = "pendulums", 4, 2, 0.01

    def step(self, x, a):
        q, v = x[:, :2], x[:, 2:]
        return np.hstack([q + self.sample_period * v, v + self.sample_period * (a - 9.81 * np.sin(q))])

    def jacobians(self, x, a):
        h, q = self.sample_period, x[:, :2]
        A = np.broadcast_to(np.eye(4), (len(x), 4, 4)).copy()
        A[:, :2, 2:] += h * np.eye(2)
        A[:, 2:, :2] -= h * 9.81 * np.cos(q)[:, :, None] * np.eye(2)
        B = np.zeros((len(x), 4, 2))
        B[:, 2:, :] = h * np.eye(2)
        return A, B


def test_held_input_substeps_chain_the_inner_steps_and_their_jacobians():
    from stdm_drake.dynamics.model import HeldInputSubsteps
    inner = _Pendulums()
    model = HeldInputSubsteps(inner, 3)
    assert model.sample_period == pytest.approx(0.03) and model.state_dim == 4 and model.action_dim == 2
    rng = np.random.default_rng(0)
    x, a = rng.normal(size=(5, 4)), rng.normal(size=(5, 2))
    np.testing.assert_array_equal(model.step(x, a), inner.step(inner.step(inner.step(x, a), a), a))
    A, B = model.jacobians(x, a)
    z, eps = np.hstack([x, a]), 1e-6
    numeric = np.empty((5, 4, 6))
    for j in range(6):
        up, down = z.copy(), z.copy()
        up[:, j] += eps
        down[:, j] -= eps
        numeric[:, :, j] = (model.step(up[:, :4], up[:, 4:]) - model.step(down[:, :4], down[:, 4:])) / (2 * eps)
    np.testing.assert_allclose(np.concatenate([A, B], axis=2), numeric, atol=1e-8)
    with pytest.raises(Exception, match="substeps must be an integer >= 1"):
        HeldInputSubsteps(inner, 0)


def test_two_half_period_plant_steps_are_one_full_period_step(excitation):
    """The recorder holds the torque for the whole period, so the plant at Δt/2 run twice with the same
    torque is the plant at Δt: what lets a model trained at half the period be tested on Δt data."""
    from stdm_drake.dynamics.model import HeldInputSubsteps
    transitions = excitation.transitions([5])
    x, u = transitions.state[::7], transitions.action[::7]
    halves = HeldInputSubsteps(PlantModel(excitation.sample_period / 2, robot=UR10), 2)
    np.testing.assert_allclose(halves.step(x, u), PlantModel(excitation.sample_period, robot=UR10).step(x, u), rtol=0, atol=1e-9)
    np.testing.assert_allclose(halves.step(x, u), transitions.next_state[::7], atol=1e-9)


def colliding_state():
    """A state of the UR-10 whose links interpenetrate (the self-collision check's first hit from home), at rest,
    and the torque that holds it against gravity."""
    from stdm_drake.robots.plant import Dynamics, SelfCollisionChecker
    checker, rng = SelfCollisionChecker(UR10), np.random.default_rng(0)
    for _ in range(2000):
        q = UR10.home + rng.uniform(-2.5, 2.5, 6)
        if not checker.is_collision_free(q):
            return np.concatenate([q, np.zeros(6)])[None], Dynamics(UR10).gravity_torque(q)[None]
    raise AssertionError("no colliding configuration found")


@pytest.mark.parametrize("case", ["without self-contact", "plant step 0.5 ms"])
def test_the_plant_baseline_simulates_the_plant_the_dataset_records(case):
    """Issue 55: the plant baseline stepped the default plant (self-contact on, 1 ms steps) whatever the data's, so
    the very plant that simulated a dataset was not exact on it. From the record a dataset writes it is: the same
    next state to the bit, where the default plant differs (links passing through each other; another step)."""
    from stdm_drake.data.dataset import DatasetMetadata
    from stdm_drake.robots.plant import PlantConfig
    if case == "without self-contact":
        simulated, (x, u) = PlantConfig(self_collision=False), colliding_state()
    else:
        simulated = PlantConfig.discrete(0.0005)
        x = np.concatenate([UR10.home + 0.2, 0.5 * np.ones(6)])[None]
        u = np.full((1, 6), 3.0)
    truth = PlantModel(0.01, simulated, robot=UR10).step(x, u)
    metadata = DatasetMetadata.from_record(dict(protocol="excitation", sample_period=0.01, plant=simulated.record()))
    baseline = physics_baselines(0.01, 12, 6, robot=UR10, plant_config=metadata.plant_config(effects=False))[-1]
    np.testing.assert_array_equal(baseline.step(x, u), truth)
    default = PlantModel(0.01, robot=UR10).step(x, u)           # what the baseline stepped before
    assert np.abs(default - truth).max() > 1e-9


def test_the_plant_baseline_is_exact_on_a_file_collected_at_another_plant_step(tmp_path):
    """`collect --plant-time-step 0.0005` with the ideal sensor: the plant baseline `evaluate` builds from the file
    predicts its transitions exactly (one-step MSE 0); the default plant's 1 ms steps do not."""
    from stdm_drake.learning.evaluate import one_step_errors
    path = tmp_path / "half.h5"
    assert main(["collect", "--protocol", "excitation", "--count", "1", "--seed", "2", "--plant-time-step", "0.0005",
                 "--sensor", "stdm-drake:controllers/sensor_ideal.yaml", "-o", str(path), "--quiet"]) == 0
    dataset = load_dataset(path)
    transitions = dataset.transitions([0])
    plant = physics_baselines(dataset.sample_period, 12, 6, robot=UR10,
                              plant_config=dataset.metadata.plant_config(effects=False))[-1]
    exact = one_step_errors(plant, transitions.state, transitions.action, transitions.next_state)
    assert exact.angle_mse == 0.0 and exact.velocity_mse == 0.0
    default = one_step_errors(PlantModel(dataset.sample_period, robot=UR10), transitions.state, transitions.action,
                              transitions.next_state)
    assert default.angle_mse > 1e-14


def test_the_alpha_plot_stars_naive_on_its_line_and_shows_the_rule(tmp_path, monkeypatch):
    """alpha_selection.png: a kept naive choice is starred on naive's dashed line (not at the smallest alpha's
    point of the curve), and a second panel draws each alpha's 95 % lower bound of its gain over naive with the
    rule in its title."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from stdm_drake.learning.alpha_selection import AlphaSelection
    from stdm_drake.learning.train_outputs import plot_alpha_selection
    figures = []
    monkeypatch.setattr(plt, "close", lambda figure: figures.append(figure))
    naive = AlphaSelection(alphas=(0.0, 1e-6, 1e-2), val_mse=[0.10, 0.30, 0.05], best_epochs=[5, 5, 5], index=0,
                           gain_low=[0.0, -0.5, -0.01])
    plot_alpha_selection(naive, tmp_path / "naive.png")
    assert (tmp_path / "naive.png").read_bytes().startswith(b"\x89PNG")
    top, rule = figures[-1].axes
    (star,) = [line for line in top.get_lines() if line.get_marker() == "*"]
    assert star.get_ydata()[0] == 0.10 and star.get_label() == "chosen: naive (alpha 0)"
    assert "above 0" in rule.get_title() and list(rule.get_lines()[0].get_ydata()) == [-50.0, -1.0]
    chosen = AlphaSelection(alphas=(0.0, 1e-6, 1e-2), val_mse=[0.10, 0.30, 0.05], best_epochs=[5, 5, 5], index=2,
                            gain_low=[0.0, -0.5, 0.2])
    plot_alpha_selection(chosen, tmp_path / "chosen.png")
    (star,) = [line for line in figures[-1].axes[0].get_lines() if line.get_marker() == "*"]
    assert (star.get_xdata()[0], star.get_ydata()[0]) == (1e-2, 0.05)
    plot_alpha_selection(AlphaSelection(alphas=(1e-3, 1e-2), val_mse=[0.2, 0.1], best_epochs=[1, 1], index=1),
                         tmp_path / "fixed.png")
    assert len(figures[-1].axes) == 1      # no naive in the grid: no rule panel
