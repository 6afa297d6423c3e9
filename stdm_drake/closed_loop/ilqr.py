"""Box-constrained iLQR (iterative LQR) over a horizon for one prediction model and one tracking cost: a
single-shooting `TrajectoryOptimizer` (`stdm_drake.closed_loop.optimizer`). Each iteration rolls the model out
node by node, linearizes every node in one batched call (`DynamicsModel.linearize`), runs the Riccati recursion
(linear in the horizon) and line-searches the step with its feedback gains.

With the robot's limits on (`constraints.py`) the backward pass is box-DDP's (Tassa, Mansard & Todorov 2014):
at every node the torque step is the solution of the box QP min 1/2 d^T Q_uu d + Q_u^T d over the torques'
room to their effort limits (`constraints.box_qp`, only where the unconstrained step leaves it), the feedback
acts on the free torques only (the clamped ones' rows are zero), and the forward pass keeps the policy's torques
in the box; the state limits' exact penalty enters the cost, its gradient and its curvature at every node where a
predicted state crosses its bound (`StateBounds.penalty_derivatives`: its kink is left to the line search). With
no bound active the iteration is the unconstrained one, bit for bit. With constraints off the backward pass is
unconstrained and the forward pass's clipping alone keeps the box (the clamped iLQR before constraints). The default optimizer is the
real-time iteration (`rti`), which needs no sequential rollout; the iLQR serves long horizons and line-searched
iterations. Its settings: `Ilqr`, in the MPC settings
`optimizer: !Ilqr {max_iterations: 1, line_search: [1.0, 0.5, 0.25, 0.1], regularization: 1.0e-6}`.
Shapes for n joints, m actuated, horizon H as in `optimizer`."""
import dataclasses

import numpy as np
from scipy.linalg.lapack import dpotrf as cholesky, dpotrs as cholesky_solve

from stdm_drake.closed_loop.constraints import StateBounds, box_qp, limits_status
from stdm_drake.closed_loop.optimizer import (LINEARIZATION_STEPS, OptimizerResult, OptimizerSettings, TrackingCost,
                                              TrajectoryOptimizer)
from stdm_drake.errors import InputError


MAX_ITERATIONS = 100   # iLQR iterations per control step: more is a run that does not end
MAX_LINE_SEARCH = 30   # line-search steps (each a rollout of the horizon): more is a control step that does not end


@dataclasses.dataclass
class Ilqr(OptimizerSettings):
    """The iLQR's settings (YAML `optimizer: !Ilqr {...}`): iterations per solve (at most: it stops when a
    line search finds no lower cost), line-search step sizes, the initial Levenberg-Marquardt regularization
    of Q_uu."""
    max_iterations: int = 1
    line_search: list[float] = dataclasses.field(default_factory=lambda: [1.0, 0.5, 0.25, 0.1])
    regularization: float = 1e-6

    def validate(self) -> None:
        """InputError for settings that would switch the optimizer off, make it diverge or never end: iterations in
        1..MAX_ITERATIONS, at most MAX_LINE_SEARCH line-search steps, each in (0, 1] (a step of 0 never moves, a
        negative one climbs the cost), a finite non-negative regularization."""
        if not 1 <= self.max_iterations <= MAX_ITERATIONS or not self.line_search:
            raise InputError(f"mpc optimizer !Ilqr max_iterations must be in 1..{MAX_ITERATIONS} and line_search "
                             f"non-empty, got {self.max_iterations} and {self.line_search}")
        if len(self.line_search) > MAX_LINE_SEARCH:
            raise InputError(f"mpc optimizer !Ilqr line_search lists {len(self.line_search)} steps, at most "
                             f"{MAX_LINE_SEARCH} (each is a rollout of the horizon in every iteration)")
        steps = np.asarray(self.line_search, dtype=float)
        if not np.all(np.isfinite(steps) & (steps >= 1e-6) & (steps <= 1)):   # (a step of 1e-320 moves nothing)
            raise InputError(f"mpc optimizer !Ilqr line_search steps must be in [1e-06, 1], got {self.line_search}")
        if not (np.isfinite(self.regularization) and 0 <= self.regularization <= 1e6):
            raise InputError(f"mpc optimizer !Ilqr regularization must be in [0, 1e6], got {self.regularization}")

    def work_per_step(self, horizon: int) -> int:
        """Each iteration linearizes every node and rolls the horizon out once per line-search step."""
        return int(self.max_iterations) * int(horizon) * (LINEARIZATION_STEPS + len(self.line_search))

    def solver(self, model, cost: TrackingCost, effort_limit: np.ndarray, horizon: int,
               bounds: StateBounds | None = None) -> "IlqrSolver":
        """An IlqrSolver (any horizon: its Riccati recursion is linear in it)."""
        return IlqrSolver(model, cost, effort_limit, self, bounds)


class IlqrSolver(TrajectoryOptimizer):
    """Box-constrained iLQR over a horizon for one prediction model and one cost (module docstring)."""

    def __init__(self, model, cost: TrackingCost, effort_limit: np.ndarray, config: Ilqr | None = None,
                 bounds: StateBounds | None = None):
        super().__init__(model, cost, effort_limit, bounds)
        self.config = config or Ilqr()
        self.config.validate()
        self.Q, self.R = cost.Q, cost.R

    def solve(self, x0: np.ndarray, u_init: np.ndarray, reference: np.ndarray, u_ff: np.ndarray,
              offset: np.ndarray | None = None, x_init: np.ndarray | None = None) -> OptimizerResult:
        """x0 (2n,); u_init (H, m) warm start; reference (H+1, 2n); u_ff (H, m); offset (2n,): a
        constant added to every predicted step (the disturbance estimate; zero by default). x_init is
        ignored: the iLQR shoots from x0 (a rollout of u_init)."""
        horizon = len(u_init)
        offset = np.zeros(self.state_dim) if offset is None else np.asarray(offset, dtype=float)
        u = np.clip(u_init, -self.effort_limit, self.effort_limit)
        x = self.rollout(x0, u, offset)
        cost = self.cost(x, u, reference, u_ff)
        if not (np.all(np.isfinite(x)) and np.isfinite(cost)):
            return OptimizerResult(u, x, cost, 0, False)
        mu = self.config.regularization
        iterations = 0
        terminal = self.cost_function.step_weights(horizon)
        for iterations in range(1, self.config.max_iterations + 1):
            _, A, B = self.linearize(x[:-1], u)     # every node's Jacobians in one batched call
            if not (np.all(np.isfinite(A)) and np.all(np.isfinite(B))):
                return OptimizerResult(u, x, cost, iterations, False)
            gains = self._backward(x, u, reference, u_ff, A, B, terminal, mu)
            if gains is None:
                mu *= 10.0
                continue
            feedforward, feedback = gains
            improved = False
            for alpha in self.config.line_search:
                x_new = np.empty_like(x)
                u_new = np.empty_like(u)
                x_new[0] = x0
                for k in range(horizon):
                    u_new[k] = np.clip(u[k] + alpha * feedforward[k] + feedback[k] @ (x_new[k] - x[k]),
                                       -self.effort_limit, self.effort_limit)
                    x_new[k + 1] = self.predict(x_new[k], u_new[k], offset)
                new_cost = self.cost(x_new, u_new, reference, u_ff)
                if np.isfinite(new_cost) and new_cost < cost:
                    x, u, cost, improved = x_new, u_new, new_cost, True
                    break
            if not improved:
                break
            mu = max(mu / 10.0, 1e-12)
        active, slack = (False, 0.0) if self.bounds is None else limits_status(self.bounds, x[1:], u, self.effort_limit)
        return OptimizerResult(u, x, cost, iterations, bool(np.all(np.isfinite(x))), active, slack)

    def _backward(self, x, u, reference, u_ff, A, B, terminal, mu):
        """Riccati recursion; returns (feedforward (H, m), feedback (H, m, 2n)) or None if Q_uu is not PD.

        Per node one product F^T V_xx F of the stacked Jacobian F = [A_k B_k] gives Q_xx, Q_ux and Q_uu at
        once, and one solve gives both gains (a handful of small numpy calls per node)."""
        horizon, S, m = len(u), self.state_dim, self.joints
        feedforward = np.empty((horizon, m))
        feedback = np.empty((horizon, m, S))
        # gradients of the running costs, all steps at once (the state limits' penalty: halved, as the
        # tracking terms' are: the recursion's gradients and curvatures are those of half the cost)
        state_gradient = terminal[:, None] * ((x[1:] - reference[1:]) @ self.Q)
        effort_gradient = (u - u_ff) @ self.R
        penalty_curvature = None
        if self.bounds is not None:
            penalty_gradient, penalty_curvature = self.bounds.penalty_derivatives(x[1:])
            state_gradient = state_gradient + 0.5 * penalty_gradient
            penalty_curvature = 0.5 * penalty_curvature
        stacked = np.concatenate([A, B], axis=2)                      # F_k = [A_k B_k] (H, 2n, 2n + m)
        R_regularized = self.R + mu * np.eye(m)
        V_x = np.zeros(S)
        V_xx = np.zeros((S, S))
        for k in range(horizon - 1, -1, -1):
            # step k's cost: state x_k+1 (weighted by terminal[k]) and torque u_k
            V_x = V_x + state_gradient[k]
            V_xx = V_xx + terminal[k] * self.Q
            if penalty_curvature is not None and penalty_curvature[k].any():
                V_xx = V_xx + np.diag(penalty_curvature[k])
            F = stacked[k]
            Q = F.T @ (V_xx @ F)                                        # [[Q_xx, Q_xu], [Q_ux, Q_uu]] less R
            gradient = F.T @ V_x                                        # [Q_x, Q_u] less the effort gradient
            Q_uu = Q[S:, S:] + R_regularized
            Q_u = gradient[S:] + effort_gradient[k]
            Q_ux = Q[S:, :S]
            if not np.all(np.isfinite(Q_uu)):   # a diverged linearization
                return None
            factor, info = cholesky(Q_uu, lower=1)      # LAPACK directly: microseconds, not numpy's checks
            if info != 0:                               # Q_uu not positive definite
                return None
            gains, _ = cholesky_solve(factor, np.column_stack([Q_u, Q_ux]), lower=1)
            d, K = -gains[:, 0], -gains[:, 1:]
            if self.bounds is not None:
                lower, upper = -self.effort_limit - u[k], self.effort_limit - u[k]
                if np.any(d < lower) or np.any(d > upper):     # box-DDP: the step within the box, feedback on free torques
                    try:
                        d, clamped = box_qp(Q_uu, Q_u, lower, upper)
                    except ArithmeticError:
                        return None
                    K = np.zeros_like(K)
                    free = ~clamped
                    if free.any():
                        K[free] = -np.linalg.solve(Q_uu[np.ix_(free, free)], Q_ux[free])
            feedforward[k], feedback[k] = d, K
            # with regularization the cross terms do not cancel; keep the full expressions
            K_T = K.T
            V_x = gradient[:S] + K_T @ (Q_uu @ d + Q_u) + Q_ux.T @ d
            V_xx = Q[:S, :S] + K_T @ (Q_uu @ K + Q_ux) + Q_ux.T @ K
            V_xx = 0.5 * (V_xx + V_xx.T)
        return feedforward, feedback
