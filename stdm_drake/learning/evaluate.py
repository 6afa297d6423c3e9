"""Test errors of trained STDMs beside the physics baselines (what `stdm-drake evaluate` reports).

One-step error: predict x_{t+1} from the recorded (x_t, a_t) of every test transition.
Multi-step error: from each test trajectory's x_0, roll the model out open loop under the
recorded torques and compare with the recorded states step by step (paper V.B.3, Fig. 18-19).
Errors are mean squared errors reported separately for joint angles q (rad²) and joint
velocities v ((rad/s)²): the state is x = [q, v], so q is the first half and v the second half.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.dynamics.model import DynamicsModel
from stdm_drake.learning.predict import as_inference_model
from stdm_drake.learning.learned_model import LearnedModel
from stdm_drake.dynamics.physics import ConstantVelocity, PlantModel, StaysPut
from stdm_drake.dynamics.verdict import learning_verdict

REPORT_STEPS = (1, 5, 10, 20, 50, 100)


def _halves(state_dim: int) -> int:
    if state_dim % 2:
        raise InputError(f"angle/velocity errors need a state [q, v] of even size, the model's has {state_dim}")
    return state_dim // 2


@dataclasses.dataclass
class OneStepErrors:
    """One-step MSE over N transitions: totals and per joint (n,) for angles q and velocities v."""
    transitions: int
    angle_mse: float
    velocity_mse: float
    angle_mse_per_joint: np.ndarray
    velocity_mse_per_joint: np.ndarray

    def as_dict(self) -> dict:
        return {key: (value.tolist() if isinstance(value, np.ndarray) else value)
                for key, value in dataclasses.asdict(self).items()}


@dataclasses.dataclass
class MultiStepErrors:
    """Open-loop MSE at steps 1..H averaged over B trajectories (curves (H,)), their spread over
    trajectories (std (H,)) and the horizon means. A rollout that diverged (a predicted state, or its
    squared error, beyond the finite numbers) counts as an infinite error from that step on: `diverged`
    trajectories, the first at step `first_diverged_step` (1-based; None: none diverged)."""
    trajectories: int
    horizon: int
    propagation: str
    angle_mse: np.ndarray
    velocity_mse: np.ndarray
    angle_mse_std: np.ndarray
    velocity_mse_std: np.ndarray
    diverged: int = 0
    first_diverged_step: int | None = None

    @property
    def angle_mse_mean(self) -> float:
        return float(self.angle_mse.mean())

    @property
    def velocity_mse_mean(self) -> float:
        return float(self.velocity_mse.mean())

    def as_dict(self) -> dict:
        result = {key: (value.tolist() if isinstance(value, np.ndarray) else value)
                  for key, value in dataclasses.asdict(self).items()}
        result.update(angle_mse_mean=self.angle_mse_mean, velocity_mse_mean=self.velocity_mse_mean)
        return result


def times_better(ratio: float, digits: int = 3) -> str:
    """A ratio baseline error / model error in words: "2.5x better" at or above 1, "5.5x worse" below it (the
    inverse, so that 0.181 reads as 5.52x worse, not "0.181x better"); "infinitely better" for an error of 0."""
    if ratio != ratio:       # NaN: a model whose error is not a number
        return "not comparable (NaN)"
    if ratio == float("inf"):
        return "infinitely better"
    if ratio >= 1.0:
        return f"{ratio:.{digits}g}x better"
    return "infinitely worse" if ratio <= 0.0 else f"{1.0 / ratio:.{digits}g}x worse"


def as_dynamics_model(model):
    """A DynamicsModel as it is; a bare network (a `TrainableModel` or its engine) as a LearnedModel of the
    paper's structure (next state from [x, a])."""
    if isinstance(model, DynamicsModel):
        return model
    return LearnedModel(as_inference_model(model))


def one_step_errors(model, states, actions, next_states) -> OneStepErrors:
    """states (N, S) [q, v], actions (N, A), next_states (N, S) -> OneStepErrors of the mean prediction
    of `model` (any DynamicsModel, or a bare network)."""
    model = as_dynamics_model(model)
    joints = _halves(model.state_dim)
    truth = np.asarray(next_states, dtype=np.float64)
    if truth.ndim != 2 or truth.shape[1] != model.state_dim:
        raise InputError(f"next_states must have shape (N, {model.state_dim}), got {truth.shape}")
    predicted = np.asarray(model.predict(states, actions).mean, dtype=np.float64)
    if predicted.shape != truth.shape:
        raise InputError(f"states and next_states differ in shape: {predicted.shape} and {truth.shape}")
    squared = (predicted - truth) ** 2
    return OneStepErrors(transitions=len(truth), angle_mse=float(squared[:, :joints].mean()),
                         velocity_mse=float(squared[:, joints:].mean()),
                         angle_mse_per_joint=squared[:, :joints].mean(axis=0),
                         velocity_mse_per_joint=squared[:, joints:].mean(axis=0))


def multi_step_errors(model, initial_states, actions, true_states, *, propagation: str = "mean",
                      particles: int = 20, seed: int = 0, implementation: str = "compiled") -> MultiStepErrors:
    """initial_states (B, S), actions (B, H, A), true_states (B, H, S) of steps 1..H -> MultiStepErrors
    of the rollout mean of `model` (any DynamicsModel, or a bare network); implementation: a network's rollout
    code ("compiled" or "numpy", `LearnedModel.rollout`; other models have one)."""
    model = as_dynamics_model(model)
    joints = _halves(model.state_dim)
    truth = np.asarray(true_states, dtype=np.float64)
    options = dict(implementation=implementation) if isinstance(model, LearnedModel) else {}
    result = model.rollout(initial_states, actions, propagation=propagation, particles=particles, seed=seed,
                           **options)
    predicted = np.asarray(result.mean, dtype=np.float64)
    if predicted.shape != truth.shape:
        raise InputError(f"rollout has shape {predicted.shape}, true_states {truth.shape}")
    with np.errstate(over="ignore"):
        squared = (predicted - truth) ** 2
    lost = ~np.isfinite(squared).all(axis=-1)                   # (B, H): diverged rows
    lost = np.logical_or.accumulate(lost, axis=1)               # (a diverged rollout stays diverged)
    squared[lost] = np.inf
    per_trajectory_q = squared[..., :joints].mean(axis=-1)     # (B, H)
    per_trajectory_v = squared[..., joints:].mean(axis=-1)
    diverged = lost.any(axis=1)
    first = int(np.argmax(lost.any(axis=0))) + 1 if diverged.any() else None
    return MultiStepErrors(trajectories=len(truth), horizon=truth.shape[1], propagation=propagation,
                           angle_mse=per_trajectory_q.mean(axis=0), velocity_mse=per_trajectory_v.mean(axis=0),
                           angle_mse_std=_spread(per_trajectory_q), velocity_mse_std=_spread(per_trajectory_v),
                           diverged=int(diverged.sum()), first_diverged_step=first)


def _spread(per_trajectory: np.ndarray) -> np.ndarray:
    """Std over trajectories (B, H) -> (H,); inf where a trajectory's error is infinite (diverged)."""
    infinite = ~np.isfinite(per_trajectory).all(axis=0)
    finite = np.where(np.isfinite(per_trajectory), per_trajectory, 0.0)
    with np.errstate(over="ignore"):
        return np.where(infinite, np.inf, finite.std(axis=0))


@dataclasses.dataclass
class ModelErrors:
    """One model's test errors on a set of trajectories, and (for learned models) its ratios to the
    physics-free baselines: one-step q MSE of the Euler step / the model's, one-step v MSE of
    "v unchanged" / the model's, and the verdict `physics.learning_verdict` draws from them."""
    name: str
    learned: bool
    one_step: OneStepErrors
    multi_step: MultiStepErrors | None   # None: one-step errors only (`train`'s validation verdict)
    ratio_q: float | None = None
    ratio_v: float | None = None
    verdict: str | None = None
    floor_ratio_q: float | None = None     # model MSE / sensor noise floor (None: no floor)
    floor_ratio_v: float | None = None

    def as_dict(self) -> dict:
        return dict(name=self.name, learned=self.learned, one_step=self.one_step.as_dict(),
                    multi_step=None if self.multi_step is None else self.multi_step.as_dict(), ratio_to_euler_q=self.ratio_q,
                    ratio_to_velocity_unchanged_v=self.ratio_v, over_noise_floor_q=self.floor_ratio_q,
                    over_noise_floor_v=self.floor_ratio_v, verdict=self.verdict)


def physics_baselines(sample_period: float, state_dim: int, action_dim: int, robot=None, plant: bool = True,
                      plant_config=None) -> list:
    """The baselines every learned number stands beside: the Euler step (q) / "v unchanged" (v), "stays
    put" (open loop), and, with plant, `robot`'s own rigid-body plant stepping the recorded torque, simulated as
    `plant_config` says (a `robots.plant.PlantConfig`: for a dataset, the plant it records without its effects,
    `DatasetMetadata.plant_config(effects=False)`; None: the default plant)."""
    if plant and robot is None:
        raise ValueError("the plant baseline needs the robot (or plant=False)")
    models = [ConstantVelocity(state_dim, action_dim, sample_period), StaysPut(state_dim, action_dim, sample_period)]
    if plant:
        models.append(PlantModel(sample_period, plant_config, robot=robot))
    return models


def compare_with_baselines(models, transitions, rollout_data, *, propagation: str = "mean", particles: int = 20,
                           seed: int = 0, noise_floor: dict | None = None,
                           implementation: str = "compiled") -> list[ModelErrors]:
    """Errors of every model (DynamicsModel) on the same transitions and rollouts (x0, actions, truth; None:
    one-step errors only; implementation: the networks' rollout code); learned models are rated against the first
    ConstantVelocity among them and, given the sensor's noise_floor ({"q", "v"} one-step MSE,
    `data.inspect.noise_floor`), against it."""
    rows = []
    for model in models:
        one = one_step_errors(model, transitions.state, transitions.action, transitions.next_state)
        multi = None if rollout_data is None else multi_step_errors(
            model, *rollout_data, propagation=propagation if model.learned else "mean", particles=particles,
            seed=seed, implementation=implementation)
        rows.append(ModelErrors(name=model.name, learned=model.learned, one_step=one, multi_step=multi))
    euler = next((row for row, model in zip(rows, models) if isinstance(model, ConstantVelocity)), None)
    if euler is not None:
        for row in rows:
            if row.learned:
                row.ratio_q = _ratio(euler.one_step.angle_mse, row.one_step.angle_mse)
                row.ratio_v = _ratio(euler.one_step.velocity_mse, row.one_step.velocity_mse)
                if noise_floor:
                    row.floor_ratio_q = _floor_ratio(row.one_step.angle_mse, noise_floor["q"])
                    row.floor_ratio_v = _floor_ratio(row.one_step.velocity_mse, noise_floor["v"])
                row.verdict = learning_verdict(row.ratio_q, row.ratio_v, row.floor_ratio_q, row.floor_ratio_v)
    return rows


def _floor_ratio(model: float, floor: float) -> float | None:
    return float(model / floor) if floor > 0 else None


def _ratio(baseline: float, model: float) -> float:
    return float(baseline / model) if model > 0 else float("inf")


def trajectory_rollout_data(dataset, indices, horizon: int | None = None):
    """(x_0 (B, 2n), tau (B, H, m), [q, v] of steps 1..H (B, H, 2n)) for dataset trajectories; H is the
    shortest selected trajectory's length, capped at `horizon`."""
    trajectories = [dataset.trajectory(int(i)) for i in indices]
    if not trajectories:
        raise InputError("no trajectories selected")
    length = min(len(t.tau) for t in trajectories)
    if horizon is not None:
        if horizon < 1:
            raise InputError(f"horizon must be >= 1, got {horizon}")
        length = min(length, horizon)
    states = np.stack([np.hstack([t.q[:length + 1], t.v[:length + 1]]) for t in trajectories])
    actions = np.stack([t.tau[:length] for t in trajectories])
    return states[:, 0], actions, states[:, 1:]
