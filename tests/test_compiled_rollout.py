"""Open-loop rollouts in the compiled core (dynamics/compiled_core.py, core/control_step.hpp) against the numpy
rollouts they replace: every structure and activation the core covers, the variance of ensembles and
probabilistic members, rows that diverge, the setting that chooses the code (`evaluate`'s: tests/test_learn_cli.py)."""
import numpy as np
import pytest

from presets import UR10
from test_compiled_step import STRUCTURES
from test_export import random_rows, synthetic_checkpoint
from stdm_drake.errors import InputError
from stdm_drake.learning.learned_model import LearnedModel
from stdm_drake.learning.structure import PAPER, ModelStructure

STEPS = 12


def rollout_inputs(count: int, seed: int):
    """x0 (B, 12) inside the UR-10's limits and torque sequences (B, STEPS, 6) near the effort scale."""
    x0, _ = random_rows(count, seed)
    rng = np.random.default_rng(seed + 100)
    return x0, rng.uniform(-50.0, 50.0, (count, STEPS, 6))


@pytest.mark.parametrize("structure, kind, activation", STRUCTURES + [(PAPER, "PE", "swish"),
                                                                     (ModelStructure("velocity", "raw"), "PE", "gelu")])
def test_the_compiled_rollout_is_the_numpy_rollout(tmp_path, structure, kind, activation):
    """Mean and variance (the members' spread plus their predicted variance) equal to float32's precision over
    the steps (the numpy paper's path carries the state in float32, the core in float64)."""
    model = LearnedModel(synthetic_checkpoint(tmp_path / "model.pt", structure, model_type=kind, activation=activation),
                         robot=UR10)
    assert model.rollout_implementation == "compiled"
    x0, actions = rollout_inputs(5, 3)
    compiled = model.rollout(x0, actions)
    reference = model.rollout(x0, actions, implementation="numpy")
    assert np.isfinite(reference.mean).all()
    scale = np.abs(reference.mean).max()
    np.testing.assert_allclose(compiled.mean, reference.mean, rtol=0, atol=2e-6 * scale)
    if kind == "D":     # one deterministic network: no variance
        assert not compiled.variance.any() and not reference.variance.any()
    else:
        assert reference.variance.max() > 0
        np.testing.assert_allclose(compiled.variance, reference.variance, rtol=1e-4,
                                   atol=1e-5 * reference.variance.max())
    # one torque sequence for every initial state, as the numpy path takes it
    shared = model.rollout(x0, actions[:1])
    np.testing.assert_allclose(shared.mean, model.rollout(x0, np.repeat(actions[:1], 5, axis=0)).mean, rtol=0, atol=0)


def test_a_diverging_row_holds_nan_after_it_left_the_finite_numbers_and_the_others_go_on(tmp_path):
    """As the numpy rollout: the step where a row's state overflows is non-finite, every step after it NaN; the
    other rows of the batch are the rollouts they are alone."""
    model = LearnedModel(synthetic_checkpoint(tmp_path / "model.pt", PAPER), robot=UR10)
    x0, actions = rollout_inputs(3, 5)
    actions[1, 4] = 1e39            # finite in float64, beyond float32 (the network's precision)
    compiled = model.rollout(x0, actions)
    reference = model.rollout(x0, actions, implementation="numpy")
    finite = np.isfinite(compiled.mean).all(axis=-1)
    assert finite[[0, 2]].all() and finite[1, :4].all() and not finite[1, 4:].any()
    assert np.isnan(compiled.mean[1, 5:]).all()
    np.testing.assert_array_equal(finite, np.isfinite(reference.mean).all(axis=-1))
    alone = model.rollout(x0[[0, 2]], actions[[0, 2]])
    np.testing.assert_array_equal(compiled.mean[[0, 2]], alone.mean)


def test_what_the_core_does_not_cover_runs_numpy_and_says_so(tmp_path):
    grey_box = LearnedModel(synthetic_checkpoint(tmp_path / "grey.pt", ModelStructure("velocity", "plant_step")),
                            robot=UR10)
    assert grey_box.rollout_implementation == "numpy (plant-step inputs)"
    x0, actions = rollout_inputs(2, 1)
    np.testing.assert_array_equal(grey_box.rollout(x0, actions).mean,
                                  grey_box.rollout(x0, actions, implementation="numpy").mean)
    with pytest.raises(InputError, match="rollout implementation must be one of compiled, numpy, got 'fast'"):
        grey_box.rollout(x0, actions, implementation="fast")


def test_trajectory_sampling_stays_on_numpy(tmp_path):
    """ts1 and tsinf draw from numpy's generator: the compiled setting gives the numpy rollout, seed for seed."""
    model = LearnedModel(synthetic_checkpoint(tmp_path / "model.pt", PAPER, model_type="PE"), robot=UR10)
    x0, actions = rollout_inputs(2, 2)
    for propagation in ("ts1", "tsinf"):
        compiled = model.rollout(x0, actions, propagation=propagation, particles=10, seed=4)
        reference = model.rollout(x0, actions, propagation=propagation, particles=10, seed=4, implementation="numpy")
        np.testing.assert_array_equal(compiled.mean, reference.mean)
