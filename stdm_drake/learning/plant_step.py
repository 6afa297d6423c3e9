"""The physics part of a grey-box model: a plant model's next state as the network's base (see
`learning.structure`, plant-step inputs)."""
import numpy as np

from stdm_drake.learning.physics import PlantModel, central_difference_rates


class PlantStep:
    """The next state x̂_{k+1} (N, 2n) of a plant model (`PlantModel`: the robot's description, or the
    description with identified parameters as `effects`) from x_k = [q, v] under the held action τ: the
    physics part of a grey-box model, whose network learns only the residual. Same interface as
    NominalAcceleration with width 2n: values; rates, the step's time derivative along a tangent
    (q̇, v̇, τ̇), by a central difference of the discrete step itself (two plant steps per row, ε = 1e-6 of
    the row's scale: the step's own derivative, where its continuous linearization is 6-11 % off on the
    UR-10's light wrists); values_and_jacobians (x̂ (N, 2n), [A B] (N, 2n, 2n + m): the AutoDiff
    linearization, zero-order-hold discretized, `PlantModel.jacobians`, as the MPC uses for the plant).
    Rows the plant cannot step (non-finite, or a state Drake's solver fails on: a diverged rollout) give NaN."""

    def __init__(self, robot, sample_period: float, effects=None, plant_time_step: float | None = None):
        from stdm_drake.robots.plant import DEFAULT_PLANT_TIME_STEP, PlantConfig
        config = None
        if effects is not None:
            config = PlantConfig.discrete(plant_time_step or DEFAULT_PLANT_TIME_STEP, effects=effects)
        self.model = PlantModel(sample_period, config, robot=robot)
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
        for i in np.flatnonzero(finite):
            try:
                out[i] = self.model.step(x[i:i + 1], tau[i:i + 1])[0]
            except RuntimeError:
                continue
        return out

    def values_and_jacobians(self, q, v, tau) -> tuple[np.ndarray, np.ndarray]:
        return self.values(q, v, tau), self.jacobians(q, v, tau)

    def jacobians(self, q, v, tau) -> np.ndarray:
        x, tau = self._rows(q, v, tau)
        out = np.full((len(x), self.width, self.width + self.action_dim), np.nan)
        finite = np.isfinite(x).all(axis=1) & np.isfinite(tau).all(axis=1)
        if finite.any():
            out[finite] = np.concatenate(self.model.jacobians(x[finite], tau[finite]), axis=2)
        return out

    def rates(self, q, v, tau, q_rate, v_rate, tau_rate) -> np.ndarray:
        """d x̂_{k+1} / dt (N, 2n) along the tangent rows (q̇, v̇, τ̇): central differences of `values`."""
        return central_difference_rates(self.values, self.num_joints, q, v, tau, q_rate, v_rate, tau_rate)
