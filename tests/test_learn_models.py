"""Networks: activations and their tangent rules, the hand-written JVP, ensembles, normalizers, NLL."""
import dataclasses

import numpy as np
import pytest
import torch

from stdm_drake.errors import InputError
from stdm_drake.learning.regression import RegressionData
from stdm_drake.learning.settings import TrainingConfig
from stdm_drake.learning.loss import member_gaussian_nll
from stdm_drake.learning.activations import ACTIVATION_NAMES
from stdm_drake.learning.models import (MAX_LOGVAR_INIT, MIN_LOGVAR_INIT, EnsembleMLP, ModelConfig,
                                        bounded_logvar, dynamics_config, get_activation, parse_model_type)


def _random_data(rng, count, input_dim, output_dim, scale_in=1.0):
    inputs = rng.standard_normal((count, input_dim)) * scale_in + rng.uniform(-3, 3, input_dim)
    return RegressionData(inputs=inputs, targets=rng.standard_normal((count, output_dim)) * 2.0 + 1.0,
                          input_rates=rng.standard_normal((count, input_dim)),
                          target_rates=rng.standard_normal((count, output_dim)) * 5.0)


def _float64_model(config, seed=0):
    torch.manual_seed(seed)
    model = EnsembleMLP(config).double()
    rng = np.random.default_rng(seed)
    scales = rng.uniform(0.1, 10.0, config.input_dim)
    model.fit_normalizers(_random_data(rng, 200, config.input_dim, config.output_dim, scale_in=scales))
    # non-zero biases so every activation is exercised away from 0
    with torch.no_grad():
        for bias in model.biases:
            bias.normal_(0.0, 0.5)
    return model


@pytest.mark.parametrize("name", ACTIVATION_NAMES)
def test_tangent_rule_matches_autograd(name):
    """y = f(h), ẏ = f'(h) ḣ and f''(h) ḣ against torch autograd of the plain function (float64)."""
    activation = get_activation(name)
    h = torch.linspace(-4.0, 4.0, 81, dtype=torch.float64).reshape(1, 81, 1) + 0.013
    hd = torch.randn(1, 81, 1, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    y, yd, slope, curvature = activation.tangent(h.clone(), hd.clone())
    x = h.clone().requires_grad_(True)
    value = activation.function(x)
    (first,) = torch.autograd.grad(value.sum(), x, create_graph=True)
    (second,) = torch.autograd.grad(first.sum(), x)
    torch.testing.assert_close(y, value.detach(), rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(slope, first.detach(), rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(yd, first.detach() * hd, rtol=1e-10, atol=1e-12)
    expected_curvature = second * hd
    if curvature is None:
        assert torch.count_nonzero(second) == 0
    else:
        torch.testing.assert_close(curvature, expected_curvature, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("name", ["swish", "tanh", "gelu", "relu"])
@pytest.mark.parametrize("probabilistic", [False, True])
def test_jvp_function_gradients_pass_gradcheck(name, probabilistic):
    """The hand-written backward of the forward-mode pass equals numerical gradients (float64)."""
    config = ModelConfig(input_dim=4, output_dim=3, residual=True, hidden_width=6, hidden_layers=2,
                         activation=name, ensemble_size=2, probabilistic=probabilistic)
    model = _float64_model(config)
    generator = torch.Generator().manual_seed(3)
    inputs = torch.randn(5, 4, dtype=torch.float64, generator=generator)
    rates = torch.randn(5, 4, dtype=torch.float64, generator=generator)
    parameters = list(model.weights) + list(model.biases)

    def outputs(*values):
        count = len(values) // 2
        with torch.no_grad():
            for target, value in zip(parameters, values):
                target.copy_(value)
        from stdm_drake.learning.tangent import TangentPropagation
        return TangentPropagation.apply(model.activation, 3, model.per_member(inputs), model.per_member(rates),
                                         *values[:count], *values[count:])

    values = tuple(p.detach().clone().requires_grad_(True) for p in parameters)
    assert torch.autograd.gradcheck(outputs, values, eps=1e-6, atol=1e-6)


def _finite_difference_rate(model, inputs, rates, epsilon=1e-6):
    with torch.no_grad():
        ahead, _ = model(inputs + epsilon * rates)
        behind, _ = model(inputs - epsilon * rates)
    return (ahead - behind) / (2.0 * epsilon)


@pytest.mark.parametrize("residual", [True, False], ids=["delta", "direct"])
@pytest.mark.parametrize("ensemble_size", [1, 3], ids=["D", "DE"])
def test_time_derivative_matches_float64_finite_difference(residual, ensemble_size):
    """d x̂/dt = J(z) ż through normalizers and the delta/direct map, for D and every ensemble member."""
    config = dynamics_config(state_dim=4, action_dim=2, delta=residual, hidden_width=16, hidden_layers=3,
                             ensemble_size=ensemble_size)
    model = _float64_model(config, seed=ensemble_size)
    assert not torch.allclose(model.input_normalizer.std, torch.ones(6, dtype=torch.float64))
    generator = torch.Generator().manual_seed(7)
    inputs = torch.randn(8, 6, dtype=torch.float64, generator=generator) * 3
    rates = torch.randn(8, 6, dtype=torch.float64, generator=generator)
    with torch.no_grad():
        analytic = model.time_derivative(inputs, rates)
    numeric = _finite_difference_rate(model, inputs, rates)
    assert analytic.shape == (ensemble_size, 8, 4)
    for member in range(ensemble_size):
        torch.testing.assert_close(analytic[member], numeric[member], rtol=1e-6, atol=1e-7)
        single = model.member(member)
        with torch.no_grad():
            torch.testing.assert_close(single.time_derivative(inputs, rates)[0], analytic[member],
                                       rtol=1e-12, atol=1e-12)
    if residual:   # the delta map adds ẋ itself: the network part alone would miss it
        network_part = analytic - rates[:, :4]
        assert (network_part - numeric).abs().max() > 1e-3


def test_probabilistic_mean_jvp_matches_finite_difference():
    config = dynamics_config(state_dim=3, action_dim=1, hidden_width=12, hidden_layers=2, ensemble_size=2,
                             probabilistic=True)
    model = _float64_model(config)
    inputs = torch.randn(6, 4, dtype=torch.float64)
    rates = torch.randn(6, 4, dtype=torch.float64)
    with torch.no_grad():
        analytic = model.time_derivative(inputs, rates)
    torch.testing.assert_close(analytic, _finite_difference_rate(model, inputs, rates), rtol=1e-6, atol=1e-7)


def test_ensemble_output_equals_loop_over_members():
    config = dynamics_config(state_dim=5, action_dim=2, ensemble_size=4, probabilistic=True, hidden_width=20)
    model = _float64_model(config)
    inputs = torch.randn(7, 7, dtype=torch.float64)
    with torch.no_grad():
        mean, variance = model(inputs)
        for member in range(4):
            single_mean, single_variance = model.member(member)(inputs)
            torch.testing.assert_close(mean[member], single_mean[0], rtol=1e-12, atol=1e-12)
            torch.testing.assert_close(variance[member], single_variance[0], rtol=1e-12, atol=1e-12)
    assert not torch.allclose(mean[0], mean[1])  # members are initialized differently


def test_ensemble_members_train_on_their_own_inputs():
    """(E, B, in) inputs: member e sees only inputs[e]."""
    config = ModelConfig(input_dim=3, output_dim=2, ensemble_size=3)
    model = _float64_model(config)
    inputs = torch.randn(3, 5, 3, dtype=torch.float64)
    with torch.no_grad():
        stacked = model.normalized_outputs(inputs)
        for member in range(3):
            alone = model.member(member).normalized_outputs(inputs[member])
            torch.testing.assert_close(stacked[member], alone[0], rtol=1e-12, atol=1e-12)


def test_normalizer_statistics_and_constant_columns():
    config = ModelConfig(input_dim=3, output_dim=1)
    model = EnsembleMLP(config)
    data = np.column_stack([np.linspace(-94, 94, 101), np.full(101, 7.0), np.linspace(0, 1, 101) ** 2])
    model.input_normalizer.fit(data)
    normalized = model.input_normalizer.normalize(torch.from_numpy(data).float())
    assert torch.allclose(normalized[:, [0, 2]].mean(0), torch.zeros(2), atol=1e-5)
    assert torch.allclose(normalized[:, [0, 2]].std(0, unbiased=False), torch.ones(2), atol=1e-5)
    assert model.input_normalizer.std[1] == 1.0   # constant column: unscaled, centred
    assert torch.allclose(normalized[:, 1], torch.zeros(101))
    restored = model.input_normalizer.denormalize(normalized)
    assert torch.allclose(restored, torch.from_numpy(data).float(), atol=1e-4)
    with pytest.raises(InputError, match="shape"):
        model.input_normalizer.fit(np.zeros((4, 2)))


def test_xavier_initialization_and_zero_biases():
    config = ModelConfig(input_dim=18, output_dim=12, hidden_width=100, ensemble_size=2)
    model = EnsembleMLP(config, generator=torch.Generator().manual_seed(0))
    bound = np.sqrt(6.0 / (18 + 100))
    first = model.weights[0]
    assert first.abs().max() <= bound
    assert first.abs().max() > 0.9 * bound
    assert first.std().item() == pytest.approx(bound / np.sqrt(3), rel=0.1)
    assert all(torch.count_nonzero(bias) == 0 for bias in model.biases)


def test_logvar_bounds_are_soft_and_within_limits():
    low = torch.full((1, 1, 2), MIN_LOGVAR_INIT)
    high = torch.full((1, 1, 2), MAX_LOGVAR_INIT)
    raw = torch.tensor([[[-1e3, 1e3], [0.0, -5.0]]])
    bounded = bounded_logvar(raw, low, high)
    # soft limits: the lower clamp is applied last, so the top can exceed max by softplus(-(max - min))
    assert torch.all(bounded >= MIN_LOGVAR_INIT) and torch.all(bounded <= MAX_LOGVAR_INIT + 1e-4)
    assert bounded[0, 0, 0] == pytest.approx(MIN_LOGVAR_INIT, abs=1e-4)
    assert bounded[0, 0, 1] == pytest.approx(MAX_LOGVAR_INIT, abs=1e-4)
    assert bounded[0, 1, 1] == pytest.approx(-5.0, abs=0.01)      # inside: nearly the identity


def test_gaussian_nll_is_minimized_by_the_true_variance():
    rng = torch.Generator().manual_seed(0)
    target = torch.randn(20000, 1, generator=rng) * 0.5
    mean = torch.zeros_like(target)
    values = {s: member_gaussian_nll(mean, torch.full_like(target, s), target).item()
              for s in (np.log(0.25) - 1, np.log(0.25), np.log(0.25) + 1)}
    assert min(values, key=values.get) == np.log(0.25)
    assert member_gaussian_nll(mean, torch.full_like(target, np.log(0.25)), target).item() == pytest.approx(
        1.0 + np.log(0.25), abs=0.05)


def test_probabilistic_loss_includes_bound_penalty_and_trains_bounds():
    config = ModelConfig(input_dim=2, output_dim=2, probabilistic=True, hidden_width=8, ensemble_size=2)
    model = EnsembleMLP(config)
    data = _random_data(np.random.default_rng(0), 32, 2, 2)
    model.fit_normalizers(data)
    tensors = model.standardize(data)
    terms = model.loss(TrainingConfig(), tensors.inputs, tensors.targets)
    mean, logvar = model.split_head(model.normalized_outputs(tensors.inputs))
    penalty = 0.01 * (MAX_LOGVAR_INIT - MIN_LOGVAR_INIT) * 2      # two outputs, per member
    expected = member_gaussian_nll(mean, logvar, tensors.targets.expand(2, -1, -1)) + penalty   # (2,)
    assert terms.total.detach().numpy() == pytest.approx(expected.detach().numpy(), rel=1e-6)
    terms.objective.backward()
    assert model.max_logvar.grad is not None and torch.all(model.max_logvar.grad != 0)


def test_config_and_type_errors_are_clear():
    with pytest.raises(InputError, match="activation"):
        ModelConfig(input_dim=2, output_dim=1, activation="mish")
    with pytest.raises(InputError, match="hidden_layers"):
        ModelConfig(input_dim=2, output_dim=1, hidden_layers=0)
    with pytest.raises(InputError, match="residual"):
        ModelConfig(input_dim=1, output_dim=2, residual=True)
    with pytest.raises(InputError, match="model type"):
        parse_model_type("XE")
    assert parse_model_type("ped") == dataclasses.replace(parse_model_type("PED"))
    assert parse_model_type("DED").ensemble and parse_model_type("DED").derivative
    assert not parse_model_type("P").ensemble and parse_model_type("P").probabilistic
    model = EnsembleMLP(ModelConfig(input_dim=3, output_dim=1, ensemble_size=2))
    with pytest.raises(InputError, match="shape"):
        model(torch.zeros(3, 4, 3))
