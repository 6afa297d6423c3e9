"""Models that need no learning: the physics baselines every learned number stands beside, the robot's
own rigid-body plant as a model, and the nominal model's acceleration that physics-structured networks
take as an input.

    ConstantVelocity   q̂ = q + Δt v, v̂ = v: the one-line Euler step for q and "v unchanged" for v
    StaysPut           q̂ = q, v̂ = 0: open loop, "the robot stays at q₀"
    PlantModel         the robot's plant stepping the held torque over the period: "rk4", its continuous
                       rigid-body dynamics in RK4 steps with exact Jacobians (the model for control), or
                       "simulator", the discrete Drake plant the simulation itself steps (exact where the
                       data are simulated from the same description: the evaluation baseline)
    NominalAcceleration  q̈ = M(q)⁻¹(B τ + τ_g(q) − C(q, v) v − D v) of the robot's description, with its
                       time derivative along a tangent and its Jacobian (`robots.rigid_body`, analytic)

A learned model that does not beat ConstantVelocity by `verdict.LEARNED_FACTOR` in both one-step q and v has
not learned the dynamics (`verdict.learning_verdict`).
"""
from __future__ import annotations

import abc

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.dynamics.model import DynamicsModel

class _Kinematic(DynamicsModel):
    """Baselines that only integrate the current state (no action)."""

    def __init__(self, state_dim: int, action_dim: int, sample_period: float):
        if state_dim % 2 or state_dim < 2:
            raise InputError(f"a physics baseline needs a state [q, v] of even size, got {state_dim}")
        if sample_period is None or not (np.isfinite(sample_period) and sample_period > 0):
            raise InputError(f"sample period must be a positive number of seconds, got {sample_period}")
        self.state_dim, self.action_dim, self.sample_period = state_dim, action_dim, float(sample_period)

    @abc.abstractmethod
    def _linear(self) -> np.ndarray:
        """The model's step as a matrix: x_{t+1} = L x_t, (S, S)."""

    def step(self, x, a):
        return np.asarray(x, dtype=np.float64) @ self._linear().T

    def jacobians(self, x, a):
        horizon = len(x)
        return (np.broadcast_to(self._linear(), (horizon, self.state_dim, self.state_dim)).copy(),
                np.zeros((horizon, self.state_dim, self.action_dim)))


class ConstantVelocity(_Kinematic):
    """q̂_{t+1} = q_t + Δt v_t, v̂_{t+1} = v_t: the Euler step for q and "v unchanged" for v."""
    name = "Euler step"

    def _linear(self):
        n = self.num_joints
        matrix = np.eye(self.state_dim)
        matrix[:n, n:] = self.sample_period * np.eye(n)
        return matrix


class StaysPut(_Kinematic):
    """q̂_{t+1} = q_t, v̂_{t+1} = 0: open loop, the robot stays where it started."""
    name = "stays put"

    def _linear(self):
        n = self.num_joints
        matrix = np.zeros((self.state_dim, self.state_dim))
        matrix[:n, :n] = np.eye(n)
        return matrix


INTEGRATORS = ("rk4", "simulator")


class PlantModel(DynamicsModel):
    """The plant of `robot` as a model at the sample period, the torque held over the period.

    integrator="rk4": the continuous rigid-body dynamics ẋ = [v, q̈(q, v, τ)] (`robots.rigid_body`:
    Pinocchio's ABA built from the Drake plant, damping and Coulomb friction added), classical
    Runge-Kutta steps over the period (`substeps` of them: one on an undamped arm, more where joint
    damping or Coulomb friction is faster than the period), with exact Jacobians: the RK4 stages'
    analytic derivatives chained through the integrator, equal to central differences of this step
    to rounding. The model for control (the MPC's reference): microseconds per step. Its one-step
    difference from the simulator's discrete plant is what `evaluate` prints beside it.

    integrator="simulator": the same discrete Drake plant as the simulation (plant step h, `period / h`
    substeps, joint limits and contact), so where the data come from this description its one-step
    predictions are exact: the evaluation baseline. Its Jacobians are central differences of its own
    step (2 (2n + m) plant steps per row: exact, slow; control uses "rk4").

    With `plant_config.effects` it is the affected plant's (the true plant of data collected with those
    effects, an oracle no user has; named "true-plant"), else the robot's description (the nominal model
    a user has; named "plant"); an identified robot's model is the description with the identified
    parameters as effects (`identification.identified`).
    """
    name = "plant"
    checkpoint = None     # source: an identified robot's `IdentifiedRobot` (the file, its dataset and split)

    def __init__(self, sample_period: float, plant_config=None, *, robot, name: str | None = None, source=None,
                 integrator: str = "simulator"):
        if integrator not in INTEGRATORS:
            raise InputError(f"plant model integrator must be one of {INTEGRATORS}, got {integrator!r}")
        if sample_period is None or not (np.isfinite(sample_period) and sample_period > 0):
            raise InputError(f"sample period must be a positive number of seconds, got {sample_period}")
        self.robot, self.integrator = robot, integrator
        self.state_dim, self.action_dim = self.robot.state_dim, self.robot.action_dim
        self.sample_period = float(sample_period)
        self.effects = plant_config.effects if plant_config is not None else None
        if self.effects is not None:
            self.name = "true-plant"
        if name is not None:
            self.name = name
        if source is not None:   # an identified robot: fitted to data, rated against the physics-free baselines
            self.checkpoint, self.learned = source, True
        self._plant_config = plant_config
        lagging = self.effects.acting_later() if self.effects is not None else []
        if lagging and integrator == "simulator":   # (the rk4 plant refuses every effect it does not hold)
            raise InputError(f"a one-step plant model cannot hold the affected plant's {', '.join(lagging)}: the "
                             "torque acting depends on earlier commands, not on (x, u); use the description's plant")
        if integrator == "simulator":
            from stdm_drake.robots.plant import PlantSimulator   # lazy: pydrake
            self.simulation = PlantSimulator(plant_config, robot=self.robot)
        else:
            from stdm_drake.robots.rigid_body import robot_dynamics   # lazy: pydrake
            self.dynamics = robot_dynamics(robot, self.effects)
            self.substeps = rk4_substeps(self.dynamics, robot.home, self.sample_period)

    def describe(self) -> str:
        """An identified robot's line (its `describe`), else the plant's."""
        if self.checkpoint is not None:
            return self.checkpoint.describe(self.name)
        return f"model {self.name}: the robot's rigid-body plant ({self.integrator})"

    def for_control(self) -> "PlantModel":
        """The same plant (robot, effects, name, source) with the "rk4" integrator: what an MPC predicts with."""
        if self.integrator == "rk4":
            return self
        return PlantModel(self.sample_period, self._plant_config, robot=self.robot, name=self.name,
                          source=self.checkpoint, integrator="rk4")

    def step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        x, u = np.atleast_2d(np.asarray(x, dtype=float)), np.atleast_2d(np.asarray(u, dtype=float))
        if self.integrator == "rk4":
            return self._rk4(x, u, derivatives=False)[0]
        out = np.empty_like(x)
        for i in range(len(x)):
            self.simulation.start(x[i], u[i])
            out[i] = self.simulation.advance_to(self.sample_period)
        return out

    def step_single(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return self._rk4_row(x, u) if self.integrator == "rk4" else super().step_single(x, u)

    def linearize(self, x: np.ndarray, u: np.ndarray):
        x, u = np.atleast_2d(np.asarray(x, dtype=float)), np.atleast_2d(np.asarray(u, dtype=float))
        if self.integrator == "rk4":
            following, jacobian = self._rk4(x, u, derivatives=True)
            return following, jacobian[:, :, :self.state_dim], jacobian[:, :, self.state_dim:]
        return super().linearize(x, u)

    def jacobians(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x, u = np.atleast_2d(np.asarray(x, dtype=float)), np.atleast_2d(np.asarray(u, dtype=float))
        if self.integrator == "rk4":
            return self.linearize(x, u)[1:]
        return central_difference_jacobians(self.step, x, u)

    def _rk4_row(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """`_rk4` of one row x (S,), u (A,) on 1-D arrays (the MPC's sequential rollouts)."""
        n, h = self.num_joints, self.sample_period / self.substeps
        acceleration = self.dynamics.acceleration_row
        q, v = x[:n], x[n:]
        for _ in range(self.substeps):
            a1 = acceleration(q, v, u)
            v2 = v + 0.5 * h * a1
            a2 = acceleration(q + 0.5 * h * v, v2, u)
            v3 = v + 0.5 * h * a2
            a3 = acceleration(q + 0.5 * h * v2, v3, u)
            v4 = v + h * a3
            a4 = acceleration(q + h * v3, v4, u)
            q = q + h / 6.0 * (v + 2.0 * v2 + 2.0 * v3 + v4)
            v = v + h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        return np.concatenate([q, v])

    def _rk4(self, x: np.ndarray, u: np.ndarray, *, derivatives: bool):
        """(x_next (N, S), d x_next / d(x, u) (N, S, S + A) or None): `substeps` RK4 steps of the continuous
        dynamics, the stages' Jacobians chained through the integrator."""
        n, S, A = self.num_joints, self.state_dim, self.action_dim
        h = self.sample_period / self.substeps
        dynamics = self.dynamics
        if derivatives:
            total = np.zeros((len(x), S, S + A))
            total[:, :, :S] = np.eye(S)
            lift = np.zeros((S + A, S + A))     # d u / d(x0, u): the held action
            lift[S:, S:] = np.eye(A)

        def slope(state, chain):
            """ẋ (N, S) at `state` and, with derivatives, d ẋ / d(x0, u) through d state / d(x0, u) = chain."""
            if not derivatives:
                rate = np.empty_like(state)
                rate[:, :n] = state[:, n:]
                rate[:, n:] = dynamics.acceleration(state[:, :n], state[:, n:], u)
                return rate, None
            acceleration, jacobian = dynamics.acceleration_and_jacobians(state[:, :n], state[:, n:], u)
            d_slope = np.empty_like(chain)
            d_slope[:, :n] = chain[:, n:]
            d_slope[:, n:] = jacobian[:, :, :S] @ chain + jacobian[:, :, S:] @ lift[S:]
            return np.hstack([state[:, n:], acceleration]), d_slope

        for _ in range(self.substeps):
            k1, d1 = slope(x, total if derivatives else None)
            k2, d2 = slope(x + 0.5 * h * k1, total + 0.5 * h * d1 if derivatives else None)
            k3, d3 = slope(x + 0.5 * h * k2, total + 0.5 * h * d2 if derivatives else None)
            k4, d4 = slope(x + h * k3, total + h * d3 if derivatives else None)
            x = x + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            if derivatives:
                total = total + h / 6.0 * (d1 + 2.0 * d2 + 2.0 * d3 + d4)
        return x, (total if derivatives else None)


def rk4_substeps(dynamics, q_home: np.ndarray, period: float) -> int:
    """RK4 steps per sample period for a model whose fastest joint decays at rate λ = max_i (d_i +
    F_c,i / v_s,i) (M⁻¹(home))_ii 1/s (viscous damping and the Coulomb friction's slope at rest): steps
    of h <= 1 / λ, well inside RK4's real-axis stability limit (2.78 / λ) and accurate there; one step
    on an arm without damping or friction."""
    inverse_inertia = np.diag(dynamics.inverse_mass_matrix(q_home))
    rate = dynamics.damping.copy()
    if dynamics.coulomb is not None:
        friction, scale = dynamics.coulomb
        rate = rate + friction / scale
    fastest = float(np.max(rate * np.abs(inverse_inertia)))
    return max(1, int(np.ceil(period * fastest)))


def central_difference_jacobians(step, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(d step / d x (N, out, S), d step / d u (N, out, A)) by central differences of step(x (N, S), u (N, A))
    -> (N, out), a step of 1e-6 of each coordinate's scale (max(|value|, 1)): the simulator's own Jacobians,
    and the reference the analytic ones are tested against."""
    S, A = x.shape[1], u.shape[1]
    point = np.hstack([x, u])
    epsilon = 1e-6 * np.maximum(np.abs(point), 1.0)                      # (N, S + A)
    rows = []
    for k in range(S + A):
        for sign in (1.0, -1.0):
            moved = point.copy()
            moved[:, k] += sign * epsilon[:, k]
            rows.append(moved)
    moved = np.concatenate(rows)                                          # (2 (S + A) N, S + A)
    values = step(moved[:, :S], moved[:, S:]).reshape(S + A, 2, len(x), -1)
    jacobian = ((values[:, 0] - values[:, 1]) / (2.0 * epsilon.T[:, :, None])).transpose(1, 2, 0)   # (N, out, S + A)
    return jacobian[:, :, :S], jacobian[:, :, S:]


def zero_order_hold_discretization(A_c: np.ndarray, B_c: np.ndarray, period: float):
    """(A_d, B_d) = (exp(A_c T), int_0^T exp(A_c s) ds B_c), exact to rounding for any stiffness; A_c (S, S)
    and B_c (S, K), or batches (N, S, S) and (N, S, K) (or B_c (S, K) for all rows).

    Scaling and squaring: with T' = T / 2^k so that |A_c T'|_1 <= 1/4 (k: the largest any row needs), the
    series of exp(A_c T') and of Phi(T') = int_0^T' exp(A_c s) ds to 8th order (truncation below 1e-11),
    then k doublings exp(2 A_c T') = exp(A_c T')^2 and Phi(2T') = (I + exp(A_c T')) Phi(T'). Stiff joints
    (damping of a light wrist: time constants below 1 ms against a 10 ms period) need the doublings; a
    plain truncated series there gives eigenvalues in the hundreds. B_c is applied once at the end, so its
    large wrist columns (1/inertia ~ 3000) cost nothing (scipy's expm of the augmented matrix would square
    for them).
    """
    single = np.ndim(A_c) == 2
    scaled = np.asarray(A_c, dtype=float)[None] * period if single else np.asarray(A_c, dtype=float) * period
    n = scaled.shape[-1]
    norm = np.abs(scaled).sum(axis=1).max() if scaled.size else 0.0
    if not np.isfinite(norm):      # a diverged linearization point: NaN matrices, which the MPC falls back on
        exponential, integral = np.full_like(scaled, np.nan), np.full_like(scaled, np.nan)
    else:
        doublings = int(np.ceil(np.log2(norm / 0.25))) if norm > 0.25 else 0
        scaled = scaled / 2.0 ** doublings
        term = np.broadcast_to(np.eye(n), scaled.shape).copy()
        exponential = term.copy()    # sum X^k / k!
        integral = term.copy()       # sum X^k / (k+1)!, Phi(T') / T'
        for k in range(1, 9):
            term = term @ scaled / k
            exponential += term
            integral += term / (k + 1)
        for _ in range(doublings):
            integral = (np.eye(n) + exponential) @ integral / 2
            exponential = exponential @ exponential
    applied = period * integral @ B_c
    return (exponential[0], applied[0]) if single else (exponential, applied)


class NominalAcceleration:
    """The joint accelerations (n,) rad/s² the robot's nominal rigid-body model (its description file,
    continuous time) gives for q (n,) rad, v (n,) rad/s and the action τ (m,) N m:
    q̈ = M(q)⁻¹(B τ + τ_g(q) − C(q, v) v − D v), from `robots.rigid_body.RigidBodyDynamics` (Pinocchio's ABA
    and its analytic derivatives, built from the Drake plant; equal to Drake's forward dynamics to rounding).

    values(q, v, tau) (N, n); rates(...) the time derivative along a tangent (q̇, q̈, τ̇) (N, n), the
    analytic Jacobian applied to the tangent; jacobians(q, v, tau) d q̈ / d(q, v, τ) (N, n, 2n + m).
    """

    def __init__(self, robot):
        from stdm_drake.robots.rigid_body import robot_dynamics   # lazy: pydrake
        self.robot = robot
        self.num_joints, self.action_dim = self.robot.num_joints, self.robot.action_dim
        self.width = self.num_joints      # values per row
        self.dynamics = robot_dynamics(robot)

    def _rows(self, q, v, tau):
        q, v, tau = (np.atleast_2d(np.asarray(values, dtype=np.float64)) for values in (q, v, tau))
        n = self.num_joints
        if q.shape[1] != n or v.shape != q.shape or tau.shape != (len(q), self.action_dim):
            raise InputError(f"nominal acceleration needs q, v (N, {n}) and tau (N, {self.action_dim}), got "
                             f"{q.shape}, {v.shape}, {tau.shape}")
        return q, v, tau

    def values(self, q, v, tau) -> np.ndarray:
        return self.dynamics.acceleration(*self._rows(q, v, tau))

    def value_row(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """`values` of one row q, v (n,), τ (m,) float64, unchecked (sequential rollouts)."""
        return self.dynamics.acceleration_row(q, v, tau)

    def rates(self, q, v, tau, q_rate, v_rate, tau_rate) -> np.ndarray:
        """d q̈ / dt = ∂q̈/∂q q̇ + ∂q̈/∂v v̇ + ∂q̈/∂τ τ̇ (N, n) along the tangent rows (q̇, v̇, τ̇)."""
        tangent = np.hstack([np.atleast_2d(q_rate), np.atleast_2d(v_rate), np.atleast_2d(tau_rate)])
        return np.einsum("nij,nj->ni", self.jacobians(q, v, tau), tangent)

    def values_and_jacobians(self, q, v, tau) -> tuple[np.ndarray, np.ndarray]:
        """(q̈ (N, n), d q̈ / d(q, v, τ) (N, n, 2n + m)), analytic."""
        return self.dynamics.acceleration_and_jacobians(*self._rows(q, v, tau))

    def jacobians(self, q, v, tau) -> np.ndarray:
        """d q̈ / d(q, v, τ) (N, n, 2n + m)."""
        return self.values_and_jacobians(q, v, tau)[1]


class PeriodAcceleration(NominalAcceleration):
    """The mean acceleration (n,) rad/s² of the robot's nominal model over one sample period T from
    (q, v) under the held action τ, linearized there: φ̄ = [Ψ f]_v / T with f = [v, q̈(q, v, τ)] and
    Ψ = ∫_0^T exp(A_c s) ds (A_c = ∂f/∂x; `zero_order_hold_discretization`), so that v + T φ̄ is the
    linearized nominal model's next velocity. Where T is short against the dynamics this is q̈ plus
    O(T) terms; on a joint whose damping decays faster than T (a light wrist with its URDF's
    <dynamics damping>: time constants near 1 ms against 10 ms) q̈ itself is -v / (1 ms) large and says
    little about the next velocity, while φ̄ stays what the period does.

    Same interface as NominalAcceleration: values (all rows' Ψ in one batched series); rates along a
    tangent and values_and_jacobians by central differences of the values (ε = 1e-6 of the row's
    scale: Ψ depends on the state through A_c, whose derivative needs the dynamics' second derivatives;
    exact to ~1e-8 relative, 2 (2n + m) evaluations per row)."""

    def __init__(self, robot, sample_period: float):
        super().__init__(robot)
        if sample_period is None or not (np.isfinite(sample_period) and sample_period > 0):
            raise InputError(f"period acceleration needs a sample period > 0 s, got {sample_period}")
        self.sample_period = float(sample_period)

    def values(self, q, v, tau) -> np.ndarray:
        q, v, tau = self._rows(q, v, tau)
        n, T = self.num_joints, self.sample_period
        accelerations, jacobians = self.dynamics.acceleration_and_jacobians(q, v, tau)
        A_c = np.zeros((len(q), 2 * n, 2 * n))
        A_c[:, :n, n:] = np.eye(n)
        A_c[:, n:] = jacobians[:, :, :2 * n]
        _, integral = zero_order_hold_discretization(A_c, np.eye(2 * n), T)            # Ψ (N, 2n, 2n)
        return np.einsum("nij,nj->ni", integral[:, n:], np.hstack([v, accelerations])) / T

    def value_row(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        return self.values(q[None], v[None], tau[None])[0]

    def values_and_jacobians(self, q, v, tau) -> tuple[np.ndarray, np.ndarray]:
        q, v, tau = self._rows(q, v, tau)
        n = self.num_joints
        step = lambda position, velocity: self.values(position[:, :n], position[:, n:], velocity)   # noqa: E731
        state_part, action_part = central_difference_jacobians(step, np.hstack([q, v]), tau)
        return self.values(q, v, tau), np.concatenate([state_part, action_part], axis=2)

    def rates(self, q, v, tau, q_rate, v_rate, tau_rate) -> np.ndarray:
        """d φ̄ / dt (N, n) along the tangent rows (q̇, v̇, τ̇): central differences of `values`."""
        return central_difference_rates(self.values, self.num_joints, q, v, tau, q_rate, v_rate, tau_rate)


def central_difference_rates(values, joints: int, q, v, tau, q_rate, v_rate, tau_rate) -> np.ndarray:
    """d values(q, v, τ) / dt (N, width) along the tangent rows (q̇, v̇, τ̇) by central differences: a step of
    1e-6 of each row's scale along its tangent (exact to ~1e-9 relative for smooth values); a zero tangent
    has a zero rate. values: a function of q, v (N, n) and τ (N, m)."""
    q, v, tau = (np.atleast_2d(np.asarray(array, dtype=np.float64)) for array in (q, v, tau))
    n = joints
    point = np.hstack([q, v, tau])
    tangent = np.hstack([np.atleast_2d(q_rate), np.atleast_2d(v_rate), np.atleast_2d(tau_rate)])
    size = np.abs(tangent).max(axis=1)
    moving = size > 0
    step = np.zeros((len(point), 1))
    step[moving, 0] = 1e-6 * np.maximum(np.abs(point[moving]).max(axis=1), 1.0) / size[moving]
    ahead, behind = point + step * tangent, point - step * tangent
    forward = values(ahead[:, :n], ahead[:, n:2 * n], ahead[:, 2 * n:])
    backward = values(behind[:, :n], behind[:, n:2 * n], behind[:, 2 * n:])
    rates = np.zeros_like(forward)
    rates[moving] = (forward[moving] - backward[moving]) / (2.0 * step[moving])
    return rates

