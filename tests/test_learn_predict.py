"""Prediction API: the numpy inference path, rollout = repeated predict, TS1/TS-inf, input errors."""
import numpy as np
import pytest
import torch

from stdm_drake.errors import InputError
from stdm_drake.learning.regression import RegressionData
from stdm_drake.learning.trainer import build_model
from stdm_drake.learning.activations import ACTIVATION_NAMES
from stdm_drake.learning.models import dynamics_config
from stdm_drake.learning.predict import InferenceModel, predict, rollout

RNG = np.random.default_rng(0)
STATES = RNG.standard_normal((400, 4))
ACTIONS = 3.0 * RNG.standard_normal((400, 2))
DATA = RegressionData(inputs=np.hstack([STATES, ACTIONS]), targets=STATES + 0.02 * RNG.standard_normal((400, 4)))


def make_model(ensemble_size=1, probabilistic=False, activation="swish", delta=True, seed=0):
    config = dynamics_config(state_dim=4, action_dim=2, delta=delta, hidden_width=32, hidden_layers=3,
                             activation=activation, ensemble_size=ensemble_size, probabilistic=probabilistic)
    model = build_model(config, seed)
    model.fit_normalizers(DATA)
    with torch.no_grad():
        for bias in model.biases:
            bias.normal_(0.0, 0.3)
    return model.eval()


@pytest.mark.parametrize("activation", ACTIVATION_NAMES)
@pytest.mark.parametrize("delta", [True, False], ids=["delta", "direct"])
def test_inference_path_matches_the_torch_model(activation, delta):
    model = make_model(ensemble_size=3, probabilistic=True, activation=activation, delta=delta)
    states, actions = STATES[:10], ACTIONS[:10]
    prediction = predict(model, states, actions)
    with torch.no_grad():
        mean, variance = model(torch.tensor(np.hstack([states, actions]), dtype=torch.float64).float())
    np.testing.assert_allclose(prediction.member_means, mean.numpy(), rtol=2e-5, atol=2e-5)
    np.testing.assert_allclose(prediction.member_variances, variance.numpy(), rtol=2e-4, atol=1e-8)
    np.testing.assert_allclose(prediction.mean, mean.numpy().mean(axis=0), rtol=2e-5, atol=2e-5)
    total = mean.numpy().var(axis=0) + variance.numpy().mean(axis=0)
    np.testing.assert_allclose(prediction.variance, total, rtol=2e-4, atol=1e-7)


@pytest.mark.parametrize("activation", ACTIVATION_NAMES)
@pytest.mark.parametrize("ensemble_size, delta", [(1, True), (3, False)], ids=["single-delta", "ensemble-direct"])
def test_mean_jacobian_matches_the_training_jvp(activation, ensemble_size, delta):
    """The float32 forward-mode Jacobian equals the float64 chain rule the derivative loss uses."""
    model = make_model(ensemble_size=ensemble_size, probabilistic=ensemble_size > 1, activation=activation,
                       delta=delta).double()
    engine = InferenceModel(model)
    z = np.hstack([STATES[:5], ACTIONS[:5]])
    jacobian = engine.mean_and_jacobian(engine.input_rows(STATES[:5], ACTIONS[None, :5])[0])[1]
    assert jacobian.shape == (5, 4, 6) and jacobian.dtype == np.float32
    rows = torch.as_tensor(np.repeat(z, 6, axis=0))
    with torch.no_grad():
        columns = model.time_derivative(rows, torch.eye(6, dtype=torch.float64).repeat(5, 1)).mean(0)
    expected = columns.reshape(5, 6, 4).transpose(1, 2).numpy()
    np.testing.assert_allclose(jacobian, expected, rtol=1e-4, atol=1e-5 * np.abs(expected).max())


@pytest.mark.parametrize("ensemble_size,probabilistic", [(1, False), (5, False), (3, True)], ids=["D", "DE", "PE"])
def test_rollout_equals_repeated_predict(ensemble_size, probabilistic):
    engine = InferenceModel(make_model(ensemble_size, probabilistic))
    x0, actions = STATES[:3], ACTIONS[:60].reshape(3, 20, 2)
    result = rollout(engine, x0, actions)
    assert result.mean.shape == result.variance.shape == (3, 20, 4)
    state = x0
    for step in range(20):
        prediction = predict(engine, state, actions[:, step])
        assert np.array_equal(result.mean[:, step], prediction.mean), step
        np.testing.assert_allclose(result.variance[:, step], prediction.variance, rtol=1e-5, atol=1e-9)
        state = prediction.mean
    assert (result.variance > 0).all() == (ensemble_size > 1 or probabilistic)


def test_rollout_matches_a_plain_torch_loop():
    model = make_model(ensemble_size=2)
    x0, actions = STATES[0], ACTIONS[:50]
    fast = rollout(model, x0, actions).mean
    state = torch.tensor(x0, dtype=torch.float32)[None]
    with torch.no_grad():
        for step in range(50):
            mean, _ = model(torch.cat([state, torch.tensor(actions[step:step + 1], dtype=torch.float32)], 1))
            state = mean.mean(0)
            np.testing.assert_allclose(fast[step], state[0].numpy(), rtol=1e-4, atol=1e-4)


def test_unbatched_inputs_give_unbatched_outputs():
    model = make_model(ensemble_size=2, probabilistic=True)
    single = predict(model, STATES[0], ACTIONS[0])
    assert single.mean.shape == single.variance.shape == (4,)
    assert single.member_means.shape == single.member_variances.shape == (2, 4)
    batched = predict(model, STATES[:1], ACTIONS[:1])
    np.testing.assert_array_equal(single.mean, batched.mean[0])
    path = rollout(model, STATES[0], ACTIONS[:7])
    assert path.mean.shape == (7, 4)


def test_ts_inf_particles_follow_single_members():
    """Deterministic ensemble + TS-inf: every particle is one member's own open-loop rollout."""
    model = make_model(ensemble_size=3)
    x0, actions = STATES[5], ACTIONS[:15]
    result = rollout(model, x0, actions, propagation="tsinf", particles=12, seed=1, keep_particles=True)
    assert result.particles.shape == (12, 15, 4)
    members = np.stack([rollout(model.member(k), x0, actions).mean for k in range(3)])     # (3, 15, 4)
    distance = np.abs(result.particles[:, None] - members[None]).max(axis=(2, 3))          # (12, 3)
    assert (distance.min(axis=1) < 1e-5).all()
    assert len(set(distance.argmin(axis=1))) > 1          # particles are spread over members
    np.testing.assert_allclose(result.mean, result.particles.mean(axis=0), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(result.variance, result.particles.var(axis=0), rtol=1e-4, atol=1e-9)


def test_trajectory_sampling_shapes_and_statistics():
    model = make_model(ensemble_size=3, probabilistic=True)
    x0, actions = STATES[:2], ACTIONS[:20].reshape(2, 10, 2)
    for propagation in ("ts1", "tsinf"):
        result = rollout(model, x0, actions, propagation=propagation, particles=40, seed=3, keep_particles=True)
        assert result.mean.shape == result.variance.shape == (2, 10, 4)
        assert result.particles.shape == (2, 40, 10, 4)
        assert np.isfinite(result.particles).all()
        assert (result.variance > 0).all()
        again = rollout(model, x0, actions, propagation=propagation, particles=40, seed=3)
        np.testing.assert_array_equal(again.mean, result.mean)
        other = rollout(model, x0, actions, propagation=propagation, particles=40, seed=4)
        assert not np.array_equal(other.mean, result.mean)
        # one step ahead the particle spread estimates the one-step predictive variance
        first = predict(model, x0, actions[:, 0])
        assert np.all(np.abs(result.mean[:, 0] - first.mean) < 4 * np.sqrt(first.variance / 40) + 1e-6)
    deterministic = make_model(ensemble_size=1)
    ts = rollout(deterministic, x0, actions, propagation="ts1", particles=5)
    np.testing.assert_allclose(ts.mean, rollout(deterministic, x0, actions).mean, rtol=1e-6, atol=1e-6)
    assert np.allclose(ts.variance, 0.0)


def test_prediction_input_errors_are_clear():
    model = make_model()
    with pytest.raises(InputError, match="states has 3 columns, the model expects 4"):
        predict(model, np.zeros((2, 3)), np.zeros((2, 2)))
    bad = STATES[:2].copy()
    bad[1, 2] = np.inf
    with pytest.raises(InputError, match="states contains 1 NaN or inf"):
        predict(model, bad, ACTIONS[:2])
    with pytest.raises(InputError, match="different batch sizes"):
        predict(model, STATES[:2], ACTIONS[:3])
    with pytest.raises(InputError, match="actions are required"):
        predict(model, STATES[:2])
    with pytest.raises(InputError, match="propagation"):
        rollout(model, STATES[0], ACTIONS[:4], propagation="moment")
    with pytest.raises(InputError, match=r"actions must have shape \(B, T, A\) or \(T, A\)"):
        rollout(model, STATES[0], ACTIONS[0])
    with pytest.raises(InputError, match="NaN or inf"):
        rollout(model, STATES[0], np.full((4, 2), np.nan))
    with pytest.raises(InputError, match="a trainable network or its inference engine"):
        predict(object(), STATES[:1], ACTIONS[:1])


def test_models_without_actions():
    """A = 0: an autonomous STDM trains, predicts without actions and rolls out under (T, 0) actions."""
    from stdm_drake.learning.settings import TrainingConfig
    from stdm_drake.learning.trainer import train_model

    states = RNG.standard_normal((300, 2))
    rotation = np.array([[np.cos(0.1), -np.sin(0.1)], [np.sin(0.1), np.cos(0.1)]])
    data = RegressionData(inputs=states, targets=states @ rotation.T)
    config = dynamics_config(state_dim=2, action_dim=0, hidden_width=16, hidden_layers=2)
    model = train_model(config, TrainingConfig(max_epochs=3), data, data).model
    assert config.action_dim == 0 and config.input_dim == 2
    step = predict(model, states[:4])
    path = rollout(model, states[:4], np.zeros((4, 6, 0)))
    np.testing.assert_array_equal(path.mean[:, 0], step.mean)
    assert path.mean.shape == (4, 6, 2) and np.isfinite(path.mean).all()
