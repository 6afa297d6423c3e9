"""Training loop, losses, reproducibility, resume, checkpoints and their error messages."""
import dataclasses
import os

import numpy as np
import pytest
import torch

from stdm_drake.errors import InputError
from stdm_drake.learning.regression import RegressionData
from stdm_drake.learning.settings import TrainingConfig
from stdm_drake.learning.alpha_selection import select_alpha
from stdm_drake.learning.trainer import build_model, train_model, training_step
from stdm_drake.learning.checkpoint import load_checkpoint, load_model, save_checkpoint
from stdm_drake.learning.activations import ACTIVATION_NAMES
from stdm_drake.learning.models import ModelConfig, dynamics_config


def pendulum_data(count, seed):
    """Damped pendulum-like STDM data (S=2, A=1) with exact chain-rule tangents and rate targets."""
    rng = np.random.default_rng(seed)
    dt = 0.05
    q, v, a = rng.uniform(-2, 2, count), rng.uniform(-2, 2, count), rng.uniform(-1, 1, count)
    a_rate = rng.uniform(-2, 2, count)

    def acceleration(q, v, a):
        return -9.81 * np.sin(q) - 0.2 * v + a

    v_next = v + dt * acceleration(q, v, a)
    q_next = q + dt * v_next
    # rates of the discrete map along the trajectory direction, by central differences in time
    eps = 1e-6
    qe, ve, ae = q + eps * v, v + eps * acceleration(q, v, a), a + eps * a_rate
    v_next_e = ve + dt * acceleration(qe, ve, ae)
    q_next_e = qe + dt * v_next_e
    return RegressionData(inputs=np.column_stack([q, v, a]), targets=np.column_stack([q_next, v_next]),
                          input_rates=np.column_stack([v, acceleration(q, v, a), a_rate]),
                          target_rates=np.column_stack([(q_next_e - q_next) / eps, (v_next_e - v_next) / eps]))


TRAIN = pendulum_data(256, 0)
VAL = pendulum_data(128, 1)
SMALL = dict(hidden_width=24, hidden_layers=2)


def weights_equal(a, b):
    return all(torch.equal(x, y) for x, y in zip(a.state_dict().values(), b.state_dict().values()))


@pytest.mark.parametrize("activation", ACTIVATION_NAMES)
def test_every_activation_trains(activation):
    """A few Adam steps lower the loss, naive and with the derivative term."""
    for alpha in (0.0, 1e-2):
        config = dynamics_config(state_dim=2, action_dim=1, activation=activation, **SMALL)
        training = TrainingConfig(alpha=alpha, learning_rate=3e-3)
        model = build_model(config, seed=0)
        model.fit_normalizers(TRAIN)
        data = model.standardize(TRAIN)
        optimizer = torch.optim.Adam(model.parameters(), lr=training.learning_rate)
        rows = torch.arange(len(TRAIN))[None]
        losses = [training_step(model, optimizer, training, data, rows)[0] for _ in range(25)]
        assert np.isfinite(losses).all()
        assert losses[-1] < 0.7 * losses[0], (activation, alpha, losses[0], losses[-1])


def test_same_seed_same_weights_different_seed_different():
    config = dynamics_config(state_dim=2, action_dim=1, ensemble_size=2, **SMALL)
    training = TrainingConfig(alpha=1e-3, max_epochs=3, batch_size=32, seed=5)
    first = train_model(config, training, TRAIN, VAL).model
    second = train_model(config, training, TRAIN, VAL).model
    other = train_model(config, dataclasses.replace(training, seed=6), TRAIN, VAL).model
    assert weights_equal(first, second)
    assert not weights_equal(first, other)


def test_best_weights_are_the_best_validation_epoch():
    config = dynamics_config(state_dim=2, action_dim=1, **SMALL)
    training = TrainingConfig(max_epochs=12, batch_size=64, learning_rate=1e-2)
    result = train_model(config, training, TRAIN, VAL)
    history = result.history["val_mse"]
    assert result.best_scores[0] == pytest.approx(min(history), rel=1e-9)
    assert result.best_epochs[0] == result.history["epoch"][int(np.argmin(history))]
    recomputed = result.model.eval_score(training, result.model.standardize(VAL))["member_mse"]
    assert recomputed.item() == pytest.approx(min(history), rel=1e-5)


def test_early_stopping_stops_after_patience():
    config = dynamics_config(state_dim=2, action_dim=1, **SMALL)
    training = TrainingConfig(max_epochs=200, patience=3, learning_rate=0.5, batch_size=256)   # diverges quickly
    result = train_model(config, training, TRAIN, VAL)
    assert result.stopped_early
    assert result.epochs_run < 200
    assert result.epochs_run - max(result.best_epochs) >= 3


@pytest.mark.slow
def test_derivative_learning_fits_the_function_better_from_few_points():
    """The derivative term does what it is for: from 10 samples of sin(3x) and their slopes, the *function*
    between the samples (what the value loss alone fits, not what the derivative term minimizes) is
    predicted better, for each of three initializations."""
    x = np.linspace(-2, 2, 10)[:, None]
    train = RegressionData(inputs=x, targets=np.sin(3 * x), input_rates=np.ones_like(x), target_rates=3 * np.cos(3 * x))
    grid = np.linspace(-2, 2, 200)[:, None]
    val = RegressionData(inputs=grid, targets=np.sin(3 * grid))
    config = ModelConfig(input_dim=1, output_dim=1, hidden_width=32, hidden_layers=2)
    for seed in range(3):
        errors = {}
        for alpha in (0.0, 0.1):
            training = TrainingConfig(alpha=alpha, batch_size=10, max_epochs=600, patience=600, learning_rate=1e-2,
                                      validation_interval=600, seed=seed)
            model = train_model(config, training, train, val).model
            with torch.no_grad():
                values = model(torch.tensor(grid, dtype=torch.float32))[0][0].numpy()
            errors[alpha] = float(np.mean((values - np.sin(3 * grid)) ** 2))
        assert errors[0.1] < 0.5 * errors[0.0], (seed, errors)


@pytest.mark.parametrize("options", [{}, dict(lr_schedule="cosine", min_learning_rate=1e-4, weight_decay=1e-2)])
def test_resume_gives_the_same_result_as_uninterrupted_training(tmp_path, options):
    config = dynamics_config(state_dim=2, action_dim=1, ensemble_size=2, probabilistic=True, **SMALL)
    training = TrainingConfig(alpha=1e-3, max_epochs=6, patience=50, batch_size=64, seed=3, **options)
    straight = train_model(config, training, TRAIN, VAL, checkpoint_path=tmp_path / "straight.pt",
                           checkpoint_every=1)

    class Interrupt(Exception):
        """Stands for a crash or Ctrl+C after epoch 3."""

    def stop_at_three(row):
        if row["epoch"] == 3:
            raise Interrupt

    path = tmp_path / "resumed.pt"
    with pytest.raises(Interrupt):
        train_model(config, training, TRAIN, VAL, checkpoint_path=path, checkpoint_every=1, on_epoch=stop_at_three)
    assert load_checkpoint(path).resume["epoch"] == 3
    resumed = train_model(config, training, TRAIN, VAL, checkpoint_path=path, checkpoint_every=1, resume=True)
    assert resumed.epochs_run == straight.epochs_run == 6
    assert weights_equal(resumed.model, straight.model)
    for column in straight.history:
        if column != "seconds":
            assert resumed.history[column] == straight.history[column], column
    final_straight, final_resumed = load_checkpoint(tmp_path / "straight.pt"), load_checkpoint(path)
    assert weights_equal(final_straight.model, final_resumed.model)
    for key, value in final_straight.resume["weights"].items():
        assert torch.equal(value, final_resumed.resume["weights"][key])
    with pytest.raises(InputError, match="options differ"):
        train_model(config, dataclasses.replace(training, seed=4), TRAIN, VAL, checkpoint_path=path, resume=True)


def test_checkpoint_round_trip(tmp_path):
    config = dynamics_config(state_dim=2, action_dim=1, ensemble_size=3, **SMALL)
    training = TrainingConfig(alpha=1e-3, max_epochs=2)
    result = train_model(config, training, TRAIN, VAL)
    path = save_checkpoint(tmp_path / "model.pt", result.model, training_config=training, history=result.history,
                           metadata={"dataset_sha256": "abc", "split": {"train": [0, 2]}, "sample_period": 0.01})
    assert [p.name for p in tmp_path.iterdir()] == ["model.pt"]      # no temp file left behind
    raw = torch.load(path, weights_only=True)
    assert raw["format"] == "stdm-drake-model"
    loaded = load_checkpoint(path)
    assert loaded.model_config == config and loaded.training_config == training
    assert loaded.metadata.split == {"train": [0, 2]} and loaded.metadata.sample_period == 0.01
    assert loaded.history["val_mse"] == pytest.approx(result.history["val_mse"])
    assert weights_equal(loaded.model, result.model)
    inputs = torch.tensor(VAL.inputs[:5], dtype=torch.float32)
    with torch.no_grad():
        assert torch.equal(loaded.model(inputs)[0], result.model(inputs)[0])


def test_bad_checkpoints_give_one_line_input_errors(tmp_path):
    config = dynamics_config(state_dim=2, action_dim=1, **SMALL)
    model = build_model(config, 0)
    good = save_checkpoint(tmp_path / "good.pt", model)
    data = good.read_bytes()
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="truncated or corrupt") as caught:
        load_checkpoint(truncated)
    assert "\n" not in str(caught.value)
    text = tmp_path / "notes.pt"
    text.write_text("not a checkpoint\n")
    with pytest.raises(InputError, match="not a readable stdm-drake checkpoint"):
        load_checkpoint(text)
    foreign = tmp_path / "foreign.pt"
    torch.save({"state_dict": {}}, foreign)
    with pytest.raises(InputError, match="not a stdm-drake model checkpoint"):
        load_checkpoint(foreign)
    with pytest.raises(InputError, match="state dim 2 and action dim 1, expected state dim 12 and action dim 6"):
        load_model(good, state_dim=12, action_dim=6)
    assert load_model(good, state_dim=2, action_dim=1).model_config == config
    with pytest.raises(FileNotFoundError):
        load_checkpoint(tmp_path / "missing.pt")
    content = torch.load(good, weights_only=True)
    content["weights"]["weights.0"] = torch.zeros(1, 5, 24)
    broken = tmp_path / "broken.pt"
    torch.save(content, broken)
    with pytest.raises(InputError, match="inconsistent checkpoint"):
        load_checkpoint(broken)


def test_bad_training_data_is_rejected_clearly():
    config = dynamics_config(state_dim=2, action_dim=1, **SMALL)
    nan = dataclasses.replace(TRAIN, targets=TRAIN.targets.copy())
    nan.targets[3, 1] = np.nan
    with pytest.raises(InputError, match="training data: targets contains 1 NaN or inf"):
        train_model(config, TrainingConfig(max_epochs=1), nan, VAL)
    with pytest.raises(InputError, match=r"inputs has shape \(256, 3\), expected \(N, 4\)"):
        train_model(dynamics_config(state_dim=2, action_dim=2), TrainingConfig(max_epochs=1), TRAIN, VAL)
    no_rates = RegressionData(inputs=TRAIN.inputs, targets=TRAIN.targets)
    with pytest.raises(InputError, match="needs input_rates and target_rates"):
        train_model(config, TrainingConfig(alpha=1e-3, max_epochs=1), no_rates, VAL)
    with pytest.raises(InputError, match="state_loss"):
        TrainingConfig(state_loss="l3")
    with pytest.raises(InputError, match="alpha"):
        TrainingConfig(alpha=float("nan"))


def test_interrupted_checkpoint_files_are_complete(tmp_path):
    """Checkpoints are replaced atomically: the file is always loadable, never half written."""
    config = dynamics_config(state_dim=2, action_dim=1, **SMALL)
    path = tmp_path / "run.pt"
    seen = []

    def check(row):
        seen.append(load_checkpoint(path).resume["epoch"])

    train_model(config, TrainingConfig(max_epochs=4), TRAIN, VAL, checkpoint_path=path, checkpoint_every=1,
                on_epoch=check)
    assert seen == [1, 2, 3, 4]
    assert sorted(os.listdir(tmp_path)) == ["run.pt"]


def test_a_dataset_passed_as_checkpoint_is_named_as_such(tmp_path):
    import h5py
    path = tmp_path / "data.h5"
    with h5py.File(path, "w") as f:
        f["x"] = [1.0]
    with pytest.raises(InputError, match="not a PyTorch checkpoint file \\(it is an HDF5 file: a dataset\\?\\)"):
        load_checkpoint(path)


def _eq9_terms(model, data):
    """Per-output raw-unit MSEs of paper eq. 9: state (S,) and time derivative (S,), float64."""
    z, zd = torch.tensor(data.inputs, dtype=torch.float64), torch.tensor(data.input_rates, dtype=torch.float64)
    with torch.no_grad():
        state = model(z)[0][0]
        rate = model.time_derivative(z, zd)[0]
    return (((state - torch.tensor(data.targets)) ** 2).mean(0).numpy(),
            ((rate - torch.tensor(data.target_rates)) ** 2).mean(0).numpy())


@pytest.mark.parametrize("residual", [True, False])
def test_loss_is_the_papers_eq9_per_output_scaled_by_the_state_spread(residual):
    """L = mean_j (1/σ_j²) [MSE_state,j + alpha MSE_derivative,j] in raw units; with one common σ it is
    exactly eq. 9 (raw-unit MSE of the state + alpha MSE of its time derivative) divided by σ²."""
    config = dynamics_config(state_dim=2, action_dim=1, delta=residual, **SMALL)
    model = build_model(config, seed=1).double()
    model.fit_normalizers(TRAIN)
    alpha = 0.37
    training = TrainingConfig(alpha=alpha)

    def loss():
        data = model.standardize(TRAIN)
        with torch.no_grad():
            return model.loss(training, data.inputs, data.targets, data.input_rates,
                                data.target_rates).total.item()

    state_mse, rate_mse = _eq9_terms(model, TRAIN)
    sigma = model.output_normalizer.std.numpy()
    assert not np.allclose(sigma[0], sigma[1])
    assert loss() == pytest.approx(np.mean((state_mse + alpha * rate_mse) / sigma ** 2), rel=1e-9)
    model.output_normalizer.std.fill_(0.25)   # one common spread: eq. 9 itself, up to the factor 1/σ²
    state_mse, rate_mse = _eq9_terms(model, TRAIN)
    assert loss() == pytest.approx((state_mse.mean() + alpha * rate_mse.mean()) / 0.25 ** 2, rel=1e-9)


@pytest.mark.parametrize("residual", [True, False])
def test_relative_alpha_scales_each_derivative_residual_by_its_targets_spread(residual):
    """alpha_scale "relative": L = mean_j [MSE_state,j / σ_j² + alpha MSE_derivative,j / τ_j²] in raw units, τ_j the
    spread of output j's derivative targets (of ẏ_j - r(ż)_j for the delta model), what the trainer sets; the
    same data with one output's derivative targets scaled by 1000 get that output's factor divided by 1000."""
    from stdm_drake.learning.trainer import relative_derivative_scale
    config = dynamics_config(state_dim=2, action_dim=1, delta=residual, **SMALL)
    alpha = 0.37
    training = TrainingConfig(alpha=alpha, alpha_scale="relative")

    def terms(data):
        model = build_model(config, seed=1).double()
        model.fit_normalizers(data)
        tensors = model.standardize(data)
        model.derivative_scale = relative_derivative_scale(tensors)
        with torch.no_grad():
            terms = model.loss(training, tensors.inputs, tensors.targets, tensors.input_rates, tensors.target_rates)
        return model, terms

    model, loss = terms(TRAIN)
    state_mse, rate_mse = _eq9_terms(model, TRAIN)
    sigma = model.output_normalizer.std.numpy()
    residual_rates = TRAIN.target_rates - (TRAIN.input_rates[:, :2] if residual else 0)
    tau = residual_rates.std(axis=0)
    assert not np.allclose(sigma / tau, (sigma / tau)[0])
    assert loss.total.item() == pytest.approx(np.mean(state_mse / sigma ** 2 + alpha * rate_mse / tau ** 2), rel=1e-9)
    # derivative targets 1000x larger on one output (a fast wrist, a shorter period): its factor is 1000x smaller,
    # so its derivative term weighs what it weighed before (on the raw scale: a million times more)
    fast = RegressionData(TRAIN.inputs, TRAIN.targets, TRAIN.input_rates, TRAIN.target_rates * [1, 1000])
    if not residual:
        fast_model, _ = terms(fast)
        torch.testing.assert_close(fast_model.derivative_scale, model.derivative_scale / torch.tensor([1.0, 1000.0],
                                   dtype=torch.float64), rtol=1e-9, atol=0)
    with pytest.raises(InputError, match="alpha_scale must be one of"):
        TrainingConfig(alpha_scale="percent")


def test_relative_alpha_trains_and_is_recorded(tmp_path):
    """The trainer applies the relative scale (a different fit from the raw one at the same alpha) and the
    checkpoint and the selection record it."""
    config = dynamics_config(state_dim=2, action_dim=1, **SMALL)
    training = TrainingConfig(max_epochs=6, seed=3, learning_rate=3e-3, alpha=1.0)
    raw = train_model(config, training, TRAIN, VAL)
    relative = train_model(config, dataclasses.replace(training, alpha_scale="relative"), TRAIN, VAL,
                           checkpoint_path=tmp_path / "relative.pt")
    assert raw.model.derivative_scale is None and relative.model.derivative_scale.shape == (2,)
    assert not weights_equal(raw.model, relative.model)
    assert load_checkpoint(tmp_path / "relative.pt").training_config.alpha_scale == "relative"
    _, selection = select_alpha(config, dataclasses.replace(training, max_epochs=3, alpha_scale="relative"), TRAIN,
                                VAL, alphas=(0.0, 1.0))
    assert selection.as_dict()["alpha_scale"] == "relative" and selection.label(1) == "relative alpha 1"


def test_alpha_grid_members_equal_training_each_alpha_alone():
    """An alpha grid is a stack of independent runs from one initialization: member k equals a single
    model trained with alpha_k and the same seed (bitwise with the derivative term on; naive alone runs
    the plain forward pass, which rounds differently by about 1e-7)."""
    alphas = (0.0, 1e-2, 1.0)
    single = dynamics_config(state_dim=2, action_dim=1, **SMALL)
    training = TrainingConfig(max_epochs=8, batch_size=64, seed=4, learning_rate=3e-3, lr_schedule="cosine")
    grid = train_model(dataclasses.replace(single, ensemble_size=len(alphas)),
                       dataclasses.replace(training, alpha_grid=alphas), TRAIN, VAL)
    for index, alpha in enumerate(alphas):
        alone = train_model(single, dataclasses.replace(training, alpha=alpha), TRAIN, VAL)
        member = grid.model.member(index)
        assert alone.best_epochs[0] == grid.best_epochs[index]
        if alpha > 0:
            assert weights_equal(alone.model, member), alpha
            assert alone.best_scores[0] == grid.best_scores[index]
        else:
            for a, b in zip(alone.model.state_dict().values(), member.state_dict().values()):
                torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)
    different = [not weights_equal(grid.model.member(0), grid.model.member(k)) for k in (1, 2)]
    assert all(different)
    with pytest.raises(InputError, match="alpha_grid has 3 values for a model of 2 members"):
        train_model(dataclasses.replace(single, ensemble_size=2), dataclasses.replace(training, alpha_grid=alphas),
                    TRAIN, VAL)


def test_select_alpha_keeps_the_best_validation_member_never_worse_than_naive():
    config = dynamics_config(state_dim=2, action_dim=1, **SMALL)
    training = TrainingConfig(max_epochs=10, batch_size=64, seed=2, learning_rate=3e-3)
    alphas = (0.0, 1e-3, 1e-1, 10.0)
    chosen, selection = select_alpha(config, training, TRAIN, VAL, alphas=alphas)
    assert selection.alphas == alphas and len(selection.val_mse) == 4
    assert selection.val_mse[selection.index] == min(selection.val_mse) <= selection.val_mse[0]
    assert chosen.model.config.ensemble_size == 1
    score = chosen.model.eval_score(training, chosen.model.standardize(VAL))["member_mse"].item()
    assert score == pytest.approx(selection.val_mse[selection.index], rel=1e-6)
    assert selection.as_dict()["chosen_alpha"] == selection.alpha == alphas[selection.index]
    tie, tied = select_alpha(config, training, TRAIN, VAL, alphas=(0.0, 0.0))
    assert tied.index == 0


def test_cosine_schedule_runs_from_the_rate_to_the_floor():
    training = TrainingConfig(learning_rate=3e-3, lr_schedule="cosine", min_learning_rate=1e-4)
    assert training.learning_rate_at(0, 100) == pytest.approx(3e-3)
    assert training.learning_rate_at(50, 100) == pytest.approx((3e-3 + 1e-4) / 2)
    assert training.learning_rate_at(100, 100) == pytest.approx(1e-4)
    rates = [training.learning_rate_at(step, 100) for step in range(101)]
    assert all(a >= b for a, b in zip(rates, rates[1:]))
    assert TrainingConfig(learning_rate=2e-3).learning_rate_at(77, 100) == 2e-3
    # every minibatch step of a run (4 epochs x 4 batches) uses its scheduled rate
    config = dynamics_config(state_dim=2, action_dim=1, **SMALL)
    seen = []
    original = torch.optim.Adam.step

    def spy(self, *args, **kwargs):
        seen.append(self.param_groups[0]["lr"])
        return original(self, *args, **kwargs)

    torch.optim.Adam.step = spy
    try:
        train_model(config, dataclasses.replace(training, max_epochs=4, batch_size=64), TRAIN, VAL)
    finally:
        torch.optim.Adam.step = original
    assert len(seen) == 16 and seen[0] == pytest.approx(3e-3)
    assert seen == pytest.approx([training.learning_rate_at(step, 16) for step in range(16)]) and seen[-1] < 1.3e-4
    for bad in (dict(lr_schedule="linear"), dict(min_learning_rate=-1.0), dict(weight_decay=float("nan")),
                dict(learning_rate=1e-3, min_learning_rate=1e-2), dict(alpha_grid=(0.0, -1.0))):
        with pytest.raises(InputError):
            TrainingConfig(**bad)


def test_checkpoint_metadata_is_typed_and_fits_are_checked_in_one_place(tmp_path, tracking_dataset):
    """Unknown metadata keys are refused; `check_fits` names a size or period mismatch; `split_indices`
    applies only to the dataset the model was trained on."""
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.learning.checkpoint import CheckpointMetadata
    dataset = load_dataset(tracking_dataset)
    model = build_model(dynamics_config(state_dim=12, action_dim=6, hidden_width=8, hidden_layers=1), seed=0)
    with pytest.raises(InputError, match="unknown checkpoint metadata fields"):
        save_checkpoint(tmp_path / "x.pt", model, metadata={"sample_periodd": 0.01})
    metadata = CheckpointMetadata(dataset_sha256=dataset.sha256, sample_period=dataset.sample_period,
                                  split={"train": [0, 1], "val": [2], "test": [3, 4]})
    checkpoint = load_checkpoint(save_checkpoint(tmp_path / "m.pt", model, metadata=metadata))
    checkpoint.check_fits(dataset)
    assert checkpoint.trained_on(dataset) and checkpoint.split_indices(dataset, "test") == [3, 4]
    other = load_checkpoint(save_checkpoint(tmp_path / "o.pt", model, metadata=dict(sample_period=0.02)))
    assert other.split_indices(dataset, "test") is None
    with pytest.raises(InputError, match="model steps at 0.02 s"):
        other.check_fits(dataset)
    small = build_model(dynamics_config(state_dim=2, action_dim=1, hidden_width=8, hidden_layers=1), seed=0)
    with pytest.raises(InputError, match="state dim 2 and action dim 1, expected state dim 12 and action dim 6"):
        load_checkpoint(save_checkpoint(tmp_path / "s.pt", small)).check_fits(dataset)
