"""Trajectory optimization for the MPC, apart from the controller: the tracking cost, the interface
every optimizer implements (`TrajectoryOptimizer`) and the one its settings implement (`OptimizerSettings`).
`stdm_drake.closed_loop.rti.RtiSolver` and `stdm_drake.closed_loop.ilqr.IlqrSolver` are optimizers, `Rti` and
`Ilqr` beside them their settings; `MpcController` takes any optimizer (`optimizer=`), so a sampling optimizer
(CEM, MPPI) plugs in without touching the controller.

A new optimizer for the settings files: a `TrajectoryOptimizer`, a dataclass of its settings deriving from
`OptimizerSettings` (its class name is its YAML tag: `optimizer: !Name {...}`), and that class added to
`stdm_drake.closed_loop.mpc.OptimizerConfig`, the one list of the optimizers a file may name.

For a robot of n joints and m actuated ones, a horizon of H steps: states x (H+1, 2n) = [q rad, v rad/s],
torques u (H, m) N m, the reference r (H+1, 2n) and the feedforward torques u_ff (H, m).
"""
from __future__ import annotations

import abc
import dataclasses

import numpy as np

from stdm_drake.closed_loop.constraints import StateBounds


@dataclasses.dataclass(frozen=True)
class TrackingCost:
    """sum_k w_k (x_k+1 - r_k+1)^T Q (x_k+1 - r_k+1) + (u_k - u_ff,k)^T R (u_k - u_ff,k), k = 0..H-1,
    with w_k = 1 except the last step's, `terminal_factor`. Q (2n, 2n) and R (m, m) are diagonal."""
    Q: np.ndarray
    R: np.ndarray
    terminal_factor: float

    @classmethod
    def from_weights(cls, position_weight, velocity_weight, effort_weight, terminal_factor: float) -> "TrackingCost":
        """From per-joint weights: position (n) 1/rad², velocity (n) s²/rad², effort (m) 1/(N m)²."""
        return cls(Q=np.diag(np.concatenate([np.asarray(position_weight, dtype=float),
                                             np.asarray(velocity_weight, dtype=float)])),
                   R=np.diag(np.asarray(effort_weight, dtype=float)), terminal_factor=float(terminal_factor))

    def step_weights(self, horizon: int) -> np.ndarray:
        """w (H,): ones, the last `terminal_factor`."""
        weights = np.ones(horizon)
        weights[-1] = self.terminal_factor
        return weights

    def value(self, x: np.ndarray, u: np.ndarray, reference: np.ndarray, u_ff: np.ndarray) -> float:
        """The cost of states x (H+1, 2n) and torques u (H, m) against reference (H+1, 2n) and u_ff (H, m)."""
        error = x[1:] - reference[1:]
        state = np.einsum("ki,ij,kj->k", error, self.Q, error) @ self.step_weights(len(u))
        effort = np.einsum("ki,ij,kj->", u - u_ff, self.R, u - u_ff)
        return float(state + effort)


@dataclasses.dataclass
class OptimizerResult:
    """u: (H, m) optimized torques; x: (H+1, 2n) predicted states; cost (the state limits' penalty included);
    iterations; finite (every predicted state finite); constraint_active: a torque bound or a state limit active
    in the solution; slack: the largest crossing of a state limit the solution accepts (rad or rad/s, 0: none)."""
    u: np.ndarray
    x: np.ndarray
    cost: float
    iterations: int
    finite: bool
    constraint_active: bool = False
    slack: float = 0.0


class OptimizerSettings(abc.ABC):
    """An optimizer's own settings, the value of `optimizer:` in the MPC settings (a dataclass, tagged in YAML
    by its class name): it checks itself and builds its optimizer."""

    @abc.abstractmethod
    def validate(self) -> None:
        """InputError (one line, starting "mpc optimizer !Name") for settings the optimizer cannot run."""

    @abc.abstractmethod
    def solver(self, model, cost: TrackingCost, effort_limit: np.ndarray, horizon: int,
               bounds: StateBounds | None = None) -> "TrajectoryOptimizer":
        """The optimizer of these settings for `model`, `cost` and torques within +-effort_limit (m,) N m over
        `horizon` sample periods, the predicted states within `bounds` (`constraints.StateBounds`; None: the
        controller before constraints, torques clipped after the step and no state limit) (InputError where it
        cannot solve that problem)."""

    def check_horizon(self, horizon: int) -> None:
        """InputError (one line) for settings that do not fit a horizon of `horizon` sample periods; none here."""

    def record(self) -> dict:
        """What an output records of these settings: its tag ("type", the class name) and its fields."""
        return dict(type=type(self).__name__, **dataclasses.asdict(self))

    def work_per_step(self, horizon: int) -> int:
        """The work of one control step over `horizon` sample periods, in model steps of one state (a node's
        linearization counts LINEARIZATION_STEPS): what `MpcConfig.validate` holds to MAX_WORK_PER_STEP."""
        return int(horizon) * LINEARIZATION_STEPS


# A linearization of the model at one node, in model steps: its Jacobians through 2n + m tangents and the node's
# share of the quadratic program, rounded up (a conservative weight for the budget below).
LINEARIZATION_STEPS = 100
# The most work one control step may ask for (OptimizerSettings.work_per_step): 12x the PETS budget (CEM 400 samples
# x 5 iterations x 20 particles x horizon 20 = 8e5, about 3 s per step measured: BENCHMARKS.md); beyond it a closed
# loop of 100 steps would run for hours, so the settings are refused before any work, with the estimate.
MAX_WORK_PER_STEP = 10_000_000


class TrajectoryOptimizer(abc.ABC):
    """Minimizes `cost` over torque sequences within +-effort_limit (m,) N m, predicting with `model` (a
    `DynamicsModel`: `step_single` and `linearize` are what optimizers call, through `predict` and
    `linearize` here; a model with only `step(x (N, 2n), u (N, m)) -> (N, 2n)` and `jacobians` works too), the
    predicted states within `bounds` (`constraints.StateBounds`, softened; None: constraints off)."""

    def __init__(self, model, cost: TrackingCost, effort_limit: np.ndarray, bounds: StateBounds | None = None):
        self.model = model
        # a `DynamicsModel`'s one-row step and batched linearization; a model with only step and jacobians
        # (the interface before them) gets both from those
        self._step_single = getattr(model, "step_single", None) or (lambda x, u: model.step(x[None], u[None])[0])
        self.linearize = getattr(model, "linearize", None) or (lambda x, u: (model.step(x, u), *model.jacobians(x, u)))
        self.cost_function = cost
        self.effort_limit = np.asarray(effort_limit, dtype=float)
        self.joints = len(self.effort_limit)
        self.state_dim = len(cost.Q)
        self.bounds = bounds

    def cost(self, x: np.ndarray, u: np.ndarray, reference: np.ndarray, u_ff: np.ndarray) -> float:
        """The tracking cost of states x (H+1, 2n) and torques u (H, m), plus the state limits' penalty."""
        value = self.cost_function.value(x, u, reference, u_ff)
        return value if self.bounds is None else value + self.bounds.penalty(x[1:])

    def rollout(self, x0: np.ndarray, u: np.ndarray, offset: np.ndarray | None = None) -> np.ndarray:
        """Predicted states (H+1, 2n) from x0 (2n,) under u (H, m), each step shifted by `offset` (2n,)."""
        offset = np.zeros(self.state_dim) if offset is None else offset
        x = np.empty((len(u) + 1, self.state_dim))
        x[0] = x0
        for k in range(len(u)):
            x[k + 1] = self.predict(x[k], u[k], offset)
        return x

    def predict(self, x: np.ndarray, u: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """One shifted model step: f(x (2n,), u (m,)) + offset (2n,)."""
        return self._step_single(x, u) + offset

    @abc.abstractmethod
    def solve(self, x0: np.ndarray, u_init: np.ndarray, reference: np.ndarray, u_ff: np.ndarray,
              offset: np.ndarray | None = None, x_init: np.ndarray | None = None) -> OptimizerResult:
        """Torques for x0 (2n,) from the warm start u_init (H, m), against reference (H+1, 2n) and u_ff
        (H, m); offset (2n,): a constant added to every predicted step (the disturbance estimate); x_init
        (H+1, 2n): the previous solution's states shifted by one period (None on the first step), which
        multiple-shooting optimizers start from and single-shooting ones ignore."""
