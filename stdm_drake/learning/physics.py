"""Models that need no learning: the physics baselines every learned number stands beside, the robot's
own rigid-body plant as a model, and the nominal model's acceleration that physics-structured networks
take as an input.

    ConstantVelocity   q̂ = q + Δt v, v̂ = v: the one-line Euler step for q and "v unchanged" for v
    StaysPut           q̂ = q, v̂ = 0: open loop, "the robot stays at q₀"
    PlantModel         the robot's discrete Drake plant stepping the held torque over the period (what
                       the simulation itself does, so exact where the data are simulated from the
                       same description: the nominal model a user has)
    RungeKuttaPlantModel  the same description's continuous rigid-body dynamics, one RK4 step over the
                       period (no contact, no joint limits, no plant substeps): the cheap nominal model,
                       the fair compute baseline for learned models in MPC
    NominalAcceleration  q̈ = M(q)⁻¹(B τ + τ_g(q) − C(q, v) v) of the robot's continuous plant, with its
                       time derivative along a tangent and its Jacobian (Drake AutoDiff)

A learned model that does not beat ConstantVelocity by `LEARNED_FACTOR` in both one-step q and v has
not learned the dynamics (`learning_verdict`).
"""
from __future__ import annotations

import abc

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.learning.dynamics_model import DynamicsModel

# A learned model must beat the physics-free baselines by this factor (one-step MSE) to count as
# having learned the dynamics; comparisons between models that do not are uninformative. Where the
# sensor's noise floor leaves no room for that factor, a model within FLOOR_FACTOR of the floor counts.
LEARNED_FACTOR = 2.0
FLOOR_FACTOR = 1.5


def learning_verdict(ratio_q: float, ratio_v: float, floor_ratio_q: float | None = None,
                     floor_ratio_v: float | None = None) -> str:
    """"learned" when, for q and for v, the one-step MSE ratio baseline/model (q: the Euler step; v: "v
    unchanged") is >= LEARNED_FACTOR or the model's MSE is within FLOOR_FACTOR of the sensor noise floor
    (floor_ratio = model MSE / floor; None: no floor known, an ideal sensor); else "has not learned the
    dynamics". "learned (at the noise floor)" when the floor decided it for q or v."""
    at_floor = [ratio is not None and ratio <= FLOOR_FACTOR for ratio in (floor_ratio_q, floor_ratio_v)]
    beats = [ratio_q >= LEARNED_FACTOR, ratio_v >= LEARNED_FACTOR]
    if all(b or f for b, f in zip(beats, at_floor)):
        return "learned" if all(beats) else "learned (at the noise floor)"
    return "has not learned the dynamics"


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


class PlantModel(DynamicsModel):
    """The plant of `robot` as a model at the sample period.

    step: the same discrete Drake plant as the simulation (plant step h, torque held for the whole
    period), so where the data come from this description its predictions are exact. jacobians:
    Drake AutoDiff linearization of the continuous dynamics at (x_k, u_k), discretized over the
    period (`zero_order_hold_discretization`). With `plant_config.effects` it is the affected plant's
    (the true plant of data collected with those effects, an oracle no user has; named "true-plant"),
    else the robot's description (the nominal model a user has; named "plant"); an identified robot's
    model is the description with the identified parameters as effects (`identification.identified`).
    """
    name = "plant"
    checkpoint = None     # source: an identified robot's `IdentifiedRobot` (the file, its dataset and split)

    def __init__(self, sample_period: float, plant_config=None, *, robot, name: str | None = None, source=None):
        from stdm_drake.robots.plant import PlantConfig, PlantSimulator, make_plant
        self.robot = robot
        self.state_dim, self.action_dim = self.robot.state_dim, self.robot.action_dim
        self.sample_period = float(sample_period)
        self.simulation = PlantSimulator(plant_config, robot=self.robot)
        self.effects = plant_config.effects if plant_config is not None else None
        if self.effects is not None:
            self.name = "true-plant"
        if name is not None:
            self.name = name
        if source is not None:   # an identified robot: fitted to data, rated against the physics-free baselines
            self.checkpoint, self.learned = source, True
        continuous_config = PlantConfig.discrete(0.0, effects=self.effects)
        continuous, _ = make_plant(continuous_config, robot=self.robot)
        self.autodiff_plant = continuous.ToAutoDiffXd()
        self.autodiff_context = self.autodiff_plant.CreateDefaultContext()
        if self.effects is not None:   # the effects' parameters, set on a double context and converted
            parameters = continuous.CreateDefaultContext()
            continuous_config.set_parameters(continuous, parameters)
            self.autodiff_context.SetTimeStateAndParametersFrom(parameters)
        self._coulomb = self.effects.coulomb(robot.num_joints) if self.effects is not None else None   # (F_c, v_s)

    def step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        x, u = np.atleast_2d(x), np.atleast_2d(u)
        out = np.empty_like(x, dtype=float)
        for i in range(len(x)):
            self.simulation.start(x[i], u[i])
            out[i] = self.simulation.advance_to(self.sample_period)
        return out

    def jacobians(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        from pydrake.autodiffutils import ExtractGradient, InitializeAutoDiff
        horizon, n = len(x), self.state_dim
        A = np.empty((horizon, n, n))
        B = np.empty((horizon, n, self.action_dim))
        for k in range(horizon):
            z = InitializeAutoDiff(np.concatenate([x[k], u[k]])).ravel()
            self.autodiff_plant.SetPositionsAndVelocities(self.autodiff_context, z[:n])
            self.autodiff_plant.get_actuation_input_port().FixValue(self.autodiff_context, z[n:])
            if self._coulomb is not None:   # -F_c tanh(v / v_s), differentiated with the state
                from stdm_drake.robots.effects import coulomb_torque
                force = coulomb_torque(z[n // 2:n], *self._coulomb)
                self.autodiff_plant.get_applied_generalized_force_input_port().FixValue(self.autodiff_context, force)
            derivatives = self.autodiff_plant.EvalTimeDerivatives(self.autodiff_context).CopyToVector()
            gradient = ExtractGradient(derivatives)
            A[k], B[k] = zero_order_hold_discretization(gradient[:, :n], gradient[:, n:], self.sample_period)
        return A, B


class RungeKuttaPlantModel(DynamicsModel):
    """The continuous dynamics ẋ = [v, q̈(q, v, τ)] of `robot`'s description (`NominalAcceleration`),
    one classical Runge-Kutta step over the sample period with the torque held: four evaluations of
    the rigid-body dynamics per step, against the discrete plant's `period / plant step` contact-aware
    substeps. jacobians: as `PlantModel`'s (the AutoDiff linearization at (x_k, u_k), zero-order-hold
    discretized), one AutoDiff evaluation per row."""
    name = "plant (RK4)"

    def __init__(self, sample_period: float, *, robot):
        self.acceleration = NominalAcceleration(robot)
        self.robot = self.acceleration.robot
        self.state_dim, self.action_dim = self.robot.state_dim, self.robot.action_dim
        self.sample_period = float(sample_period)

    def _derivative(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        n = self.num_joints
        return np.hstack([x[:, n:], self.acceleration.values(x[:, :n], x[:, n:], u)])

    def step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        x, u = np.atleast_2d(np.asarray(x, dtype=float)), np.atleast_2d(np.asarray(u, dtype=float))
        h = self.sample_period
        k1 = self._derivative(x, u)
        k2 = self._derivative(x + 0.5 * h * k1, u)
        k3 = self._derivative(x + 0.5 * h * k2, u)
        k4 = self._derivative(x + h * k3, u)
        return x + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

    def jacobians(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x, u = np.atleast_2d(np.asarray(x, dtype=float)), np.atleast_2d(np.asarray(u, dtype=float))
        n, S = self.num_joints, self.state_dim
        acceleration = self.acceleration.jacobians(x[:, :n], x[:, n:], u)        # (H, n, 2n + m)
        A, B = np.empty((len(x), S, S)), np.empty((len(x), S, self.action_dim))
        for k in range(len(x)):
            A[k], B[k] = zero_order_hold_discretization(*state_space_jacobians(acceleration[k]), self.sample_period)
        return A, B


def state_space_jacobians(acceleration_jacobian: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A_c (2n, 2n), B_c (2n, m)): the Jacobians of ẋ = [v, q̈(q, v, τ)] w.r.t. x = [q, v] and τ, from
    d q̈ / d(q, v, τ) (n, 2n + m)."""
    n = acceleration_jacobian.shape[0]
    A_c = np.zeros((2 * n, 2 * n))
    A_c[:n, n:] = np.eye(n)
    A_c[n:] = acceleration_jacobian[:, :2 * n]
    B_c = np.vstack([np.zeros((n, acceleration_jacobian.shape[1] - 2 * n)), acceleration_jacobian[:, 2 * n:]])
    return A_c, B_c


def zero_order_hold_discretization(A_c: np.ndarray, B_c: np.ndarray, period: float):
    """(A_d, B_d) = (exp(A_c T), int_0^T exp(A_c s) ds B_c), exact to rounding for any stiffness.

    Scaling and squaring: with T' = T / 2^k so that |A_c T'|_1 <= 1/4, the series of exp(A_c T') and of
    Phi(T') = int_0^T' exp(A_c s) ds to 8th order (truncation below 1e-11), then k doublings
    exp(2 A_c T') = exp(A_c T')^2 and Phi(2T') = (I + exp(A_c T')) Phi(T'). Stiff joints (damping of a
    light wrist: time constants below 1 ms against a 10 ms period) need the doublings; a plain truncated
    series there gives eigenvalues in the hundreds. B_c is applied once at the end, so its large wrist
    columns (1/inertia ~ 3000) cost nothing (scipy's expm of the augmented matrix would square for them).
    """
    n = len(A_c)
    scaled = A_c * period
    norm = np.abs(scaled).sum(axis=0).max()
    if not np.isfinite(norm):      # a diverged linearization point: NaN matrices, which the MPC falls back on
        return np.full_like(scaled, np.nan), np.full(B_c.shape, np.nan)
    doublings = int(np.ceil(np.log2(norm / 0.25))) if norm > 0.25 else 0
    scaled = scaled / 2.0 ** doublings
    term = np.eye(n)
    exponential = term.copy()    # sum X^k / k!
    integral = term.copy()       # sum X^k / (k+1)!, Phi(T') / T'
    for k in range(1, 9):
        term = term @ scaled / k
        exponential += term
        integral += term / (k + 1)
    for _ in range(doublings):
        integral = (np.eye(n) + exponential) @ integral / 2
        exponential = exponential @ exponential
    return exponential, period * integral @ B_c


class NominalAcceleration:
    """The joint accelerations (n,) rad/s² the robot's nominal rigid-body model (its description file,
    continuous time) gives for q (n,) rad, v (n,) rad/s and the action τ (m,) N m:
    q̈ = M(q)⁻¹(B τ + τ_g(q) − C(q, v) v), evaluated by Drake's plant (`EvalTimeDerivatives`).

    values(q, v, tau) (N, n); rates(...) the time derivative along a tangent (q̇, q̈, τ̇) (N, n), one
    forward-mode AutoDiff pass per row; jacobians(q, v, tau) d q̈ / d(q, v, τ) (N, n, 2n + m).
    """

    def __init__(self, robot):
        from stdm_drake.robots.plant import PlantConfig, make_plant
        self.robot = robot
        self.num_joints, self.action_dim = self.robot.num_joints, self.robot.action_dim
        self.width = self.num_joints      # values per row
        self.plant, _ = make_plant(PlantConfig.continuous(), robot=self.robot)
        self.context = self.plant.CreateDefaultContext()
        self.autodiff_plant = self.plant.ToAutoDiffXd()
        self.autodiff_context = self.autodiff_plant.CreateDefaultContext()

    def _rows(self, q, v, tau):
        q, v, tau = (np.atleast_2d(np.asarray(values, dtype=np.float64)) for values in (q, v, tau))
        n = self.num_joints
        if q.shape[1] != n or v.shape != q.shape or tau.shape != (len(q), self.action_dim):
            raise InputError(f"nominal acceleration needs q, v (N, {n}) and tau (N, {self.action_dim}), got "
                             f"{q.shape}, {v.shape}, {tau.shape}")
        return q, v, tau

    def values(self, q, v, tau) -> np.ndarray:
        q, v, tau = self._rows(q, v, tau)
        plant, context, n = self.plant, self.context, self.num_joints
        port = plant.get_actuation_input_port()
        out = np.empty_like(q)
        for i in range(len(q)):
            plant.SetPositionsAndVelocities(context, np.concatenate([q[i], v[i]]))
            port.FixValue(context, tau[i])
            out[i] = plant.EvalTimeDerivatives(context).CopyToVector()[n:]
        return out

    def _autodiff(self, q, v, tau, gradients):
        """(values (N, n), d values (N, n, K)) with the inputs' gradients (N, 2n + m, K)."""
        from pydrake.autodiffutils import ExtractGradient, ExtractValue, InitializeAutoDiff
        q, v, tau = self._rows(q, v, tau)
        plant, context, n = self.autodiff_plant, self.autodiff_context, self.num_joints
        port = plant.get_actuation_input_port()
        values = np.empty_like(q)
        derivatives = np.empty((len(q), n, gradients.shape[-1]))
        for i in range(len(q)):
            z = InitializeAutoDiff(np.concatenate([q[i], v[i], tau[i]]), gradients[i]).ravel()
            plant.SetPositionsAndVelocities(context, z[:2 * n])
            port.FixValue(context, z[2 * n:])
            result = plant.EvalTimeDerivatives(context).CopyToVector()[n:]
            values[i] = ExtractValue(result).ravel()
            derivatives[i] = ExtractGradient(result)
        return values, derivatives

    def rates(self, q, v, tau, q_rate, v_rate, tau_rate) -> np.ndarray:
        """d q̈ / dt = ∂q̈/∂q q̇ + ∂q̈/∂v v̇ + ∂q̈/∂τ τ̇ (N, n) along the tangent rows (q̇, v̇, τ̇)."""
        tangent = np.hstack([np.atleast_2d(q_rate), np.atleast_2d(v_rate), np.atleast_2d(tau_rate)])
        return self._autodiff(q, v, tau, tangent[:, :, None])[1][:, :, 0]

    def values_and_jacobians(self, q, v, tau) -> tuple[np.ndarray, np.ndarray]:
        """(q̈ (N, n), d q̈ / d(q, v, τ) (N, n, 2n + m)) from one AutoDiff pass per row."""
        count, width = len(np.atleast_2d(q)), 2 * self.num_joints + self.action_dim
        return self._autodiff(q, v, tau, np.broadcast_to(np.eye(width), (count, width, width)))

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

    Same interface as NominalAcceleration: values; rates along a tangent by central differences of
    the values (ε = 1e-6 of the row's scale; exact to ~1e-9 relative); values_and_jacobians with Ψ held
    constant (d φ̄ ≈ Ψ_v [A_c B_c] / T: the linearization's own Jacobian, for the MPC's iLQR)."""

    def __init__(self, robot, sample_period: float):
        super().__init__(robot)
        if sample_period is None or not (np.isfinite(sample_period) and sample_period > 0):
            raise InputError(f"period acceleration needs a sample period > 0 s, got {sample_period}")
        self.sample_period = float(sample_period)

    def _period_mean(self, q, v, tau):
        """(φ̄ (N, n), Ψ_v [A_c B_c] / T (N, n, 2n + m)) from one AutoDiff pass per row."""
        q, v, tau = self._rows(q, v, tau)
        n, T = self.num_joints, self.sample_period
        accelerations, jacobians = super().values_and_jacobians(q, v, tau)
        values, derivatives = np.empty_like(q), np.empty_like(jacobians)
        for i in range(len(q)):
            A_c, B_c = state_space_jacobians(jacobians[i])
            _, integral = zero_order_hold_discretization(A_c, np.eye(2 * n), T)      # Ψ (2n, 2n)
            values[i] = integral[n:] @ np.concatenate([v[i], accelerations[i]]) / T
            derivatives[i] = integral[n:] @ np.hstack([A_c, B_c]) / T
        return values, derivatives

    def values(self, q, v, tau) -> np.ndarray:
        return self._period_mean(q, v, tau)[0]

    def values_and_jacobians(self, q, v, tau) -> tuple[np.ndarray, np.ndarray]:
        return self._period_mean(q, v, tau)

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

