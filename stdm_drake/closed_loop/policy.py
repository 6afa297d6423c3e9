"""The MPC's control step as a function of what it carries from one step to the next (`StepMemory`), so the same
step runs inside Drake (`mpc.MpcController`, its memory in the context's state) and as a controller callback of
the collection station (`MpcPolicy`: the model-based RL loop's data, `experiments.mbrl_loop`).

For a robot of n joints (m actuated), a horizon of H steps, state S = 2n: torques (m,) N m, states (S,).
"""
import dataclasses

import numpy as np

from stdm_drake.closed_loop.constraints import SLACK_TOLERANCE


@dataclasses.dataclass
class StepMemory:
    """What a control step leaves the next one: the prediction of the next measured state made with the applied
    torque and the disturbance estimate (S,), that estimate (S,), the warm-start torques (H, m) and states
    (H+1, S; NaN: none) shifted by one period."""
    predicted: np.ndarray
    disturbance: np.ndarray
    plan: np.ndarray
    nodes: np.ndarray


@dataclasses.dataclass(frozen=True)
class StepStatus:
    """How a control step went: fallback (the gravity fallback acted), constraint_active (a torque bound or a state
    limit active in the solution), slack (the largest crossing of a state limit the solution accepted, rad or
    rad/s; 0: none)."""
    fallback: bool
    constraint_active: bool = False
    slack: float = 0.0


class MpcStep:
    """One control step at sample k from the measured state x (mpc.MpcController's docstring: the offset-free
    disturbance estimate, the warm start, the gravity fallback when the prediction is not finite).

    solver: a `TrajectoryOptimizer`; reference: an `mpc.Reference`; gravity_torque(q) -> (n,) N m; horizon and
    disturbance_gain: the MPC settings'; effort_limit (m,) N m.
    """

    def __init__(self, solver, reference, gravity_torque, horizon: int, disturbance_gain: float,
                 effort_limit: np.ndarray, warm_states: bool):
        self.solver, self.reference, self.gravity_torque = solver, reference, gravity_torque
        self.horizon, self.disturbance_gain = horizon, disturbance_gain
        self.effort_limit, self.warm_states = effort_limit, warm_states
        self.feedforward = np.array([gravity_torque(q) for q in reference.q])
        self.joints = len(reference.q[0])
        self.state_dim = 2 * self.joints
        # the whole step in one compiled call where the solver has one (compiled.CompiledRtiSolver)
        self.compiled = solver.control_step(np.hstack([reference.q, reference.v]), self.feedforward, horizon,
                                            disturbance_gain) if hasattr(solver, "control_step") else None

    def first_memory(self) -> StepMemory:
        """The memory before the first step: no prediction, no disturbance, the reference's gravity torques."""
        return StepMemory(predicted=np.full(self.state_dim, np.nan), disturbance=np.zeros(self.state_dim),
                          plan=self.feedforward_window(0),
                          nodes=np.full((self.horizon + 1, self.state_dim), np.nan))

    def __call__(self, k: int, x: np.ndarray, memory: StepMemory) -> tuple[np.ndarray, StepMemory, StepStatus]:
        """(torque (m,), the next step's memory, how the step went) at sample k."""
        x = np.asarray(x, dtype=float)
        if self.compiled is not None:
            solved, torque, predicted, disturbance, plan, nodes, active, slack = self.compiled.step(
                k, x, memory.predicted, memory.disturbance, memory.plan, memory.nodes)
            if solved:
                return torque, StepMemory(predicted, disturbance, plan, nodes), StepStatus(False, active, slack)
            return self.fallback(k, x, disturbance)
        horizon = self.horizon
        reference = self.reference.window(k, horizon + 1)
        u_ff = self.feedforward_window(k)
        fallback = not np.all(np.isfinite(x))
        disturbance = np.zeros(self.state_dim)
        if not fallback:
            with np.errstate(all="ignore"):
                if k > 0 and self.disturbance_gain > 0:
                    disturbance = self.estimate_disturbance(x, memory)
                warm = u_ff if k == 0 else memory.plan
                nodes = None if k == 0 or not np.all(np.isfinite(memory.nodes)) else memory.nodes
                if self.warm_states:
                    result = self.solver.solve(x, warm, reference, u_ff, disturbance, x_init=nodes)
                else:
                    result = self.solver.solve(x, warm, reference, u_ff, disturbance)
            fallback = not (result.finite and np.all(np.isfinite(result.u)))
        if fallback:
            return self.fallback(k, x, disturbance)
        torque = result.u[0]
        return torque, StepMemory(predicted=result.x[1], disturbance=disturbance,
                                  plan=np.vstack([result.u[1:], result.u[-1:]]),
                                  nodes=np.vstack([result.x[1:], result.x[-1:]])), \
            StepStatus(False, result.constraint_active, result.slack)

    def feedforward_window(self, k: int) -> np.ndarray:
        """The reference's gravity torques (H, m) N m from sample k, holding the last one past the end."""
        return self.feedforward[np.minimum(np.arange(k, k + self.horizon), len(self.feedforward) - 1)]

    def fallback(self, k: int, x: np.ndarray, disturbance: np.ndarray) -> tuple[np.ndarray, StepMemory, StepStatus]:
        """The gravity fallback at sample k: the reference-free hold of x's joint angles (non-finite ones as 0),
        within the torque limits; the memory: the model's prediction under it and the reference's gravity
        torques as the next warm start."""
        q = np.nan_to_num(x[:self.joints])
        torque = np.clip(self.gravity_torque(q), -self.effort_limit, self.effort_limit)
        predicted = np.full(self.state_dim, np.nan)
        if self.disturbance_gain > 0:
            with np.errstate(all="ignore"):
                predicted = self.solver.rollout(x, torque[None], disturbance)[1]
        return torque, StepMemory(predicted, disturbance, self.feedforward_window(k),
                                  np.full((self.horizon + 1, self.state_dim), np.nan)), StepStatus(True)

    def estimate_disturbance(self, x: np.ndarray, memory: StepMemory) -> np.ndarray:
        """d_k = d_k-1 + gain (x_k - (f(x_k-1, u_k-1) + d_k-1)): the model's recent one-step error, added to every
        step of the next solve (offset-free MPC); the bracket is the last step's prediction. Non-finite -> zero."""
        disturbance = memory.disturbance + self.disturbance_gain * (x - memory.predicted)
        return disturbance if np.all(np.isfinite(disturbance)) else np.zeros(self.state_dim)


class MpcPolicy:
    """The MPC of `model` as a tracking controller of the collection station: `control(k, t, q, v)` (the
    measurement at sample k) -> torque (m,) N m held over the period, the same step as the Drake controller's.
    One reference per policy: make a new one for every trajectory. `fallbacks` counts gravity fallbacks,
    `constraint_active` the steps with a limit active in the solution, `slack_used` those whose solution accepted
    a crossing of a state limit."""

    def __init__(self, model, reference, config, robot, optimizer=None):
        import inspect
        from stdm_drake.robots.plant import Dynamics, joint_limits   # lazy: pydrake
        dynamics = Dynamics(robot)
        limits = joint_limits(dynamics.plant)
        solver = optimizer or config.solver(model, limits, robot.joint_names)
        self.step = MpcStep(solver, reference, dynamics.gravity_torque, config.horizon, config.disturbance_gain,
                            limits.effort, "x_init" in inspect.signature(solver.solve).parameters)
        self.memory = self.step.first_memory()
        self.fallbacks = self.constraint_active = self.slack_used = 0

    def control(self, k: int, t: float, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        torque, self.memory, status = self.step(k, np.concatenate([q, v]), self.memory)
        self.fallbacks += int(status.fallback)
        self.constraint_active += int(status.constraint_active)
        self.slack_used += int(status.slack > SLACK_TOLERANCE)
        return torque
