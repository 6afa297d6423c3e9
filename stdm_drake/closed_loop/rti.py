"""The real-time iteration (RTI): the MPC's default `TrajectoryOptimizer`, a multiple-shooting Gauss-Newton
step per control step with no sequential rollout (Diehl, Bock & Schlöder 2005; acados' SQP_RTI).

The horizon's states are kept from one control step to the next (the previous solution shifted by one
period, its first node replaced by the measurement), so every node's prediction and Jacobians come from
one batched call, `DynamicsModel.linearize`. With F_k = f(X_k, u_k) + d (d the disturbance estimate) and
the gaps c_k = F_k - X_k+1, the state deviations of a torque step δu follow

    δx_k+1 = A_k δx_k + B_k δu_k + c_k,    δx_0 = 0,

for every δu at once (one small product per node). Stacked, δx = Γ δu + s with Γ (H 2n, H m) block lower triangular; the tracking cost then gives one dense
(H m) x (H m) positive-definite system, solved by one Cholesky factorization. With the robot's limits on (the
MPC settings' `constraints:`, `constraints.py`) that solution is the step when it keeps every torque inside its
effort limit and every predicted state inside its bounds (then it is the constrained QP's solution too, bit for
bit the unconstrained step); otherwise the step is the box- and state-constrained QP's solution (`CondensedQp`:
DAQP, the state limits soft). With constraints off the torques are clipped to the effort limits instead (the
controller before constraints). The nodes move to their linear prediction (the first one to the model's own step
from the measurement, which the disturbance observer compares with the next measurement) and warm-start
the next control step. More iterations per step (`iterations`) repeat linearize + solve on the updated
nodes (a full SQP).

The multi-level iteration (`jacobian_refresh: K`; default `all`, the exact step above): each iteration computes
the Jacobians (A_k, B_k) of the nodes `refreshed_nodes` names only, about K of the H (every k with k mod P = 0, P
= ceil(H / K), and the newest node), and keeps the others' from the last solve, shifted by one period as the
warm start shifts the nodes; the predictions F_k come from the model's forward step at every node. Each node's
Jacobians are at most P - 1 periods old; the Gauss-Newton step is then inexact (level B of the multi-level
iterations of Bock, Diehl, Kirches & Schlöder), its predictions exact. A solve without a warm start (the first
control step, after a fallback) computes every node's. docs/realtime.md measures what it saves and costs.

Its settings: `Rti` (`optimizer: !Rti {iterations: 1, regularization: 1.0e-6, jacobian_refresh: all,
implementation: compiled}` in the MPC settings). `implementation: compiled` (the default) runs the whole control step in C++ (`compiled.py`) for
the models it covers; `numpy` runs this module, the reference the compiled step is tested equal to.
Shapes for n joints, m actuated, horizon H as in `optimizer`. Horizons with H m > `MAX_CONDENSED` use
the iLQR (`optimizer: !Ilqr {...}`), whose Riccati recursion is linear in H.
"""
import dataclasses
import typing

import numpy as np
from scipy.linalg.lapack import dpotrf as cholesky, dpotrs as cholesky_solve

from stdm_drake.closed_loop.compiled import CompiledRtiSolver
from stdm_drake.dynamics.compiled_core import IMPLEMENTATIONS, compiled_model
from stdm_drake.closed_loop.constraints import CondensedQp, StateBounds
from stdm_drake.closed_loop.optimizer import (LINEARIZATION_STEPS, OptimizerResult, OptimizerSettings, TrackingCost,
                                              TrajectoryOptimizer)
from stdm_drake.errors import InputError

MAX_CONDENSED = 600    # H m up to which the dense system is solved (its cost grows as (H m)^3: 0.1 ms at 120)
MAX_ITERATIONS = 100   # Gauss-Newton iterations per control step: more is a run that does not end


@dataclasses.dataclass
class Rti(OptimizerSettings):
    """The real-time iteration's settings, the MPC's default optimizer (YAML `optimizer: !Rti {...}`):
    Gauss-Newton iterations per control step (1: the real-time iteration), the initial Levenberg-Marquardt
    regularization added to the Hessian's diagonal (multiplied by 10 until it is positive definite), and the
    implementation: "compiled" (C++, `compiled.CompiledRtiSolver`, for the models it covers; the others run the
    numpy step and the solver's `implementation` says why) or "numpy" (`RtiSolver`, the reference); and the
    Jacobians each iteration computes: "all" (every node's, the exact step) or a number K of the horizon's H nodes
    (1..H; the multi-level iteration of the module docstring)."""
    iterations: int = 1
    regularization: float = 1e-6
    jacobian_refresh: typing.Union[int, str] = "all"
    implementation: str = "compiled"

    def refresh_count(self) -> int:
        """K as the compiled step takes it: 0 for "all"."""
        return 0 if self.jacobian_refresh == "all" else int(self.jacobian_refresh)

    def work_per_step(self, horizon: int) -> int:
        """Each iteration linearizes every node."""
        return int(self.iterations) * int(horizon) * LINEARIZATION_STEPS

    def validate(self) -> None:
        """InputError for settings the solver cannot run: iterations outside 1..MAX_ITERATIONS, a regularization
        outside [0, 1e6]."""
        if not 1 <= self.iterations <= MAX_ITERATIONS:
            raise InputError(f"mpc optimizer !Rti iterations must be in 1..{MAX_ITERATIONS}, got {self.iterations}")
        if not (np.isfinite(self.regularization) and 0 <= self.regularization <= 1e6):
            raise InputError(f"mpc optimizer !Rti regularization must be in [0, 1e6], got {self.regularization}")
        refresh = self.jacobian_refresh
        if refresh != "all" and (isinstance(refresh, (bool, str)) or not isinstance(refresh, int) or refresh < 1):
            raise InputError(f"mpc optimizer !Rti jacobian_refresh must be all or a number of nodes from 1 to the "
                             f"horizon, got {refresh!r}")
        if self.implementation not in IMPLEMENTATIONS:
            raise InputError(f"mpc optimizer !Rti implementation must be one of {', '.join(IMPLEMENTATIONS)}, got "
                             f"{self.implementation!r}")

    def check_horizon(self, horizon: int) -> None:
        """InputError for a jacobian_refresh beyond the horizon's nodes."""
        if self.refresh_count() > horizon:
            raise InputError(f"mpc optimizer !Rti jacobian_refresh {self.jacobian_refresh} is beyond the horizon's "
                             f"{horizon} nodes (all: every node)")

    def solver(self, model, cost: TrackingCost, effort_limit: np.ndarray, horizon: int,
               bounds: StateBounds | None = None) -> TrajectoryOptimizer:
        """The compiled solver (`compiled.CompiledRtiSolver`) where the implementation is "compiled" and it covers
        `model`, else an RtiSolver (its `implementation` says why); InputError for a horizon whose dense system is
        beyond MAX_CONDENSED unknowns, or a compiled step that is not built."""
        joints = len(effort_limit)
        self.check_horizon(horizon)
        if horizon * joints > MAX_CONDENSED:
            raise InputError(f"mpc horizon {horizon} x {joints} joints = {horizon * joints} torques is beyond the "
                             f"real-time iteration's {MAX_CONDENSED}; use `optimizer: !Ilqr {{}}` for long horizons")
        if self.implementation == "compiled":
            core_model, why_not = compiled_model(model)
            if core_model is not None:
                return CompiledRtiSolver(model, cost, effort_limit, self, bounds, core_model)
            solver = RtiSolver(model, cost, effort_limit, self, bounds)
            solver.implementation = f"numpy (the compiled step does not cover {why_not})"
            return solver
        return RtiSolver(model, cost, effort_limit, self, bounds)


def affine_recursion(A: np.ndarray, E: np.ndarray) -> np.ndarray:
    """Y (H, S, W) with Y_0 = E_0 and Y_k = A_k Y_k-1 + E_k, for A (H, S, S) and E (H, S, W): one
    (S, S) x (S, W) product per node, in place (two numpy calls each; a parallel prefix scan of batched
    products measured 9x slower at H = 20, S = 12, W = 121)."""
    value = E.copy()
    for k in range(1, len(A)):
        np.matmul(A[k], value[k - 1], out=value[k])
        value[k] += E[k]
    return value


class RtiSolver(TrajectoryOptimizer):
    """The real-time iteration over a horizon for one prediction model and one cost (module docstring)."""
    implementation = "numpy"

    def __init__(self, model, cost: TrackingCost, effort_limit: np.ndarray, config: Rti | None = None,
                 bounds: StateBounds | None = None):
        super().__init__(model, cost, effort_limit, bounds)
        self.config = config or Rti()
        self.config.validate()
        self._weights = {}     # horizon -> (state weights (H 2n,), effort weights (H m,))
        self.qp = None if bounds is None else CondensedQp(bounds, self.joints)
        self._kept = None      # the last solve's Jacobians (A (H, S, S), B (H, S, m)) where the refresh is partial

    def refreshed_nodes(self, horizon: int) -> np.ndarray:
        """The nodes (indices < H) whose Jacobians an iteration computes: every k with k mod P = 0, P = ceil(H / K),
        and the newest, H - 1 (each node moves down one position per control step, so it is refreshed at least
        every P steps); all H for "all"."""
        count = self.config.refresh_count()
        period = -(-horizon // count) if count else 1
        nodes = np.arange(horizon)
        return nodes[(nodes % period == 0) | (nodes == horizon - 1)]

    def _linearize_nodes(self, x, u, nodes, A, B):
        """Predictions F (H, S) at every node of x (H+1, S), u (H, m) (the model's forward step; the linearization's
        own at `nodes`), and A (H, S, S), B (H, S, m) with the Jacobians of `nodes` replaced, in place."""
        others = np.setdiff1d(np.arange(len(u)), nodes)
        following = np.empty((len(u), self.state_dim))
        following[nodes], A[nodes], B[nodes] = self.linearize(x[nodes], u[nodes])
        if len(others):
            following[others] = self.model.step(x[others], u[others])
        return following

    def solve(self, x0: np.ndarray, u_init: np.ndarray, reference: np.ndarray, u_ff: np.ndarray,
              offset: np.ndarray | None = None, x_init: np.ndarray | None = None) -> OptimizerResult:
        """x0 (2n,); u_init (H, m) and x_init (H+1, 2n) the warm start (its torques moved into the box first) (x_init None: a rollout of u_init from
        x0 gives the first nodes); reference (H+1, 2n); u_ff (H, m); offset (2n,) added to every prediction."""
        offset = np.zeros(self.state_dim) if offset is None else np.asarray(offset, dtype=float)
        u = np.clip(u_init, -self.effort_limit, self.effort_limit)
        warm = x_init is not None and bool(np.all(np.isfinite(x_init)))
        if not warm:
            x = self.rollout(x0, u, offset)
        else:
            x = np.array(x_init, dtype=float)
            x[0] = x0
        horizon = len(u)
        nodes = self.refreshed_nodes(horizon)
        partial = len(nodes) < horizon
        kept, self._kept = self._kept, None
        # the kept Jacobians shifted by one period (node k's are the last solve's node k + 1's), from a warm start only
        reuse = partial and warm and kept is not None and kept[0].shape == (horizon, self.state_dim, self.state_dim)
        if reuse:
            A, B = np.empty_like(kept[0]), np.empty_like(kept[1])
            A[:-1], B[:-1] = kept[0][1:], kept[1][1:]
        if not np.all(np.isfinite(x)):
            return OptimizerResult(u, x, np.inf, 0, False)
        mu = self.config.regularization
        iterations = 0
        active, slack = False, 0.0
        for iterations in range(1, self.config.iterations + 1):
            step = None
            if partial and (iterations > 1 or reuse):
                following = self._linearize_nodes(x, u, nodes, A, B)
            else:
                following, A, B = self.linearize(x[:-1], u)
                if partial:     # (kept and refreshed in place)
                    A, B = np.array(A, dtype=float), np.array(B, dtype=float)
            if np.all(np.isfinite(following)) and np.all(np.isfinite(A)) and np.all(np.isfinite(B)):
                for _ in range(12):    # raise the regularization until the system is positive definite
                    step = self._step(x, u, reference, u_ff, following + offset, A, B, mu)
                    if step is not None:
                        break
                    mu = max(10.0 * mu, 1e-9)
            if step is None:
                return OptimizerResult(u, x, np.inf, iterations, False)
            u, x, active, slack = step
            x[1] = self.predict(x0, u[0], offset)     # the first node: the model's own step from the measurement
        if partial:
            self._kept = (A, B)
        cost = self.cost(x, u, reference, u_ff)
        return OptimizerResult(u, x, cost, iterations, bool(np.all(np.isfinite(x)) and np.isfinite(cost)),
                               active, slack)

    def _step(self, x, u, reference, u_ff, predicted, A, B, mu):
        """(u_new (H, m), x_new (H+1, 2n), a constraint active, slack used) of one Gauss-Newton step, or None if
        the system is not positive definite. predicted: F_k = f(x_k, u_k) + d (H, 2n)."""
        horizon, S, m = len(u), self.state_dim, self.joints
        width = horizon * m + 1                       # columns: every δu_j, then the gaps' response
        inputs = np.zeros((horizon, S, width))
        index = np.arange(horizon)[:, None]
        inputs[index, :, index * m + np.arange(m)] = B.transpose(0, 2, 1)     # δu_k enters node k+1 through B_k
        inputs[:, :, -1] = predicted - x[1:]
        response = affine_recursion(A, inputs).reshape(horizon * S, width)
        gamma, drift = response[:, :-1], response[:, -1]
        state_weight, effort_weight = self._cost_weights(horizon)
        error = (x[1:] - reference[1:]).ravel() + drift
        hessian = gamma.T @ (state_weight[:, None] * gamma)
        hessian[np.diag_indices_from(hessian)] += effort_weight + mu
        gradient = gamma.T @ (state_weight * error) + effort_weight * (u - u_ff).ravel()
        factor, info = cholesky(hessian, lower=1)     # LAPACK directly: microseconds, not numpy's checks
        if info != 0 or not np.all(np.isfinite(factor)):
            return None
        solution, _ = cholesky_solve(factor, gradient, lower=1)
        active, slack, states = False, 0.0, None
        if self.qp is None:
            u_new = np.clip(u - solution.reshape(horizon, m), -self.effort_limit, self.effort_limit)
        else:
            u_new = u - solution.reshape(horizon, m)
            states = x[1:].ravel() + drift + gamma @ (u_new - u).ravel()
            if self._inside(u_new, states):
                self.qp.forget()
            else:
                lower = (-self.effort_limit - u).ravel()
                upper = (self.effort_limit - u).ravel()
                try:
                    qp = self.qp.solve(hessian, gradient, lower, upper, gamma, x[1:].ravel() + drift)
                except ArithmeticError:
                    return None
                # the box holds to DAQP's round-off; the projection only removes that
                u_new = np.clip(u + qp.delta.reshape(horizon, m), -self.effort_limit, self.effort_limit)
                active, slack, states = qp.active, qp.slack, None
        if states is None:      # (the unconstrained step's prediction, where it is the step, is already made)
            states = x[1:].ravel() + drift + gamma @ (u_new - u).ravel()
        x_new = np.empty_like(x)
        x_new[0] = x[0]
        x_new[1:] = states.reshape(horizon, S)
        return u_new, x_new, active, slack

    def _inside(self, u: np.ndarray, states: np.ndarray) -> bool:
        """Whether torques u (H, m) keep their effort limits and stacked states (H S,) their bounds (strictly)."""
        bounds = self.bounds
        stacked = states.reshape(-1, self.state_dim)
        return bool(np.all(np.abs(u) < self.effort_limit) and np.all(stacked < bounds.upper)
                    and np.all(stacked > bounds.lower))

    def _cost_weights(self, horizon: int) -> tuple[np.ndarray, np.ndarray]:
        weights = self._weights.get(horizon)
        if weights is None:
            terminal = self.cost_function.step_weights(horizon)
            weights = self._weights[horizon] = ((terminal[:, None] * np.diag(self.cost_function.Q)[None]).ravel(),
                                                np.tile(np.diag(self.cost_function.R), horizon))
        return weights
