"""A trained STDM in Drake: LearnedModel Jacobians, LearnedDynamicsSystem vs rollout, view, MPC CLI."""
import json

import numpy as np
import pytest
from conftest import closed_loop_status
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from presets import UR10
from stdm_drake.cli import main
from stdm_drake.data.dataset import load_dataset
from stdm_drake.errors import InputError
from stdm_drake.closed_loop.learned_system import LearnedDynamicsSystem
from stdm_drake.learning.learned_model import LearnedModel
from stdm_drake.learning.predict import predict, rollout


@pytest.fixture(scope="module")
def checkpoints(tracking_dataset, tmp_path_factory):
    """Small PE (2 members) and D models trained briefly on 5 of the tracking fixture's 8 trajectories."""
    folder = tmp_path_factory.mktemp("models")
    paths = {}
    for kind, extra in (("PE", ["--ensemble-size", "2"]), ("D", [])):
        assert main(["train", str(tracking_dataset), "-o", str(folder / kind), "--predicts", "state", "--inputs", "raw", "--model", kind, *extra,
                     "--hidden-width", "32", "--hidden-layers", "2", "--epochs", "5", "--seeds", "0",
                     "--train", "3", "--val", "2", "--test", "0", "--per-group", "off", "--quiet"]) == 0
        paths[kind] = folder / kind / "seed0" / "checkpoint.pt"
    return paths


def simulate_system(model, x0, torques, measured=None):
    """Run LearnedDynamicsSystem fed by zero-order-held torques; returns states and variances (T, 12)."""
    steps, dt = len(torques), model.sample_period
    times = np.arange(steps + 1) * dt
    builder = DiagramBuilder()
    system = builder.AddSystem(LearnedDynamicsSystem(model))
    source = builder.AddSystem(TrajectorySource(
        PiecewisePolynomial.ZeroOrderHold(times, np.vstack([torques, torques[-1:]]).T)))
    builder.Connect(source.get_output_port(), system.get_torque_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = system.GetMyContextFromRoot(simulator.get_mutable_context())
    system.set_initial_state(context, x0)
    if measured is not None:
        system.get_measured_state_input_port().FixValue(context, measured)
    states, variances = [], []
    simulator.Initialize()
    for k in range(1, steps + 1):
        simulator.AdvanceTo(k * dt)
        states.append(system.get_state_output_port().Eval(context).copy())
        if system.HasOutputPort("variance"):
            variances.append(system.get_variance_output_port().Eval(context).copy())
    return np.array(states), np.array(variances)


def test_system_trajectory_equals_rollout(checkpoints, tracking_dataset):
    model = LearnedModel(checkpoints["PE"], robot=UR10)
    traj = load_dataset(tracking_dataset).trajectory(3)
    x0 = np.concatenate([traj.q[0], traj.v[0]])
    states, variances = simulate_system(model, x0, traj.tau)
    expected = rollout(model.engine, x0, traj.tau)
    np.testing.assert_array_equal(states, expected.mean)
    # variances: same float32 formula, summed in another order by rollout's batched path (1e-4 observed)
    np.testing.assert_allclose(variances, expected.variance, rtol=1e-3)
    assert states.shape == (100, 12) and np.all(variances > 0)


def test_measured_state_reanchors_every_step(checkpoints, tracking_dataset):
    model = LearnedModel(checkpoints["D"], robot=UR10)
    traj = load_dataset(tracking_dataset).trajectory(0)
    measured = np.concatenate([traj.q[10], traj.v[10]])
    states, variances = simulate_system(model, np.zeros(12), traj.tau[:3], measured=measured)
    assert variances.size == 0  # a single deterministic model has no variance port
    for k in range(3):
        np.testing.assert_allclose(states[k], predict(model.engine, measured, traj.tau[k]).mean, rtol=1e-6)


def test_non_finite_torque_is_refused(checkpoints):
    model = LearnedModel(checkpoints["D"], robot=UR10)
    torques = np.zeros((3, 6))
    torques[1, 2] = np.nan
    with pytest.raises(Exception, match="non-finite torque"):
        simulate_system(model, np.zeros(12), torques)
    system = LearnedDynamicsSystem(model)
    with pytest.raises(InputError, match="initial state"):
        system.set_initial_state(system.CreateDefaultContext(), np.full(12, np.inf))


@pytest.mark.parametrize("kind", ["PE", "D"])
def test_learned_jacobians_match_finite_differences(checkpoints, kind):
    model = LearnedModel(checkpoints[kind], robot=UR10)
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.uniform(-1, 1, (4, 6)) + [0, -1.5, 1.6, -1.7, -1.5, 0], rng.normal(size=(4, 6))], 1)
    u = rng.normal(size=(4, 6)) * [5, 50, 20, 2, 0.2, 0.01]
    A, B = model.jacobians(x, u)
    engine64 = model.network  # float64 torch model: finite differences without float32 round-off
    import torch
    def mean(z):
        with torch.no_grad():
            return engine64(torch.as_tensor(z[None]))[0].mean(0)[0].numpy()
    for row in range(4):
        z = np.concatenate([x[row], u[row]])
        eps = 1e-6 * np.maximum(1.0, np.abs(z))
        J = np.stack([(mean(z + e) - mean(z - e)) / (2 * e[i]) for i, e in enumerate(np.diag(eps))], axis=1)
        # float32 Jacobians (the inference path) against float64 finite differences
        np.testing.assert_allclose(np.hstack([A[row], B[row]]), J, rtol=2e-3, atol=2e-5 * np.abs(J).max())


def test_checkpoint_of_the_wrong_size_is_rejected(tmp_path):
    from stdm_drake.learning.trainer import build_model
    from stdm_drake.learning.checkpoint import save_checkpoint
    from stdm_drake.learning.models import dynamics_config
    path = save_checkpoint(tmp_path / "small.pt", build_model(dynamics_config(state_dim=4, action_dim=2), seed=0),
                           metadata={"sample_period": 0.01})
    with pytest.raises(InputError, match="expected state dim 12 and action dim 6"):
        LearnedModel(path, robot=UR10)


@pytest.mark.slow
def test_view_and_mpc_commands(checkpoints, tracking_dataset, tmp_path, capsys):
    html = tmp_path / "view.html"
    assert main(["view", str(checkpoints["PE"]), str(tracking_dataset), "--index", "2", "--html", str(html)]) == 0
    assert "open-loop RMS joint-angle error" in capsys.readouterr().out
    assert html.stat().st_size > 100_000
    out = tmp_path / "mpc"
    code = main(["mpc", str(tracking_dataset), "--model", f"D={checkpoints['D']}", "--plans", "1",
                 "--config", str(_short_horizon(tmp_path)), "-o", str(out), "--quiet"])
    assert code == closed_loop_status(json.loads((out / "mpc.json").read_text())["summary"])   # tiny D: may leave
    table = (out / "mpc.md").read_text()
    assert "| plant | 1 |" in table and "| D | 1 |" in table
    summary = {row["model"]: row for row in json.loads((out / "mpc.json").read_text())["summary"]}
    for name, row in summary.items():      # the solve time against the 10 ms period, in mpc.md and printed
        verdict = "real time" if row["solve_ms_p95"] <= 10.0 else "not real time"
        assert row["control_step"] == "compiled"    # (the plant and the default D: both covered by the compiled step)
        line = (f"- {name} (compiled control step): solve {row['solve_ms_mean']:.2f} ms mean, {row['solve_ms_p95']:.2f} ms "
                f"p95 per control step")
        hertz = 1e3 / row["solve_ms_p95"]
        rate = int(hertz // 10 * 10) if hertz >= 100 else int(hertz)
        assert line in table and f"against the 10 ms control period: {verdict}" in table
        assert f"real time at {rate} Hz by its p95" in table
    assert (out / "mpc.png").stat().st_size > 10_000 and (out / "mpc.csv").exists()
    models = json.loads((out / "mpc.json").read_text())["inputs"]["models"]   # each model with its file and kind
    assert [(model["name"], model["kind"]) for model in models] == [("plant", "plant"), ("D", "checkpoint")]
    assert models[1]["file"] == str(checkpoints["D"]) and len(models[1]["sha256"]) == 64
    assert main(["mpc"]) == 2                                  # argparse's error, as one line


def test_mpc_needs_a_held_out_plan(tracking_dataset, tmp_path, capsys):
    folder = tmp_path / "all"
    assert main(["train", str(tracking_dataset), "-o", str(folder), "--predicts", "state", "--inputs", "raw", "--model", "D", "--hidden-width", "8",
                 "--hidden-layers", "1", "--epochs", "1", "--seeds", "0", "--train", "1", "--val", "1",
                 "--test", "0", "--quiet"]) == 0
    assert main(["mpc", str(tracking_dataset), "--model", f"D={folder / 'seed0' / 'checkpoint.pt'}",
                 "-o", str(tmp_path / "out")]) == 2
    assert "no held-out plan to track" in capsys.readouterr().err


def _short_horizon(tmp_path):
    path = tmp_path / "mpc.yaml"
    path.write_text("horizon: 5\noptimizer: !Rti {iterations: 1}\n")
    return path
