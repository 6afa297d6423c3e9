"""Sampling MPC (CEM, iCEM, MPPI): the batched particle rollouts are the model's own rollouts, PyTorch and NumPy
agree, the optimizers lower the cost within the torque limits, the same seed gives the same torques, bad
settings are one line before any work, and the closed loop tracks on the UR-10."""
import dataclasses

import numpy as np
import pytest
import torch

from presets import UR10
from test_mpc import LinearModel, exact_lqr_controls, quintic_reference
from stdm_drake.cli import main
from stdm_drake.closed_loop.ancillary_law import computed_torque_law
from stdm_drake.closed_loop.mpc import MpcConfig, load_mpc_config, run_closed_loop
from stdm_drake.closed_loop.sampled_costs import SampledCosts
from stdm_drake.closed_loop.sampling import Cem, Icem, Mppi, colored_noise
from stdm_drake.errors import InputError
from stdm_drake.learning.learned_model import LearnedModel
from stdm_drake.learning.models import EnsembleMLP, ModelConfig

LIMIT = np.array([330.0, 330.0, 150.0, 56.0, 56.0, 56.0])


def network_model(members=1, probabilistic=False, seed=0):
    torch.manual_seed(seed)
    network = EnsembleMLP(ModelConfig(input_dim=18, output_dim=12, residual=True, hidden_width=32,
                                      ensemble_size=members, probabilistic=probabilistic))
    return LearnedModel(network, sample_period=0.01)


def problem(seed=1, samples=7, horizon=6):
    rng = np.random.default_rng(seed)
    return (0.3 * rng.normal(size=12), 20.0 * rng.normal(size=(samples, horizon, 6)),
            0.1 * rng.normal(size=(horizon + 1, 12)), np.zeros((horizon, 6)))


def costs_of(model, settings, x0, u, reference, u_ff, gain=None):
    cost = MpcConfig().cost(6)
    evaluate = SampledCosts(model, cost, np.full(6, 1e9), settings, np.random.default_rng(settings.seed))
    gain = np.zeros((6, 12)) if gain is None else gain
    return evaluate(x0, u, gain, reference, u_ff, np.zeros(12), keep_states=True)


def test_sampled_rollouts_of_a_single_network_equal_its_own_rollout_and_cost():
    model = network_model()
    x0, u, reference, u_ff = problem()
    costs, states = costs_of(model, Icem(), x0, u, reference, u_ff)
    own = model.rollout(np.repeat(x0[None], len(u), axis=0), u).mean           # (K, H, S)
    np.testing.assert_allclose(states[:, 0].transpose(1, 0, 2), own, rtol=1e-5, atol=1e-5)   # (float32 inside)
    solver = Icem().solver(model, MpcConfig().cost(6), np.full(6, 1e9), len(reference) - 1)
    expected = [solver.cost(np.vstack([x0, own[k]]), u[k], reference, u_ff) for k in range(len(u))]
    np.testing.assert_allclose(costs, expected, rtol=1e-6)


def test_tsinf_particles_follow_one_member_each_and_ts1_particles_one_member_per_step():
    model = network_model(members=3)
    x0, u, reference, u_ff = problem(samples=4, horizon=5)
    _, states = costs_of(model, Icem(propagation="tsinf", particles=6), x0, u, reference, u_ff)   # (H, P, K, S)
    for particle in range(6):
        member = particle // 2
        for k in range(len(u)):
            x = x0
            for step in range(u.shape[1]):
                x = model.predict(x[None], u[k, step][None]).member_means[member, 0]
                np.testing.assert_allclose(states[step, particle, k], x, rtol=1e-5, atol=1e-5)
    _, states = costs_of(model, Icem(propagation="ts1", particles=3), x0, u, reference, u_ff)
    used = set()
    for step in range(u.shape[1]):
        for particle in range(3):
            for k in range(len(u)):
                before = x0 if step == 0 else states[step - 1, particle, k]
                members = model.predict(before[None], u[k, step][None]).member_means[:, 0]
                match = np.flatnonzero(np.all(np.isclose(members, states[step, particle, k], rtol=1e-5, atol=1e-5),
                                              axis=1))
                assert len(match) == 1
                used.add(int(match[0]))
    assert used == {0, 1, 2}


def test_a_mean_propagation_takes_the_ensembles_mean_and_a_deterministic_model_ignores_particles():
    model = network_model(members=3)
    x0, u, reference, u_ff = problem(samples=3)
    _, states = costs_of(model, Icem(), x0, u, reference, u_ff)
    np.testing.assert_allclose(states[:, 0].transpose(1, 0, 2), model.rollout(np.repeat(x0[None], 3, axis=0), u).mean,
                               rtol=1e-5, atol=1e-5)
    single = network_model()
    evaluate = SampledCosts(single, MpcConfig().cost(6), LIMIT, Icem(propagation="tsinf", particles=20),
                            np.random.default_rng(0))
    assert (evaluate.propagation, evaluate.particles) == ("mean", 1)


def test_probabilistic_particles_sample_the_members_gaussian():
    model = network_model(members=1, probabilistic=True)
    x0, u, reference, u_ff = problem(samples=1, horizon=1)
    _, states = costs_of(model, Icem(propagation="tsinf", particles=4000), x0, u, reference, u_ff)
    prediction = model.predict(x0[None], u[0, :1])
    np.testing.assert_allclose(states[0, :, 0].mean(axis=0), prediction.mean[0],
                               atol=5 * np.sqrt(prediction.variance[0].max() / 4000) + 1e-9)
    np.testing.assert_allclose(states[0, :, 0].var(axis=0), prediction.variance[0], rtol=0.15)


@pytest.mark.parametrize("members, propagation, particles", [(1, "mean", 1), (3, "tsinf", 6), (3, "ts1", 3)])
@pytest.mark.parametrize("kind", [Icem, Mppi, Cem])
def test_pytorch_on_the_cpu_returns_the_numpy_torques(kind, members, propagation, particles):
    model = network_model(members=members)
    x0, _, reference, u_ff = problem(horizon=8)
    results = []
    for framework in ("numpy", "torch"):
        settings = kind(samples=32, iterations=2, propagation=propagation, particles=particles, framework=framework,
                        **({"elites": 4} if kind is not Mppi else {}))
        solver = settings.solver(model, MpcConfig().cost(6), LIMIT, 8)
        results.append(solver.solve(x0, np.zeros((8, 6)), reference, u_ff))
    np.testing.assert_allclose(results[1].u, results[0].u, rtol=1e-4, atol=1e-4 * LIMIT.max())


@pytest.mark.parametrize("kind", [Icem, Mppi, Cem])
def test_the_compiled_model_steps_return_the_numpy_torques(kind, tmp_path):
    """`implementation: compiled` (the default) steps every rollout through the compiled core's batched model:
    the paper's black box, a network of the default structure (the nominal acceleration from Pinocchio in C++)
    and the plant as a model in RK4 steps; `implementation: numpy` is the reference, the same draws from the same
    seed, so the same torques to float precision. The solver says which steps ran."""
    from test_export import synthetic_checkpoint
    from stdm_drake.closed_loop.mpc import control_step_implementation
    from stdm_drake.dynamics.physics import PlantModel
    from stdm_drake.learning.structure import DEFAULT
    models = [network_model(), LearnedModel(synthetic_checkpoint(tmp_path / "default.pt", DEFAULT), robot=UR10),
              PlantModel(0.01, robot=UR10, integrator="rk4")]
    x0, _, reference, u_ff = problem(horizon=6)
    x0[:6] += UR10.home
    reference[:, :6] += UR10.home
    for model in models:
        results, said = [], []
        for implementation in ("compiled", "numpy"):
            settings = kind(samples=24, iterations=2, implementation=implementation,
                            **({"elites": 4} if kind is not Mppi else {}))
            solver = settings.solver(model, MpcConfig().cost(6), LIMIT, 6)
            said.append(control_step_implementation(solver))
            results.append(solver.solve(x0, np.zeros((6, 6)), reference, u_ff))
        name = type(solver).__name__
        assert said == [f"numpy ({name}; the model's steps compiled)", f"numpy ({name}; the model's steps numpy)"]
        assert results[0].finite
        np.testing.assert_allclose(results[0].u, results[1].u, rtol=1e-6, atol=1e-6 * LIMIT.max())
        np.testing.assert_allclose(results[0].cost, results[1].cost, rtol=1e-6)


def test_what_the_compiled_core_does_not_cover_steps_on_numpy_and_says_so():
    from stdm_drake.closed_loop.mpc import control_step_implementation
    solver = Icem().solver(LinearArm(), MpcConfig().cost(6), LIMIT, 5)
    assert control_step_implementation(solver) == (
        "numpy (IcemSolver; the model's steps numpy: the compiled core does not cover a LinearArm)")
    with pytest.raises(InputError, match="implementation must be one of compiled, numpy, got 'C'"):
        Icem(implementation="C").validate()


class LinearArm(LinearModel):
    """Six coupled joints, a double integrator each at 10 ms holds: x_next = A x + B u with B = [dt^2/2 M^-1;
    dt M^-1] for an inertia M whose joints span 0.01 to 4 kg m^2 (a mechanism: the law inverts its B_v)."""

    def __init__(self, seed=0):
        rng = np.random.default_rng(seed)
        root = rng.normal(size=(6, 6)) * 0.05 + np.diag(np.sqrt(np.geomspace(4.0, 0.01, 6)))
        inverse = np.linalg.inv(root @ root.T)
        dt = self.sample_period
        self.A = np.block([[np.eye(6), dt * np.eye(6)], [np.zeros((6, 6)), np.eye(6)]])
        self.B = np.vstack([0.5 * dt ** 2 * inverse, dt * inverse])


@pytest.mark.parametrize("settings", [Icem(samples=200, iterations=4), Cem(samples=200, iterations=4, elites=20),
                                      Mppi(samples=200, iterations=4, temperature=1.0)])
def test_each_optimizer_lowers_the_cost_towards_the_optimum_within_the_limits(settings):
    model = LinearArm()
    config = dataclasses.replace(MpcConfig(), horizon=10)
    rng = np.random.default_rng(3)
    x0, u_ff = 0.05 * rng.normal(size=12), np.zeros((10, 6))
    reference = np.hstack([np.zeros((11, 6)), np.outer(np.linspace(0, 1, 11), np.full(6, 0.5))])
    cost = config.cost(6)
    solver = settings.solver(model, cost, np.full(6, 1e4), 10)
    law = dataclasses.replace(settings, noise_std=1e-12).solver(model, cost, np.full(6, 1e4), 10)
    law_only = law.solve(x0, u_ff, reference, u_ff).cost
    lqr = exact_lqr_controls(model, config, x0, reference, u_ff)
    optimum = solver.cost(solver.rollout(x0, lqr), lqr, reference, u_ff)
    result = solver.solve(x0, u_ff, reference, u_ff)
    # one solve of 4 iterations closes 7-15 % of the law's gap to the optimum on this arm (the closed loop keeps
    # the residuals from step to step)
    assert result.finite and optimum <= result.cost < law_only - 0.05 * (law_only - optimum)
    tight = settings.solver(model, cost, np.full(6, 0.5), 10).solve(x0, u_ff, reference, u_ff)
    assert np.all(np.abs(tight.u) <= 0.5 + 1e-12)


def test_the_same_seed_gives_the_same_torques_and_another_seed_others():
    model = network_model(members=3, probabilistic=True)
    x0, _, reference, u_ff = problem(horizon=8)

    def solve(seed):
        settings = Icem(samples=40, iterations=2, elites=5, propagation="ts1", particles=3, seed=seed)
        return settings.solver(model, MpcConfig().cost(6), LIMIT, 8).solve(x0, np.zeros((8, 6)), reference, u_ff).u

    np.testing.assert_array_equal(solve(0), solve(0))
    assert not np.array_equal(solve(0), solve(1))


def test_colored_noise_has_unit_variance_and_more_low_frequency_power():
    rng = np.random.default_rng(0)
    for horizon in (7, 20):
        white, colored = colored_noise(rng, 20000, horizon, 2, 0.0), colored_noise(rng, 20000, horizon, 2, 2.0)
        np.testing.assert_allclose(white.var(axis=0), 1.0, rtol=0.05)
        np.testing.assert_allclose(colored.var(axis=0), 1.0, rtol=0.05)
        step = lambda noise: np.mean(np.diff(noise, axis=1) ** 2)   # noqa: E731
        assert step(colored) < 0.7 * step(white)


@pytest.mark.parametrize("text, message", [
    ("optimizer: !Icem {samples: 0}\n", "mpc optimizer !Icem samples must be an integer in 1..100000, got 0"),
    ("optimizer: !Cem {samples: 50, elites: 60}\n", "mpc optimizer !Cem elites must be an integer in 1..50"),
    ("optimizer: !Mppi {temperature: -1.0}\n", "mpc optimizer !Mppi temperature must be in [1e-12, 1e+12]"),
    ("optimizer: !Icem {framework: torch, device: cuda:7}\n", "mpc optimizer !Icem device 'cuda:7'"),
    ("optimizer: !Icem {framework: torch, device: gpu}\n", "device 'gpu' is not a PyTorch device"),
    ("optimizer: !Icem {device: cuda}\n", "device 'cuda' needs `framework: torch`"),
    ("optimizer: !Mppi {propagation: ts2}\n", "propagation must be one of mean, ts1, tsinf"),
    ("optimizer: !Icem {noise_std: 0.0}\n", "noise_std must be in [1e-12, 10000] rad/s^2"),
    # settings that mean nothing (issue 56): a spread that only clips, what `propagation: mean` would ignore
    ("optimizer: !Icem {noise_std: 1.0e+300}\n", "noise_std must be in [1e-12, 10000] rad/s^2"),
    ("optimizer: !Icem {particles: 5}\n", "optimizer !Icem's particles needs `propagation: ts1` or `tsinf`"),
    ("optimizer: !Icem {samples: \"100\"}\n", "optimizer.samples is '100' in quotes, not a number; write the number without quotes"),
    ("horizon: '20'\n", "horizon is '20' in quotes, not a number"),
    ("position_weight: [1.0e4, '10']\n", "position_weight is '10' in quotes"),
    ("optimizer: !Mppi {propagation: mean, variance_weight: 1.0}\n", "optimizer !Mppi's variance_weight needs `propagation: ts1`"),
    ("optimizer: !Icem {population_decay: 0.5}\n", "population_decay must be in [1, 5]"),
    ("optimizer: !Pets {}\n", "unknown optimizer !Pets; the MPC's optimizers are !Rti, !Ilqr, !Icem, !Mppi, !Cem"),
    ("optimizer: !Ilqr {line_search: [" + ", ".join(["0.5"] * 31) + "]}\n", "line_search lists 31 steps, at most 30"),
])
def test_bad_sampling_settings_are_one_line(tmp_path, text, message):
    path = tmp_path / "mpc.yaml"
    path.write_text(text)
    with pytest.raises(InputError) as error:
        load_mpc_config(path).validate()
    assert message in str(error.value) and "\n" not in str(error.value)


@pytest.mark.parametrize("kp, kd", [(225.0, 30.0), (2.0e4, 150.0), (3.0e4, 151.0), (225.0, 199.0), (0.0, 30.0),
                                     (3.0e4, 149.0), (3.0e4, 30.0), (225.0, 0.0), (3.9e4, 199.0), (225.0, 201.0)])
def test_the_law_is_refused_exactly_where_its_closed_loop_grows_on_a_held_torque_arm(kp, kd):
    """Held-out run 32: kp 30,000-39,999 1/s² passed the old bound (kp h² < 4) and made the rollouts diverge. On a
    double integrator under held torques (`LinearArm`, h = 10 ms) the law's own closed loop, run for 2000 periods
    from a 0.1 rad error, stays within it where `check_law_stable` accepts the gains and grows where it refuses them."""
    model, n = LinearArm(), 6
    settings = Mppi(feedback_kp=kp, feedback_kd=kd)
    try:
        solver = settings.solver(model, MpcConfig().cost(n), np.full(n, 1e9), 5)
    except InputError as error:
        refused = str(error)
        assert "\n" not in refused and "unstable at the model's period 0.01 s" in refused
    else:
        refused = None
    x = np.hstack([np.full(n, 0.1), np.zeros(n)])
    with np.errstate(all="ignore"):
        for _ in range(2000):
            _, gain, _ = computed_torque_law(model.A @ x, model.B, x, np.zeros((2, 2 * n)), np.zeros((1, n)),
                                             np.zeros(2 * n), settings, model.sample_period, n)
            x = model.A @ x + model.B @ (gain @ -x)
    held = np.abs(x[:n]).max() <= 0.1 * (1 + 1e-9)
    assert (refused is None) == held, (refused, np.abs(x[:n]).max())
    if refused is None:
        assert solver.settings.feedback_kp == kp


def test_the_law_is_described_against_the_defaults_by_its_error_map():
    """A failing loop's line describes a sampler's law by its held-torque error map: spectral radius and, where the
    dominant eigenvalue is negative, an error changing sign each period (held-out run 39: kp 35,000, kd 199 at 10 ms,
    radius 0.872, inside the defaults' 0.886, rang at the Nyquist frequency and left the limits)."""
    from stdm_drake.closed_loop.ancillary_law import law_radius
    from stdm_drake.closed_loop.failure_causes import default_law, law_description
    from stdm_drake.closed_loop.rti import Rti
    assert law_radius(225.0, 30.0, 0.01) == pytest.approx(0.8858, abs=1e-4)
    assert law_radius(2e4, 150.0, 0.01) == pytest.approx(np.sqrt(0.5))
    assert law_description(Mppi(feedback_kp=35000.0, feedback_kd=199.0), 0.01) == (
        "the sampler's law (feedback_kp 35000 1/s², feedback_kd 199 1/s; spectral radius 0.872 of its held-torque error "
        "map at the model's period 0.01 s, its error changing sign each period; the defaults' kp 225, kd 30: 0.886)")
    assert "changing sign" not in law_description(Mppi(feedback_kp=3000.0, feedback_kd=30.0), 0.01)   # (0.922)
    assert "spectral radius 0.9996 " in law_description(Icem(feedback_kp=3e4, feedback_kd=199.99), 0.01)   # (not "1")
    assert default_law(Mppi()) is None and default_law(Rti()) is None
    assert default_law(Icem(feedback_kp=3e4, feedback_kd=199.99, samples=50)) == Icem(samples=50)


def test_the_failure_line_names_what_the_checks_show(monkeypatch):
    """Where no plant model held the limits, the failing plans are run again and the line names what they show:
    with the plant model where the run left it out (`--no-plant`: it holds, so the learned model is why; held-out run
    39), under the defaults' law where a sampler ran another (it holds, so the law is why; held-out run 39: radius
    0.872 inside the defaults' named nothing), or neither (the MPC's settings, the plans or the plant). A plant model
    that held the limits in the run, or gravity beyond an effort limit, needs no check."""
    from types import SimpleNamespace
    from stdm_drake.closed_loop import failure_causes
    from stdm_drake.closed_loop.comparison import ClosedLoopResult, closed_loop_failures
    from stdm_drake.closed_loop.rti import Rti

    def run(name, violations):
        return ClosedLoopResult(name, 0, 1.0, 1.0, 1.0, 1.0, limit_violations=violations, fallbacks=0,
                                constraint_active_steps=0, slack_steps=0, solve_ms_mean=1.0, solve_ms_p95=1.0, steps=100,
                                q_error=[])
    checks = []

    def lines(results, models, optimizer, outcomes, **clauses):
        """The failure lines, with each check (in order) leaving the limits on the steps `outcomes` gives."""
        checks.clear()
        scripted = iter(outcomes)
        monkeypatch.setattr(failure_causes, "check_model", lambda *arguments: SimpleNamespace(name="plant"))
        monkeypatch.setattr(failure_causes, "_failed_steps",
                            lambda model, plans, config, *rest: checks.append(config.optimizer) or next(scripted))
        causes = failure_causes.loop_causes(results, models, [(0, None)], MpcConfig(optimizer=optimizer), None, None,
                                            0.01, learned_models=[SimpleNamespace(name=model["name"]) for model in models
                                                                  if model["kind"] != "plant"], **clauses)
        return closed_loop_failures(results, note=causes.note, model_notes=causes.model_notes)

    plant, learned = dict(name="plant", kind="plant"), dict(name="D", kind="D")
    ringing = Mppi(feedback_kp=35000.0, feedback_kd=199.0)
    model_is_why = ", so this model is not accurate enough for the closed loop (train's one-step verdict is no closed-loop one)"
    assert lines([run("plant", 0), run("D", 97)], [plant, learned], ringing, []) == [
        "model D left the robot's joint limits on 97 of 100 steps (1 of 1 plans); the MPC with the plant model held "
        "the limits on the same plans" + model_is_why] and checks == []
    assert lines([run("D", 97)], [learned], Rti(), [0]) == [
        "model D left the robot's joint limits on 97 of 100 steps (1 of 1 plans); the same MPC with the plant model "
        "held the limits on these plans (a check run once the loops had failed)" + model_is_why] and checks == [Rti()]
    settings_are_why = ", so the MPC's settings (--config), the plans or the plant are why, not a learned model's accuracy"
    assert lines([run("D", 97)], [learned], Rti(), [40], effects="the loops ran with X") == [
        "model D left the robot's joint limits on 97 of 100 steps (1 of 1 plans); the loops ran with X; the same MPC with "
        "the plant model left the limits too (40 steps, a check run once the loops had failed)" + settings_are_why]
    law = failure_causes.law_description(ringing, 0.01)
    law_is_why = (f"{law} makes the loops leave the robot's limits: under the defaults' law the same MPC with the plant "
                  "model held them on these plans; use the defaults, or gains that settle like them")
    assert lines([run("plant", 78)], [plant], ringing, [0]) == [
        f"model plant left the robot's joint limits on 78 of 100 steps (1 of 1 plans); {law_is_why}"] and \
        checks == [Mppi()]
    # (held-out run 40: a poor model under a ringing law; the plant model holds the limits under the defaults' law,
    # the model does not: both are named on its line, the law alone where the model holds them under the defaults')
    assert lines([run("D", 97)], [learned], ringing, [30, 0, 12]) == [
        "model D left the robot's joint limits on 97 of 100 steps (1 of 1 plans); under the defaults' law too this "
        "model's loops failed where the plant model held the limits (a check run once the loops had failed)" + model_is_why +
        f"; {law_is_why}"] and checks == [ringing, Mppi(), Mppi()]
    fallback_only = dataclasses.replace(run("D", 0), fallbacks=100)   # (held-out run 41: a row that only fell back)
    assert lines([fallback_only], [learned], ringing, [30, 0, 81]) == [
        "model D fell back to gravity compensation on 100 of 100 steps (its predictions were not finite); its row is "
        "not a result; under the defaults' law too this model's loops failed where the plant model held the limits (a "
        "check run once the loops had failed)" + model_is_why + f"; {law_is_why}"]
    assert lines([run("D", 97)], [learned], ringing, [30, 0, 0]) == [
        f"model D left the robot's joint limits on 97 of 100 steps (1 of 1 plans); {law_is_why}"]
    assert lines([run("D", 97)], [learned], ringing, [50, 60]) == [
        "model D left the robot's joint limits on 97 of 100 steps (1 of 1 plans); the same MPC with the plant model "
        "left the limits too (50 steps, a check run once the loops had failed) and the plant model left the limits "
        f"under the defaults' law too, not only under {law}" + settings_are_why] and checks == [ringing, Mppi()]
    assert lines([run("plant", 5), run("D", 97)], [plant, learned], Rti(), []) == [
        f"model {name} left the robot's joint limits on {steps} of 100 steps (1 of 1 plans); the plant model's own loops "
        "left the limits too under this MPC" + settings_are_why for name, steps in (("plant", 5), ("D", 97))]
    assert lines([run("plant", 5)], [plant], Rti(), []) == [
        "model plant left the robot's joint limits on 5 of 100 steps (1 of 1 plans); with the robot's own dynamics as "
        "the MPC's model: the MPC's settings (--config) or the plans are why"]
    assert lines([run("D", 97)], [learned], ringing, [], gravity="gravity beyond X") == [
        "model D left the robot's joint limits on 97 of 100 steps (1 of 1 plans); gravity beyond X"] and checks == []


@pytest.mark.slow
def test_mpc_names_a_ringing_law_and_a_model_run_without_the_plant(tracking_dataset, tmp_path, capsys):
    """Held-out run 39's two kinds, through the command: MPPI whose law rings (kp 35,000, kd 199 at 10 ms) left the
    limits with the plant as its model and named nothing; a model trained for one epoch, run with --no-plant, left them
    and named nothing. Each line now names the cause its check shows."""
    settings = tmp_path / "mpc.yaml"
    settings.write_text("optimizer: !Mppi {samples: 50, feedback_kp: 35000.0, feedback_kd: 199.0}\n")
    capsys.readouterr()
    assert main(["mpc", str(tracking_dataset), "--plans", "1", "--config", str(settings), "--quiet",
                 "-o", str(tmp_path / "law")]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("stdm-drake mpc: error: model plant left the robot's joint limits") and line.endswith(
        "makes the loops leave the robot's limits: under the defaults' law the same MPC with the plant model held them "
        "on these plans; use the defaults, or gains that settle like them"), line
    assert main(["train", str(tracking_dataset), "--model", "D", "--epochs", "1", "--per-group", "off", "--quiet",
                 "-o", str(tmp_path / "weak")]) == 0
    capsys.readouterr()
    assert main(["mpc", str(tracking_dataset), "--no-plant", "--model", f"W={tmp_path / 'weak' / 'seed0' / 'checkpoint.pt'}",
                 "--plans", "1", "--quiet", "-o", str(tmp_path / "model")]) == 2
    line = capsys.readouterr().err.strip().splitlines()[0]   # (then its fallbacks' line, with the same cause)
    assert line.startswith("stdm-drake mpc: error: model W left the robot's joint limits") and line.endswith(
        "the same MPC with the plant model held the limits on these plans (a check run once the loops had failed)"
        ", so this model is not accurate enough for the closed loop (train's one-step verdict is no closed-loop one)"), line


def test_work_beyond_the_sampling_budget_is_refused_before_it_starts():
    """Horizon 1000 with 100,000 samples (issue 56: a memory traceback after minutes): one line with the estimate
    when the solver is made, before any rollout; the largest budgeted size is accepted."""
    with pytest.raises(InputError, match=r"samples 100000 x horizon 1000 x 6 joints = 600,000,000 values per array "
                                         r"\(about 4.8 GB each"):
        Icem(samples=100_000).solver(network_model(), MpcConfig().cost(6), LIMIT, 1000)
    Icem(samples=100_000).solver(network_model(), MpcConfig().cost(6), LIMIT, 83)


def test_trajectory_sampling_asked_of_one_deterministic_network_runs_as_mean_and_says_so():
    """One MPC settings file serves every model `mpc` compares: with tsinf particles, a PE samples its members
    while a single network (or the plant) can only roll out its mean; its solver says so where `mpc` prints which
    step ran (issue 56: it was silent), and an ensemble's says nothing."""
    from stdm_drake.closed_loop.mpc import control_step_implementation
    settings = Icem(propagation="tsinf", particles=5, variance_weight=1.0)
    single = settings.solver(network_model(), MpcConfig().cost(6), LIMIT, 5)
    assert single.costs.propagation == "mean" and single.costs.particles == 1
    assert control_step_implementation(single) == (
        "numpy (IcemSolver; the model's steps compiled; propagation tsinf with 5 particles runs as mean: "
        f"{network_model().name} has one deterministic member)")
    ensemble = settings.solver(network_model(members=5), MpcConfig().cost(6), LIMIT, 5)
    assert ensemble.costs.particles == 5
    assert control_step_implementation(ensemble) == "numpy (IcemSolver; tsinf member steps numpy)"


def test_particles_must_split_evenly_over_the_members():
    with pytest.raises(InputError, match=r"particles \(4\) must be a multiple of the model's 3 ensemble members"):
        Icem(propagation="tsinf", particles=4).solver(network_model(members=3), MpcConfig().cost(6), LIMIT, 5)


def test_the_command_refuses_bad_sampling_settings_before_any_work(tracking_dataset, tmp_path, capsys):
    path = tmp_path / "mpc.yaml"
    path.write_text("optimizer: !Icem {samples: 10, elites: 11}\n")
    capsys.readouterr()
    assert main(["mpc", str(tracking_dataset), "--plans", "1", "--config", str(path), "-o", str(tmp_path / "m")]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "elites must be an integer in 1..10" in error and "Traceback" not in error
    assert not (tmp_path / "m").exists()


@pytest.mark.slow
@pytest.mark.parametrize("settings", [Icem(), Mppi(temperature=10.0)])
def test_sampling_mpc_with_the_plant_tracks_a_move_of_the_ur10(settings):
    """The UR-10 with its plant as the model: a 0.1 rad quintic move of every joint in 0.3 s tracked within
    0.01 rad RMS, no fallback (the RTI, exact on this model, tracks to about 3e-4 rad)."""
    from stdm_drake.dynamics.physics import PlantModel
    model = PlantModel(0.01, robot=UR10, integrator="rk4")
    reference = quintic_reference(30)
    log = run_closed_loop(model, reference, dataclasses.replace(load_mpc_config(), optimizer=settings), robot=UR10)
    states = np.array(log.state)
    assert not any(log.fallback) and len(states) == 30
    assert np.sqrt(np.mean((states[:, :6] - reference.q[:30]) ** 2)) < 0.01


def test_the_command_refuses_a_pytorch_optimizer_for_the_plant_model_before_any_work(tracking_dataset, tmp_path, capsys):
    path = tmp_path / "mpc.yaml"
    path.write_text("optimizer: !Icem {framework: torch}\n")
    capsys.readouterr()
    assert main(["mpc", str(tracking_dataset), "--plans", "1", "--config", str(path), "-o", str(tmp_path / "m")]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "framework torch: model plant has no PyTorch particle step" in error
    assert not any((tmp_path / "m").glob("mpc.*"))


def test_icem_population_decay_is_bounded_where_it_stops_acting_and_its_default_always_loads():
    """Held-out run 30: a decay of 1e300 was run as any decay past samples / (2 elites), where the population is at its
    floor of 2 x elites after one iteration; the default (1.25) loads for any population."""
    Icem(samples=20, elites=10).validate()
    Icem(samples=20, elites=4, population_decay=2.5).validate()
    for settings in (Icem(samples=20, elites=4, population_decay=1e300), Icem(samples=20, elites=10, population_decay=1.3)):
        with pytest.raises(InputError, match="population_decay must be in"):
            settings.validate()
