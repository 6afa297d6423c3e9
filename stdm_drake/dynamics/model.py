"""The one model contract: every state-transition model x_{t+1} = f(x_t, a_t) implements `DynamicsModel`.

Learned models (`learning.learned_model.LearnedModel`: the paper's D/P/DE/PE networks and the
physics-structured networks), the physics baselines and the robot's own plant as a model
(`dynamics.physics`) all implement it, so `evaluate`, `view`, the LeafSystem and the MPC accept any
of them. As in mbrl-lib's `mbrl.models.Model`, the contract is small:

    sizes           state_dim S = 2n ([q rad, v rad/s]), action_dim A = m (N m), sample_period (s)
    step(x, a)      next states (N, S) for x (N, S), a (N, A): the mean prediction, no input checks
    step_single(x, a)  one row on 1-D arrays, x (S,), a (A,) -> (S,): the same numbers as `step`, for the
                    MPC's sequential rollouts (models override it where a row costs less than a batch)
    predict(x, a)   a checked one-step `Prediction` (mean, variance); deterministic models give
                    zero variance
    rollout(x0, a)  open-loop prediction of steps 1..T: x0 (B, S), a (B, T, A) -> `Rollout`
    jacobians(x, a) d step / d(x, a) at H rows: A (H, S, S), B (H, S, A)
    linearize(x, a) a whole horizon at once: next states (H, S), A and B at H rows from one batched call
                    (the MPC's way to evaluate a horizon; models that share work between the value and
                    its Jacobians override it)
    member_step(x, a, rng)  particles laid out member by member, x (E, M, S), a (E, M, A) -> (E, M, S): row
                    block e follows ensemble member e, sampling its Gaussian with `rng` (sampling MPC)
"""
from __future__ import annotations

import abc
import dataclasses

import numpy as np

from stdm_drake.errors import InputError

# How a rollout carries an ensemble's spread: "mean", each step from the previous mean; PETS trajectory
# sampling, each particle following one member: "ts1" draws it again every step, "tsinf" keeps it throughout.
PROPAGATIONS = ("mean", "ts1", "tsinf")


@dataclasses.dataclass
class Prediction:
    """One-step prediction for B states. mean, variance (B, S): ensemble mean and total variance
    (member spread + mean aleatoric); member_means (E, B, S); member_variances (E, B, S) or None."""
    mean: np.ndarray
    variance: np.ndarray
    member_means: np.ndarray
    member_variances: np.ndarray | None


@dataclasses.dataclass
class Rollout:
    """Open-loop prediction of steps 1..T. mean, variance (B, T, S); particles (B, P, T, S) for TS."""
    mean: np.ndarray
    variance: np.ndarray
    particles: np.ndarray | None = None


def check_batch(values, width: int, name: str, *, sequence: bool = False) -> np.ndarray:
    """float64 (B, width) or, with sequence, (B, T, width); InputError on another shape or non-finite values."""
    array = np.asarray(values, dtype=np.float64)
    wanted = 3 if sequence else 2
    if array.ndim != wanted or array.shape[-1] != width:
        shape = "(B, T, {})" if sequence else "(B, {})"
        raise InputError(f"{name} must have shape {shape.format(width)}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise InputError(f"{name} contain NaN or infinite values")
    return array


class DynamicsModel(abc.ABC):
    """A state-transition model of a robot with n joints, m of them actuated, at a fixed sample period.

    Subclasses set `name`, `state_dim` (2n), `action_dim` (m) and `sample_period` (s; None for a
    bare network that was not trained on a dataset) and implement `step` and `jacobians`.
    `probabilistic` and `ensemble_size` tell whether `predict` has a variance worth showing.
    """
    name: str = "model"
    state_dim: int
    action_dim: int
    sample_period: float | None = None
    probabilistic: bool = False
    ensemble_size: int = 1
    learned: bool = False          # True for models fitted to data (the baselines' gate applies to them)

    @property
    def num_joints(self) -> int:
        """n: half the state."""
        return self.state_dim // 2

    @abc.abstractmethod
    def step(self, x: np.ndarray, a: np.ndarray) -> np.ndarray:
        """Mean next states (N, S) float64 for x (N, S) [q rad, v rad/s] and a (N, A) N m."""

    @abc.abstractmethod
    def jacobians(self, x: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """d step / d x (H, S, S) and d step / d a (H, S, A) at the rows x (H, S), a (H, A)."""

    def describe(self) -> str:
        """One line on what the model is (a model file's models say how it was trained or identified)."""
        return f"model {self.name}"

    def step_single(self, x: np.ndarray, a: np.ndarray) -> np.ndarray:
        """`step` of one row: x (S,), a (A,) float64 -> (S,), unchecked."""
        return self.step(x[None], a[None])[0]

    def member_step(self, x: np.ndarray, a: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
        """Next states (E, M, S) of particles laid out member by member: rows x[e] (M, S), a[e] (M, A) follow
        member e of an ensemble of E = `ensemble_size` members; a probabilistic model samples its predicted
        Gaussian with `rng` (None: its mean). What sampling MPC rolls out (`closed_loop.sampling`); a model
        of one deterministic member gives `step` of every row."""
        count, rows, size = x.shape
        return self.step(x.reshape(-1, size), a.reshape(count * rows, -1)).reshape(x.shape)

    def linearize(self, x: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every row of a horizon at once: (next states (H, S), d step / d x (H, S, S), d step / d a (H, S, A))
        at x (H, S), a (H, A), the same numbers as `step` and `jacobians`."""
        return (self.step(x, a), *self.jacobians(x, a))

    def predict(self, x, a) -> Prediction:
        """Checked one-step prediction for x (B, S), a (B, A) (or unbatched): mean and variance (B, S)."""
        states, actions, added = self._checked_pair(x, a)
        mean = self.step(states, actions)
        variance = np.zeros_like(mean)
        if added:
            return Prediction(mean=mean[0], variance=variance[0], member_means=mean[None, 0], member_variances=None)
        return Prediction(mean=mean, variance=variance, member_means=mean[None], member_variances=None)

    def rollout(self, x0, actions, *, propagation: str = "mean", particles: int = 20, seed: int | None = 0) -> Rollout:
        """Open-loop prediction of steps 1..T from x0 (B, S) under actions (B, T, A): mean (B, T, S). A
        rollout that diverges (a state beyond the finite numbers) holds NaN from the step after on.

        Only "mean" propagation (each step from the previous mean); ensembles of networks also offer
        PETS trajectory sampling (`LearnedModel.rollout`)."""
        if propagation not in PROPAGATIONS:
            raise InputError(f"propagation must be one of {PROPAGATIONS}, got {propagation!r}")
        if propagation != "mean":
            raise InputError(f"{self.name}: only 'mean' propagation (ts1/tsinf sample the members of an ensemble "
                             "in the paper's structure: train --model DE/PE --predicts state --inputs raw)")
        states = check_batch(x0, self.state_dim, "initial_states")
        sequence = check_batch(actions, self.action_dim, "actions", sequence=True)
        if len(sequence) != len(states):
            raise InputError(f"initial_states and actions have different batch sizes: {len(states)} and {len(sequence)}")
        horizon = sequence.shape[1]
        mean = np.full((len(states), horizon, self.state_dim), np.nan)
        variance = np.full_like(mean, np.nan)
        current, going = states, np.ones(len(states), dtype=bool)
        with np.errstate(over="ignore", invalid="ignore"):   # (a diverging row overflows: the states report it)
            for k in range(horizon):   # a row whose state left the finite numbers has diverged: NaN from there on
                if not going.any():
                    break
                step_mean, step_variance = self._rollout_step(current[going], sequence[going, k])
                mean[going, k], variance[going, k] = step_mean, step_variance
                current = mean[:, k]
                going &= np.isfinite(current).all(axis=1)
        return Rollout(mean=mean, variance=variance)

    def _rollout_step(self, x: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(mean, variance) (B, S) of one rollout step; models with a variance override it."""
        mean = self.step(x, a)
        return mean, np.zeros_like(mean)

    def _checked_pair(self, x, a) -> tuple[np.ndarray, np.ndarray, bool]:
        states = np.asarray(x, dtype=np.float64)
        added = states.ndim == 1
        states = check_batch(states[None] if added else states, self.state_dim, "states")
        actions = np.asarray(a, dtype=np.float64)
        actions = check_batch(actions[None] if added and actions.ndim == 1 else actions, self.action_dim, "actions")
        if len(actions) != len(states):
            raise InputError(f"states and actions have different batch sizes: {len(states)} and {len(actions)}")
        return states, actions, added


class HeldInputSubsteps(DynamicsModel):
    """A model of period k·h made of k steps of a model of period h with the action held (a zero-order
    hold over the longer period, as the recorder holds torques): runs a model trained at a finer sample
    period on data of a coarser one. Jacobians by the chain rule over the k steps."""

    def __init__(self, inner: DynamicsModel, substeps: int, name: str | None = None):
        if not isinstance(substeps, int) or substeps < 1:
            raise InputError(f"substeps must be an integer >= 1, got {substeps!r}")
        self.inner, self.substeps = inner, substeps
        self.name = name or f"{inner.name} x{substeps}"
        self.state_dim, self.action_dim, self.learned = inner.state_dim, inner.action_dim, inner.learned
        self.sample_period = None if inner.sample_period is None else inner.sample_period * substeps

    def step(self, x: np.ndarray, a: np.ndarray) -> np.ndarray:
        for _ in range(self.substeps):
            x = self.inner.step(x, a)
        return x

    def jacobians(self, x: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.linearize(x, a)[1:]

    def linearize(self, x: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """d x_k / d x_0 = A_k ... A_1 and d x_k / d a = sum_j A_k ... A_{j+1} B_j, each A_j, B_j at the
        j-th intermediate state (one `linearize` of the inner model per substep)."""
        state_jacobian = np.broadcast_to(np.eye(self.state_dim), (len(x), self.state_dim, self.state_dim)).copy()
        action_jacobian = np.zeros((len(x), self.state_dim, self.action_dim))
        for _ in range(self.substeps):
            x, step_x, step_a = self.inner.linearize(x, a)
            state_jacobian = step_x @ state_jacobian
            action_jacobian = step_x @ action_jacobian + step_a
        return x, state_jacobian, action_jacobian
