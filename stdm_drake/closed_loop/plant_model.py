"""The robot's plant itself as an MPC prediction model: exact steps through the same discrete Drake plant
as the simulation, Jacobians by Drake AutoDiff of the continuous dynamics discretized over the period."""
import numpy as np

from stdm_drake.plant import PlantConfig
from stdm_drake.robot import UR10, Robot


class PlantModel:
    """The plant of `robot` (default: the UR-10 preset) as a prediction model at the control period.

    step: the same discrete Drake plant as the simulation (plant step h, torque held for the whole
    period), so its predictions are exact. jacobians: Drake AutoDiff linearization of the
    continuous dynamics at (x_k, u_k), discretized over the period with a matrix exponential.
    """

    name = "plant"

    def __init__(self, sample_period: float, plant_config: PlantConfig | None = None, robot: Robot | None = None):
        from stdm_drake.plant import PlantSimulator, make_plant
        self.robot = robot or UR10
        self.robot.check_fully_actuated("MPC with the plant as model")
        self.sample_period = sample_period
        self.simulation = PlantSimulator(plant_config, self.robot)
        continuous, _ = make_plant(PlantConfig(time_step=0.0), robot=self.robot)
        self.autodiff_plant = continuous.ToAutoDiffXd()
        self.autodiff_context = self.autodiff_plant.CreateDefaultContext()

    def step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        x, u = np.atleast_2d(x), np.atleast_2d(u)
        out = np.empty_like(x, dtype=float)
        for i in range(len(x)):
            self.simulation.start(x[i], u[i])
            out[i] = self.simulation.advance_to(self.sample_period)
        return out

    def jacobians(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        from pydrake.autodiffutils import ExtractGradient, InitializeAutoDiff
        horizon, n = len(x), self.robot.state_dim
        A = np.empty((horizon, n, n))
        B = np.empty((horizon, n, self.robot.num_joints))
        for k in range(horizon):
            z = InitializeAutoDiff(np.concatenate([x[k], u[k]])).ravel()
            self.autodiff_plant.SetPositionsAndVelocities(self.autodiff_context, z[:n])
            self.autodiff_plant.get_actuation_input_port().FixValue(self.autodiff_context, z[n:])
            derivatives = self.autodiff_plant.EvalTimeDerivatives(self.autodiff_context).CopyToVector()
            gradient = ExtractGradient(derivatives)
            A[k], B[k] = zero_order_hold_discretization(gradient[:, :n], gradient[:, n:],
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
