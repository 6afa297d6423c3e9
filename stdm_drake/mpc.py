"""Model predictive control of the UR-10 with a pluggable prediction model.

The optimizer is iLQR (iterative LQR: a gradient-based shooting method on the model's
Jacobians). Why iLQR rather than sampling (MPPI/CEM): the learned models are smooth, their
Jacobians cost one forward-mode pass, and derivative training is exactly what makes those
Jacobians right, so the controller uses what the method improves; and the plant itself can
serve as the reference model (exact rollouts through the same discrete plant, Jacobians from
Drake's AutoDiff), which a sampling method could not afford (tens of thousands of plant steps per
control step).

Cost over the horizon H (k = 0..H-1, reference r from a planner, u_ff = g(q_ref) the static
gravity torque at the reference):
    sum_k (x_k+1 - r_k+1)^T Q (x_k+1 - r_k+1) + (u_k - u_ff,k)^T R (u_k - u_ff,k),
with the last state term weighted by `terminal_factor`. Torques are clipped to the effort limits
in the forward passes (clamped iLQR). The first torque is applied, the rest warm-starts the next
solve; by default one iLQR iteration per control step (a real-time iteration: with the warm start,
more iterations changed the closed-loop tracking by less than 0.5 %).

Offset-free MPC: every prediction over the horizon is shifted by a disturbance estimate d, the
model's latest one-step error x_k - f(x_k-1, u_k-1) (filtered by `disturbance_gain`), so a model's
slowly varying bias does not become a tracking error. For the plant as model d is ~0.

Every prediction model provides `sample_period` (s) and two batched methods:
    step(x (N, 12), u (N, 6)) -> x_next (N, 12)
    jacobians(x (H, 12), u (H, 6)) -> (A (H, 12, 12), B (H, 12, 6))   of x_next w.r.t. x and u.
"""
import dataclasses
import time

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from stdm_drake.config import check_joint_vector, load_yaml_config
from stdm_drake.errors import InputError
from stdm_drake.robot import CONTROLLERS_DIR, NUM_JOINTS, Dynamics, PlantConfig, joint_limits

STATE_DIM = 2 * NUM_JOINTS
DEFAULT_MPC_CONFIG = CONTROLLERS_DIR / "mpc.yaml"


@dataclasses.dataclass
class MpcConfig:
    """MPC settings (controllers/mpc.yaml).

    position_weight (6) 1/rad^2, velocity_weight (6) s^2/rad^2, effort_weight (6) 1/(N m)^2 on the
    torque beyond the reference's gravity torque; horizon in sample periods; iLQR iterations per
    control step, line-search step sizes and the initial Levenberg-Marquardt regularization;
    disturbance_gain in [0, 1]: observer gain of the offset-free disturbance estimate (0 = off).
    """
    horizon: int = 20
    position_weight: list[float] = dataclasses.field(default_factory=lambda: [1e4] * 6)
    velocity_weight: list[float] = dataclasses.field(default_factory=lambda: [10.0] * 6)
    effort_weight: list[float] = dataclasses.field(
        default_factory=lambda: [1e-4, 1e-4, 1e-3, 0.1, 1.0, 100.0])
    terminal_factor: float = 10.0
    max_iterations: int = 1
    line_search: list[float] = dataclasses.field(default_factory=lambda: [1.0, 0.5, 0.25, 0.1])
    regularization: float = 1e-6
    disturbance_gain: float = 1.0

    def validate(self) -> None:
        for name in ("position_weight", "velocity_weight", "effort_weight"):
            check_joint_vector(f"mpc {name}", getattr(self, name), nonnegative=True)
        if np.any(np.asarray(self.effort_weight) <= 0):
            raise InputError("mpc effort_weight must be > 0 for every joint (the torque problem must be convex)")
        if not 0.0 <= self.disturbance_gain <= 1.0:
            raise InputError(f"mpc disturbance_gain must be in [0, 1], got {self.disturbance_gain}")
        if self.horizon < 1 or self.max_iterations < 1 or not self.line_search:
            raise InputError("mpc horizon and max_iterations must be >= 1 and line_search non-empty")


def load_mpc_config(path=DEFAULT_MPC_CONFIG) -> MpcConfig:
    return load_yaml_config(path, MpcConfig, what="MPC config")


class PlantModel:
    """The UR-10 plant itself as a prediction model at the control period.

    step: the same discrete Drake plant as the simulation (plant step h, torque held for the whole
    period), so its predictions are exact. jacobians: Drake AutoDiff linearization of the
    continuous dynamics at (x_k, u_k), discretized over the period with a matrix exponential.
    """

    name = "plant"

    def __init__(self, sample_period: float, plant_config: PlantConfig | None = None):
        from pydrake.systems.analysis import Simulator
        from pydrake.systems.framework import DiagramBuilder

        from stdm_drake.robot import make_plant
        self.sample_period = sample_period
        builder = DiagramBuilder()
        self.plant, _ = make_plant(plant_config or PlantConfig(), builder=builder)
        builder.ExportInput(self.plant.get_actuation_input_port(), "actuation")
        self.diagram = builder.Build()
        self.simulator = Simulator(self.diagram)
        self.context = self.simulator.get_mutable_context()
        self.plant_context = self.plant.GetMyContextFromRoot(self.context)
        continuous, _ = make_plant(PlantConfig(time_step=0.0))
        self.autodiff_plant = continuous.ToAutoDiffXd()
        self.autodiff_context = self.autodiff_plant.CreateDefaultContext()

    def step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        x, u = np.atleast_2d(x), np.atleast_2d(u)
        out = np.empty_like(x, dtype=float)
        for i in range(len(x)):
            self.diagram.SetDefaultContext(self.context)
            self.context.SetTime(0.0)
            self.plant.SetPositionsAndVelocities(self.plant_context, x[i])
            self.diagram.get_input_port(0).FixValue(self.context, u[i])
            self.simulator.Initialize()
            self.simulator.AdvanceTo(self.sample_period)
            out[i] = self.plant.GetPositionsAndVelocities(self.plant_context)
        return out

    def jacobians(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        from pydrake.autodiffutils import ExtractGradient, InitializeAutoDiff
        horizon = len(x)
        A = np.empty((horizon, STATE_DIM, STATE_DIM))
        B = np.empty((horizon, STATE_DIM, NUM_JOINTS))
        for k in range(horizon):
            z = InitializeAutoDiff(np.concatenate([x[k], u[k]])).ravel()
            self.autodiff_plant.SetPositionsAndVelocities(self.autodiff_context, z[:STATE_DIM])
            self.autodiff_plant.get_actuation_input_port().FixValue(self.autodiff_context, z[STATE_DIM:])
            derivatives = self.autodiff_plant.EvalTimeDerivatives(self.autodiff_context).CopyToVector()
            gradient = ExtractGradient(derivatives)
            A[k], B[k] = zero_order_hold_discretization(gradient[:, :STATE_DIM], gradient[:, STATE_DIM:],
                                                        self.sample_period)
        return A, B


def zero_order_hold_discretization(A_c: np.ndarray, B_c: np.ndarray, period: float, order: int = 4):
    """(A_d, B_d) = (exp(A_c T), int_0^T exp(A_c s) ds B_c) by their Taylor series to `order`.

    scipy's expm of the augmented matrix spends ~5 ms per call here, because the wrist columns of
    B_c (1/inertia ~ 3000) force many squarings; |A_c T| itself is small at T = 10 ms.
    """
    AT = A_c * period
    term = np.eye(len(A_c))
    exp_sum = term.copy()      # sum AT^n / n!
    integral_sum = term.copy()  # sum AT^n / (n+1)!
    for n in range(1, order + 1):
        term = term @ AT / n
        exp_sum += term
        integral_sum += term / (n + 1)
    return exp_sum, period * integral_sum @ B_c


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
        self.Q = np.diag(np.concatenate([config.position_weight, config.velocity_weight]))
        self.R = np.diag(np.asarray(config.effort_weight, dtype=float))

    def rollout(self, x0: np.ndarray, u: np.ndarray, offset: np.ndarray | None = None) -> np.ndarray:
        """Predicted states (H+1, 12) from x0 under u (H, 6), each step shifted by `offset` (12,)."""
        offset = np.zeros(STATE_DIM) if offset is None else offset
        x = np.empty((len(u) + 1, STATE_DIM))
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
        offset = np.zeros(STATE_DIM) if offset is None else np.asarray(offset, dtype=float)
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
        feedforward = np.empty((horizon, NUM_JOINTS))
        feedback = np.empty((horizon, NUM_JOINTS, STATE_DIM))
        # gradients of the running costs, all steps at once
        state_gradient = terminal[:, None] * ((x[1:] - reference[1:]) @ self.Q)
        effort_gradient = (u - u_ff) @ self.R
        R_regularized = self.R + mu * np.eye(NUM_JOINTS)
        V_x = np.zeros(STATE_DIM)
        V_xx = np.zeros((STATE_DIM, STATE_DIM))
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


@dataclasses.dataclass
class Reference:
    """A reference trajectory at the control period: q (N+1, 6) rad, v (N+1, 6) rad/s.

    Past its end the reference holds its last sample (at rest).
    """
    q: np.ndarray
    v: np.ndarray

    def window(self, k: int, length: int) -> np.ndarray:
        """States r_k .. r_k+length-1 as (length, 12), holding the last sample past the end."""
        index = np.minimum(np.arange(k, k + length), len(self.q) - 1)
        return np.hstack([self.q[index], self.v[index]])


@dataclasses.dataclass
class MpcLog:
    """What the controller did at each control step (diagnostics, appended as it runs)."""
    time: list = dataclasses.field(default_factory=list)
    state: list = dataclasses.field(default_factory=list)
    torque: list = dataclasses.field(default_factory=list)
    solve_seconds: list = dataclasses.field(default_factory=list)
    fallback: list = dataclasses.field(default_factory=list)


class MpcController(LeafSystem):
    """Discrete-time MPC: every `model.sample_period` it solves iLQR from the measured state and
    holds the first torque until the next sample.

    Ports: input "state" (12: [q rad, v rad/s]); output "torque" (6, N m).

    Timing: a discrete plant steps at multiples of its step h; the controller updates at
    t_k - h/2, where the plant's state already equals x(t_k), so the torque it computes is the one
    the plant integrates over the whole period [t_k, t_k+1). The first torque comes from an
    initialization event at t = 0.

    State: the torque being applied, the disturbance estimate and the prediction of the next
    measured state made with both (discrete), the warm-start plan (abstract).

    If the model's predictions are not finite, the controller applies gravity compensation at the
    measured q, clipped to the effort limits, and records the step in `log.fallback`.
    """

    def __init__(self, model, reference: Reference, config: MpcConfig, plant_time_step: float):
        super().__init__()
        config.validate()
        self.model = model
        self.reference = reference
        self.config = config
        self.dynamics = Dynamics()
        self.effort_limit = joint_limits(self.dynamics.plant).effort
        self.solver = IlqrSolver(model, config, self.effort_limit)
        self.log = MpcLog()
        period = model.sample_period
        if not 0 < plant_time_step <= period:
            raise InputError(f"plant time step {plant_time_step} s must be in (0, {period}] s")
        self._period = period
        self._state_input = self.DeclareVectorInputPort("state", STATE_DIM)
        self._torque_index = self.DeclareDiscreteState(NUM_JOINTS)
        self._predicted_index = self.DeclareDiscreteState(STATE_DIM)
        self._disturbance_index = self.DeclareDiscreteState(STATE_DIM)
        self._plan_index = self.DeclareAbstractState(AbstractValue.Make(np.zeros((config.horizon, NUM_JOINTS))))
        self.DeclareStateOutputPort("torque", self._torque_index)
        self.DeclareInitializationUnrestrictedUpdateEvent(self._update)
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, period - 0.5 * plant_time_step, self._update)
        self._feedforward = np.array([self.dynamics.gravity_torque(q) for q in reference.q])

    def _estimate_disturbance(self, context, x: np.ndarray) -> np.ndarray:
        """d_k = d_k-1 + gain (x_k - (f(x_k-1, u_k-1) + d_k-1)): the model's recent one-step error,
        added to every step of the next solve (offset-free MPC). The bracket is the prediction
        stored at the last update. Non-finite -> zero."""
        predicted = context.get_discrete_state(int(self._predicted_index)).get_value()
        last = context.get_discrete_state(int(self._disturbance_index)).get_value()
        disturbance = last + self.config.disturbance_gain * (x - predicted)
        return disturbance if np.all(np.isfinite(disturbance)) else np.zeros(STATE_DIM)

    def _update(self, context, state):
        x = self._state_input.Eval(context)
        k = int(round(context.get_time() / self._period))
        horizon = self.config.horizon
        reference = self.reference.window(k, horizon + 1)
        u_ff = self._feedforward[np.minimum(np.arange(k, k + horizon), len(self._feedforward) - 1)]
        warm = state.get_mutable_abstract_state(int(self._plan_index)).get_value()
        if k == 0:
            warm = u_ff  # first solve: start from the reference's gravity torques
        started = time.perf_counter()
        x = np.asarray(x)
        fallback = not np.all(np.isfinite(x))
        disturbance = np.zeros(STATE_DIM)
        if not fallback:
            with np.errstate(all="ignore"):
                if k > 0 and self.config.disturbance_gain > 0:
                    disturbance = self._estimate_disturbance(context, x)
                result = self.solver.solve(x, warm, reference, u_ff, disturbance)
            fallback = not (result.finite and np.all(np.isfinite(result.u)))
        if fallback:
            q = np.nan_to_num(x[:NUM_JOINTS])
            torque = np.clip(self.dynamics.gravity_torque(q), -self.effort_limit, self.effort_limit)
            next_plan = u_ff
            predicted = np.full(STATE_DIM, np.nan)
            if self.config.disturbance_gain > 0:
                with np.errstate(all="ignore"):
                    predicted = self.solver.rollout(x, torque[None], disturbance)[1]
        else:
            torque = result.u[0]
            next_plan = np.vstack([result.u[1:], result.u[-1:]])
            predicted = result.x[1]  # the solve's own prediction under the torque it applies
        elapsed = time.perf_counter() - started
        state.get_mutable_discrete_state(int(self._torque_index)).set_value(torque)
        state.get_mutable_discrete_state(int(self._predicted_index)).set_value(predicted)
        state.get_mutable_discrete_state(int(self._disturbance_index)).set_value(disturbance)
        state.get_mutable_abstract_state(int(self._plan_index)).set_value(next_plan)
        self.log.time.append(context.get_time())
        self.log.state.append(np.array(x))
        self.log.torque.append(torque.copy())
        self.log.solve_seconds.append(elapsed)
        self.log.fallback.append(fallback)


def build_closed_loop(model, reference: Reference, config: MpcConfig, plant_config: PlantConfig | None = None,
                      meshcat=None):
    """Diagram: UR-10 plant (discrete) <-> MpcController(model). Returns (diagram, plant, controller)."""
    from stdm_drake.robot import make_plant
    plant_config = plant_config or PlantConfig()
    builder = DiagramBuilder()
    plant, scene_graph = make_plant(plant_config, builder=builder)
    controller = builder.AddSystem(MpcController(model, reference, config, plant_config.time_step))
    controller.set_name("mpc")
    builder.Connect(plant.get_state_output_port(), controller.get_input_port(0))
    builder.Connect(controller.get_output_port(0), plant.get_actuation_input_port())
    if meshcat is not None:
        from pydrake.geometry import MeshcatVisualizer
        MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat)
    return builder.Build(), plant, controller


def run_closed_loop(model, reference: Reference, config: MpcConfig, plant_config: PlantConfig | None = None,
                    duration: float | None = None) -> MpcLog:
    """Simulate plant + MPC from rest at the reference's start; returns the controller's log."""
    from pydrake.systems.analysis import Simulator
    diagram, plant, controller = build_closed_loop(model, reference, config, plant_config)
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    x0 = np.concatenate([reference.q[0], np.zeros(NUM_JOINTS)])
    plant.SetPositionsAndVelocities(plant.GetMyContextFromRoot(context), x0)
    period = model.sample_period
    duration = (len(reference.q) - 1) * period if duration is None else duration
    simulator.Initialize()
    simulator.AdvanceTo(duration - 0.25 * period)  # the last update (t = duration - h/2) included
    return controller.log


# ---- closed-loop comparison and the `stdm-drake mpc` command ---------------------------------

@dataclasses.dataclass
class ClosedLoopResult:
    """One closed-loop run: model name, reference index, and its metrics (units in the names)."""
    model: str
    trajectory: int
    q_mse_rad2: float
    v_mse: float
    torque_rms_nm: float
    effort_beyond_gravity_rms_nm: float
    limit_violations: int
    fallbacks: int
    solve_ms_mean: float
    solve_ms_p95: float
    steps: int
    q_error: list  # per-step RMS joint-angle error (rad), for plots


def closed_loop_metrics(name: str, index: int, log: MpcLog, reference: Reference, limits, gravity) -> ClosedLoopResult:
    """gravity: (N, 6) torque holding the arm at each reference sample (N >= the run's steps)."""
    states, torques = np.array(log.state), np.array(log.torque)
    steps = len(states)
    error = states - reference.window(0, steps)
    q_error, v_error = error[:, :NUM_JOINTS], error[:, NUM_JOINTS:]
    finite = np.all(np.isfinite(states), axis=1)
    outside = ((states[:, :NUM_JOINTS] < limits.position_lower) | (states[:, :NUM_JOINTS] > limits.position_upper)
               | (np.abs(states[:, NUM_JOINTS:]) > limits.velocity))
    solve_ms = 1e3 * np.array(log.solve_seconds)
    return ClosedLoopResult(
        model=name, trajectory=index,
        q_mse_rad2=float(np.mean(q_error ** 2)), v_mse=float(np.mean(v_error ** 2)),
        torque_rms_nm=float(np.sqrt(np.mean(torques ** 2))),
        effort_beyond_gravity_rms_nm=float(np.sqrt(np.mean((torques - gravity[:steps]) ** 2))),
        limit_violations=int(np.count_nonzero(outside.any(axis=1) | ~finite)),
        fallbacks=int(np.count_nonzero(log.fallback)),
        solve_ms_mean=float(solve_ms.mean()), solve_ms_p95=float(np.percentile(solve_ms, 95)), steps=steps,
        q_error=np.sqrt(np.mean(q_error ** 2, axis=1)).tolist())


def compare_controllers(models: list, references: list[tuple[int, Reference]], config: MpcConfig,
                        plant_config: PlantConfig | None = None, progress: bool = True, recorder=None):
    """Run plant + MPC(model) on every reference for every model; returns [ClosedLoopResult].

    recorder: an optional ghost TrajectoryRecorder; each run is added (robot = plant, ghost = reference).
    """
    from tqdm import tqdm
    dynamics = Dynamics()
    limits = joint_limits(dynamics.plant)
    results = []
    bar = tqdm(total=len(models) * len(references), desc="mpc", unit="run", disable=not progress)
    # gravity at each reference sample, held past its end like the reference (a run may outlast it)
    horizon = max(len(reference.q) for _, reference in references) + 1
    gravity = {index: np.array([dynamics.gravity_torque(q) for q in reference.window(0, horizon)[:, :NUM_JOINTS]])
               for index, reference in references}
    for model in models:
        for index, reference in references:
            log = run_closed_loop(model, reference, config, plant_config)
            results.append(closed_loop_metrics(model.name, index, log, reference, limits, gravity[index]))
            if recorder is not None:
                q = np.array(log.state)[:, :NUM_JOINTS]
                recorder.add(q, reference.window(0, len(q))[:, :NUM_JOINTS])
            bar.update()
    bar.close()
    return results


def summarize(results: list[ClosedLoopResult], sample_period: float) -> list[dict]:
    """One row per model: means over references (solve p95 over all control steps' p95s)."""
    rows = []
    for name in dict.fromkeys(result.model for result in results):
        mine = [result for result in results if result.model == name]
        p95 = max(result.solve_ms_p95 for result in mine)
        rows.append(dict(
            model=name, runs=len(mine),
            q_mse_rad2=float(np.mean([r.q_mse_rad2 for r in mine])),
            v_mse=float(np.mean([r.v_mse for r in mine])),
            effort_beyond_gravity_rms_nm=float(np.mean([r.effort_beyond_gravity_rms_nm for r in mine])),
            limit_violations=int(sum(r.limit_violations for r in mine)),
            fallbacks=int(sum(r.fallbacks for r in mine)),
            solve_ms_mean=float(np.mean([r.solve_ms_mean for r in mine])), solve_ms_p95=float(p95),
            faster_than_real_time=bool(p95 < 1e3 * sample_period)))
    plant = next((row for row in rows if row["model"] == PlantModel.name), None)
    for row in rows:  # tracking error relative to the plant-as-model MPC on the same plans
        known = plant is not None and plant["q_mse_rad2"] > 0
        row["q_mse_vs_plant"] = float(row["q_mse_rad2"] / plant["q_mse_rad2"]) if known else None
    return rows


def markdown_table(rows: list[dict]) -> str:
    header = ("| model | runs | q MSE (rad²) | q MSE / plant MPC | q̇ MSE ((rad/s)²) | effort beyond g, RMS (N m) "
              "| limit violations | fallbacks | solve mean (ms) | solve p95 (ms) | faster than real time |")
    lines = [header, "|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        ratio = "" if row.get("q_mse_vs_plant") is None else f"{row['q_mse_vs_plant']:.3g}"
        lines.append(f"| {row['model']} | {row['runs']} | {row['q_mse_rad2']:.3g} | {ratio} | {row['v_mse']:.3g} "
                     f"| {row['effort_beyond_gravity_rms_nm']:.3g} | {row['limit_violations']} | {row['fallbacks']} "
                     f"| {row['solve_ms_mean']:.2f} | {row['solve_ms_p95']:.2f} "
                     f"| {'yes' if row['faster_than_real_time'] else 'no'} |")
    return "\n".join(lines)


def plot_results(results: list[ClosedLoopResult], sample_period: float, path) -> None:
    """Per-step RMS joint-angle error of the first reference, one line per model (PNG)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stdm_drake.files import atomic_path
    first = results[0].trajectory
    figure, axes = plt.subplots(1, 2, figsize=(11, 4))
    for result in results:
        if result.trajectory == first:
            t = np.arange(len(result.q_error)) * sample_period
            axes[0].semilogy(t, np.maximum(result.q_error, 1e-12), label=result.model)
    axes[0].set(xlabel="time (s)", ylabel="RMS joint-angle error (rad)", title=f"MPC tracking, plan {first}")
    axes[0].legend()
    names = list(dict.fromkeys(result.model for result in results))
    means = [np.mean([r.q_mse_rad2 for r in results if r.model == name]) for name in names]
    axes[1].bar(names, means)
    axes[1].set(yscale="log", ylabel="q MSE (rad²)", title="mean over held-out plans")
    figure.tight_layout()
    with atomic_path(path) as temp:
        figure.savefig(temp, format="png", dpi=110)
    plt.close(figure)


def held_out_references(dataset, checkpoints: list, count: int) -> list[tuple[int, Reference]]:
    """`count` held-out trajectories as references: their *planned* q, v (tracking data) or
    recorded q, v (excitation data). Held out = in no checkpoint's training or validation set
    (when a checkpoint was trained on this dataset), test-split trajectories first."""
    seen, test = set(), []
    for checkpoint in checkpoints:
        split = checkpoint.metadata.get("split")
        if split and checkpoint.metadata.get("dataset_sha256") == dataset.sha256:
            seen |= set(split["train"]) | set(split["val"])
            test += [index for index in split["test"] if index not in test]
    rest = [index for index in range(dataset.num_trajectories - 1, -1, -1) if index not in seen and index not in test]
    indices = [index for index in test if index not in seen] + rest
    if not indices:
        raise InputError(f"{dataset.path}: every trajectory was used to train or validate the models; "
                         "no held-out plan to track")
    references = []
    for index in indices[:count]:
        traj = dataset.trajectory(index)
        if dataset.protocol == "tracking":
            references.append((index, Reference(q=traj["q_planned"], v=traj["v_planned"])))
        else:
            references.append((index, Reference(q=traj["q_true"], v=traj["v_true"])))
    return references


def add_arguments(parser) -> None:
    import pathlib
    parser.add_argument("dataset", type=pathlib.Path, help="tracking dataset whose held-out plans are the references")
    parser.add_argument("--model", action="append", default=[], metavar="NAME=CHECKPOINT",
                        help="a learned model to compare (repeatable), e.g. DD=runs/dd/seed0/checkpoint.pt")
    parser.add_argument("--no-plant", action="store_true", help="leave out the plant-as-model reference MPC")
    parser.add_argument("--plans", type=int, default=3, help="held-out plans to track (default 3)")
    parser.add_argument("--config", type=pathlib.Path, default=DEFAULT_MPC_CONFIG, help="MPC settings YAML")
    parser.add_argument("--output", "-o", type=pathlib.Path, default=pathlib.Path("out/mpc"),
                        help="folder for mpc.md, mpc.csv, mpc.json and mpc.png")
    parser.add_argument("--html", type=pathlib.Path, help="Meshcat recording: plant (robot) vs reference (ghost)")
    parser.add_argument("--quiet", action="store_true")


def run(args) -> int:
    import json

    import torch

    from stdm_drake.dataset import load_dataset
    from stdm_drake.files import write_text_atomic
    from stdm_drake.learned_system import LearnedModel
    torch.set_num_threads(1)  # the solver makes many small calls; threads only add overhead
    config = load_mpc_config(args.config)
    dataset = load_dataset(args.dataset)
    learned = []
    for entry in args.model:
        name, separator, path = entry.partition("=")
        if not separator or not name or not path:
            raise InputError(f"--model takes NAME=CHECKPOINT, got {entry!r}")
        learned.append(LearnedModel(path, name=name))
    for model in learned:
        if abs(model.sample_period - dataset.sample_period) > 1e-12:
            raise InputError(f"model {model.name} steps at {model.sample_period} s, the dataset at {dataset.sample_period} s")
    models = ([] if args.no_plant else [PlantModel(dataset.sample_period)]) + learned
    if not models:
        raise InputError("nothing to compare: give --model NAME=CHECKPOINT or keep the plant model")
    references = held_out_references(dataset, [model.checkpoint for model in learned], args.plans)
    recorder = None
    if args.html:
        from stdm_drake.visualize import TrajectoryRecorder
        recorder = TrajectoryRecorder(dataset.sample_period, ghost=True)
    results = compare_controllers(models, references, config, progress=not args.quiet, recorder=recorder)
    rows = summarize(results, dataset.sample_period)
    table = markdown_table(rows)
    print(table)
    out = args.output
    write_text_atomic(out / "mpc.md", table + "\n")
    write_text_atomic(out / "mpc.json", json.dumps(dict(summary=rows, runs=[dataclasses.asdict(r) for r in results]),
                                                   indent=1))
    columns = [field.name for field in dataclasses.fields(ClosedLoopResult) if field.name != "q_error"]
    write_text_atomic(out / "mpc.csv", "\n".join([",".join(columns)] + [
        ",".join(str(getattr(result, column)) for column in columns) for result in results]) + "\n")
    plot_results(results, dataset.sample_period, out / "mpc.png")
    print(f"wrote {out}/mpc.md, mpc.csv, mpc.json, mpc.png")
    if recorder is not None:
        recorder.finish(args.html, what="robot: plant under MPC; translucent orange: the reference")
    return 0
