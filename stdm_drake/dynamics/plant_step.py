"""The physics part of a grey-box model: a plant model's next state as the network's base (see
`learning.structure`, plant-step inputs)."""
import numpy as np

from stdm_drake.dynamics.physics import PlantModel, central_difference_jacobians, central_difference_rates


class PlantStep:
    """The next state x̂_{k+1} (N, 2n) of a plant model (`PlantModel`: the robot's description, or the
    description with identified parameters as `effects`) from x_k = [q, v] under the held action τ: the
    physics part of a grey-box model, whose network learns only the residual. Same interface as
    NominalAcceleration with width 2n: values; values_and_jacobians (x̂ (N, 2n), [A B] (N, 2n, 2n + m));
    rates, the step's time derivative along a tangent (q̇, v̇, τ̇).

    integrator "rk4" (what `train` writes): RK4 steps of the continuous dynamics, with exact Jacobians
    (microseconds per row) and rates = Jacobian x tangent. "simulator" (grey boxes trained before the
    field existed): the discrete Drake plant, rates and Jacobians by central differences of its own step
    (ε = 1e-6 of the row's scale; two plant steps per rate, 2 (2n + m) per Jacobian row: exact, slow).
    Rows the plant cannot step (non-finite, or a state Drake's solver fails on: a diverged rollout) give NaN."""

    def __init__(self, robot, sample_period: float, effects=None, plant_time_step: float | None = None, *,
                 integrator: str = "simulator"):
        from stdm_drake.robots.plant import DEFAULT_PLANT_TIME_STEP, PlantConfig   # lazy: pydrake
        config = None
        if effects is not None:
            config = PlantConfig.discrete(plant_time_step or DEFAULT_PLANT_TIME_STEP, effects=effects)
        self.model = PlantModel(sample_period, config, robot=robot, integrator=integrator)
        self.robot = robot
        self.num_joints, self.action_dim = robot.num_joints, robot.action_dim
        self.width = 2 * robot.num_joints

    def _rows(self, q, v, tau):
        q, v, tau = (np.atleast_2d(np.asarray(values, dtype=np.float64)) for values in (q, v, tau))
        return np.hstack([q, v]), tau

    def values(self, q, v, tau) -> np.ndarray:
        x, tau = self._rows(q, v, tau)
        out = np.full_like(x, np.nan)
        finite = np.isfinite(x).all(axis=1) & np.isfinite(tau).all(axis=1)
        if self.model.integrator == "rk4":
            if finite.any():
                out[finite] = self.model.step(x[finite], tau[finite])
            return out
        for i in np.flatnonzero(finite):
            try:
                out[i] = self.model.step(x[i:i + 1], tau[i:i + 1])[0]
            except RuntimeError:
                continue
        return out

    def values_and_jacobians(self, q, v, tau) -> tuple[np.ndarray, np.ndarray]:
        x, tau = self._rows(q, v, tau)
        values = np.full_like(x, np.nan)
        out = np.full((len(x), self.width, self.width + self.action_dim), np.nan)
        finite = np.isfinite(x).all(axis=1) & np.isfinite(tau).all(axis=1)
        if not finite.any():
            return values, out
        if self.model.integrator == "rk4":
            following, A, B = self.model.linearize(x[finite], tau[finite])
        else:   # (the simulator: rows it cannot step give NaN, through `values`)
            n = self.num_joints
            step = lambda state, action: self.values(state[:, :n], state[:, n:], action)   # noqa: E731
            following = step(x[finite], tau[finite])
            A, B = central_difference_jacobians(step, x[finite], tau[finite])
        values[finite], out[finite] = following, np.concatenate([A, B], axis=2)
        return values, out

    def jacobians(self, q, v, tau) -> np.ndarray:
        return self.values_and_jacobians(q, v, tau)[1]

    def rates(self, q, v, tau, q_rate, v_rate, tau_rate) -> np.ndarray:
        """d x̂_{k+1} / dt (N, 2n) along the tangent rows (q̇, v̇, τ̇)."""
        if self.model.integrator == "rk4":
            tangent = np.hstack([np.atleast_2d(q_rate), np.atleast_2d(v_rate), np.atleast_2d(tau_rate)])
            return np.einsum("nij,nj->ni", self.jacobians(q, v, tau), tangent)
        return central_difference_rates(self.values, self.num_joints, q, v, tau, q_rate, v_rate, tau_rate)
