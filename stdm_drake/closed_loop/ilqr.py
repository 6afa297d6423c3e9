"""Clamped iLQR (iterative LQR) over a horizon for one prediction model and one tracking cost; see
`stdm_drake.closed_loop.mpc` for the cost and the prediction-model interface."""
from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from stdm_drake.config import check_joint_vector

if TYPE_CHECKING:
    from stdm_drake.closed_loop.mpc import MpcConfig



@dataclasses.dataclass
class IlqrResult:
    """u: (H, 6) optimized torques; x: (H+1, 12) predicted states; cost; iterations; finite."""
    u: np.ndarray
    x: np.ndarray
    cost: float
    iterations: int
    finite: bool


class IlqrSolver:
    """Clamped iLQR over a horizon for one prediction model and one cost."""

    def __init__(self, model, config: MpcConfig, effort_limit: np.ndarray):
        config.validate()
        self.model = model
        self.config = config
        self.effort_limit = np.asarray(effort_limit, dtype=float)
        self.joints = joints = len(self.effort_limit)
        self.state_dim = 2 * joints
        weight = {name: check_joint_vector(f"mpc {name}", getattr(config, name), count=joints, nonnegative=True)
                  for name in ("position_weight", "velocity_weight", "effort_weight")}
        self.Q = np.diag(np.concatenate([weight["position_weight"], weight["velocity_weight"]]))
        self.R = np.diag(weight["effort_weight"])

    def rollout(self, x0: np.ndarray, u: np.ndarray, offset: np.ndarray | None = None) -> np.ndarray:
        """Predicted states (H+1, 12) from x0 under u (H, 6), each step shifted by `offset` (12,)."""
        offset = np.zeros(self.state_dim) if offset is None else offset
        x = np.empty((len(u) + 1, self.state_dim))
        x[0] = x0
        for k in range(len(u)):
            x[k + 1] = self._predict(x[k], u[k], offset)
        return x

    def _predict(self, x: np.ndarray, u: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """One shifted model step: f(x (12,), u (6,)) + offset (12,)."""
        return self.model.step(x[None], u[None])[0] + offset

    def cost(self, x: np.ndarray, u: np.ndarray, reference: np.ndarray, u_ff: np.ndarray) -> float:
        error = x[1:] - reference[1:]
        weights = np.ones(len(u))
        weights[-1] = self.config.terminal_factor
        state = np.einsum("ki,ij,kj->k", error, self.Q, error) @ weights
        effort = np.einsum("ki,ij,kj->", u - u_ff, self.R, u - u_ff)
        return float(state + effort)

    def solve(self, x0: np.ndarray, u_init: np.ndarray, reference: np.ndarray, u_ff: np.ndarray,
              offset: np.ndarray | None = None) -> IlqrResult:
        """x0 (12,); u_init (H, 6) warm start; reference (H+1, 12); u_ff (H, 6); offset (12,): a
        constant added to every predicted step (the disturbance estimate; zero by default)."""
        horizon = len(u_init)
        offset = np.zeros(self.state_dim) if offset is None else np.asarray(offset, dtype=float)
        u = np.clip(u_init, -self.effort_limit, self.effort_limit)
        x = self.rollout(x0, u, offset)
        cost = self.cost(x, u, reference, u_ff)
        if not (np.all(np.isfinite(x)) and np.isfinite(cost)):
            return IlqrResult(u, x, cost, 0, False)
        mu = self.config.regularization
        iterations = 0
        terminal = np.ones(horizon)
        terminal[-1] = self.config.terminal_factor
        for iterations in range(1, self.config.max_iterations + 1):
            A, B = self.model.jacobians(x[:-1], u)
            if not (np.all(np.isfinite(A)) and np.all(np.isfinite(B))):
                return IlqrResult(u, x, cost, iterations, False)
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
                    x_new[k + 1] = self._predict(x_new[k], u_new[k], offset)
                new_cost = self.cost(x_new, u_new, reference, u_ff)
                if np.isfinite(new_cost) and new_cost < cost:
                    x, u, cost, improved = x_new, u_new, new_cost, True
                    break
            if not improved:
                break
            mu = max(mu / 10.0, 1e-12)
        return IlqrResult(u, x, cost, iterations, bool(np.all(np.isfinite(x))))

    def _backward(self, x, u, reference, u_ff, A, B, terminal, mu):
        """Riccati recursion; returns (feedforward (H, 6), feedback (H, 6, 12)) or None if Q_uu is not PD."""
        horizon = len(u)
        feedforward = np.empty((horizon, self.joints))
        feedback = np.empty((horizon, self.joints, self.state_dim))
        # gradients of the running costs, all steps at once
        state_gradient = terminal[:, None] * ((x[1:] - reference[1:]) @ self.Q)
        effort_gradient = (u - u_ff) @ self.R
        R_regularized = self.R + mu * np.eye(self.joints)
        V_x = np.zeros(self.state_dim)
        V_xx = np.zeros((self.state_dim, self.state_dim))
        for k in range(horizon - 1, -1, -1):
            # step k's cost: state x_k+1 (weighted by terminal[k]) and torque u_k
            V_x = V_x + state_gradient[k]
            V_xx = V_xx + terminal[k] * self.Q
            A_k, B_k = A[k], B[k]
            V_xx_A = V_xx @ A_k
            V_xx_B = V_xx @ B_k
            Q_uu = R_regularized + B_k.T @ V_xx_B
            Q_u = effort_gradient[k] + B_k.T @ V_x
            Q_ux = B_k.T @ V_xx_A
            if np.linalg.eigvalsh(Q_uu)[0] <= 0:
                return None
            gains = -np.linalg.solve(Q_uu, np.column_stack([Q_u, Q_ux]))
            d, K = gains[:, 0], gains[:, 1:]
            feedforward[k], feedback[k] = d, K
            # with regularization the cross terms do not cancel; keep the full expressions
            K_T_Q_uu = K.T @ Q_uu
            V_x = A_k.T @ V_x + K_T_Q_uu @ d + K.T @ Q_u + Q_ux.T @ d
            V_xx = A_k.T @ V_xx_A + K_T_Q_uu @ K + K.T @ Q_ux + Q_ux.T @ K
            V_xx = 0.5 * (V_xx + V_xx.T)
        return feedforward, feedback
