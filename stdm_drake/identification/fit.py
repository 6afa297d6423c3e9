"""Fitting the regressor's parameters to a robot's data: least squares on the identifiable (base)
parameters, and the physically consistent fit.

Both minimize the squared joint-torque error of tau = Y pi (`regressor`) over a dataset's samples
(k = 0 .. T−1 of each trajectory: the held torque tau_k with the state and acceleration at t_k):

    least_squares     ordinary least squares on the base parameters: the columns of Y (each scaled to
                      unit RMS) that a QR decomposition with column pivoting finds independent; the
                      others are combinations of them (set to 0). Reports the condition number of the
                      scaled base regressor (excitation quality) and the covariance
                      sigma² (Y_bᵀ Y_b)⁻¹ of the base parameters.
    consistent_fit    all parameters, each link's pseudo-inertia positive semidefinite (an SDP solved
                      with Drake's MathematicalProgram and Clarabel), friction and rotor inertia >= 0,
                      plus lambda ‖s ⊙ (pi − pi_prior)‖² toward the description's parameters (s the
                      columns' RMS, so lambda is relative to the data term's curvature): the directions
                      the data leave open stay at the description's values.

`IdentificationData` holds a split's samples; the states and accelerations come from the dataset's
true ones (simulated data) or from a Savitzky-Golay smoothing differentiator of the measured angles.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.identification.regressor import InverseDynamicsRegressor, pseudo_inertia

DERIVATIVE_SOURCES = ("true", "smoothed")
SMOOTHING_ORDER = 3            # polynomial order of the Savitzky-Golay differentiator


@dataclasses.dataclass
class IdentificationData:
    """Samples of one split: the regressor's rigid-body rows Y_rb (N, n, 10 B) and fixed part tau_0
    (N, n), velocities v (N, n) rad/s, accelerations v̇ (N, n) rad/s², torques tau (N, n) N m."""
    rigid: np.ndarray
    fixed: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    torque: np.ndarray

    def system(self, regressor: InverseDynamicsRegressor, velocity_scale) -> tuple[np.ndarray, np.ndarray]:
        """(Y (N n, P), tau − tau_0 (N n,)) with the Coulomb columns at velocity scale v_s rad/s."""
        joint = regressor.joint_rows(self.velocity, self.acceleration, velocity_scale)
        rows = np.concatenate([self.rigid, joint], axis=2)
        return rows.reshape(-1, rows.shape[2]), (self.torque - self.fixed).ravel()

    def predicted_torque(self, regressor, parameters: np.ndarray, velocity_scale) -> np.ndarray:
        """tau (N, n) N m of `parameters` (P,) at these samples."""
        rows, _ = self.system(regressor, velocity_scale)
        return (rows @ parameters).reshape(self.torque.shape) + self.fixed


def smoothed_samples(q: np.ndarray, tau: np.ndarray, sample_period: float, window: int):
    """(q, q̇, q̈, tau) (T − 1 − 2 r, n) at the samples k = r + 1 .. T − 1 − r (r = window // 2) of measured
    angles q (T + 1, n) rad and held torques tau (T, n) N m, filtered alike: the angles through a
    Savitzky-Golay smoother K (cubic, `window` samples, odd, >= 5), then central differences:
    q̈_k = (q̃_{k+1} − 2 q̃_k + q̃_{k−1}) / h², the filtered acceleration K * (q_{k+1} − 2 q_k + q_{k−1}) / h²,
    which under torques held over each period answers the torque (tau_{k−1} + tau_k) / 2 (the triangle kernel
    of the second difference weighs the two periods alike); that torque goes through the same K. The
    rigid-body dynamics' linear part then sees the same filter on both sides (the idea of parallel filtering
    in robot identification); q̇_k = (q̃_{k+1} − q̃_{k−1}) / 2h. Filtering and differencing commute only where
    every window lies inside the trajectory, so the r samples at each end are left out. window 1: no
    smoother (the raw differences: what the filter recovers is measured against it)."""
    from scipy.signal import savgol_filter
    q, tau = np.asarray(q, dtype=float), np.asarray(tau, dtype=float)
    half = window // 2
    if window != 1 and (window < 5 or window % 2 == 0 or len(tau) - 1 - 2 * half < 1):
        raise InputError(f"smoothing window must be 1 (none) or an odd number >= 5 of samples that leaves samples "
                         f"inside a trajectory of {len(tau)} steps, got {window}")
    smoothed = (lambda values: values) if window == 1 else (
        lambda values: savgol_filter(values, window, SMOOTHING_ORDER, axis=0, mode="interp"))
    smooth = smoothed(q)
    h = sample_period
    velocity = (smooth[2:] - smooth[:-2]) / (2 * h)
    acceleration = (smooth[2:] - 2 * smooth[1:-1] + smooth[:-2]) / h ** 2
    torque = smoothed(0.5 * (tau[:-1] + tau[1:]))
    inside = slice(half, len(torque) - half)    # samples k = half + 1 .. T - 1 - half
    return smooth[1:-1][inside], velocity[inside], acceleration[inside], torque[inside]


def fits_window(steps: int, window: int) -> bool:
    """Whether a trajectory of `steps` sample periods keeps samples inside a smoothing window."""
    return window == 1 or steps - 1 - 2 * (window // 2) >= 1


def identification_data(regressor: InverseDynamicsRegressor, dataset, indices, source: str = "true",
                        window: int | None = None) -> IdentificationData:
    """The samples of trajectories `indices` of `dataset`: states and accelerations from `source` ("true":
    the simulation's q, v, q̈; "smoothed": the Savitzky-Golay filter of the measured q with `window`)."""
    if source not in DERIVATIVE_SOURCES:
        raise InputError(f"derivative source must be one of {DERIVATIVE_SOURCES}, got {source!r}")
    if not len(indices):
        raise InputError("no trajectories selected for identification")
    if source == "true" and not dataset.is_simulated:
        raise InputError(f"{dataset.path}: a real robot's log has no true accelerations; identify it with "
                         "--derivatives smoothed")
    parts = []
    for index in indices:
        trajectory = dataset.trajectory(int(index))
        steps = len(trajectory.tau)
        if source == "true":
            q, v, vd = trajectory.q_true[:steps], trajectory.v_true[:steps], trajectory.qdd[:steps]
            torque = np.asarray(trajectory.tau, dtype=float)
        else:
            q, v, vd, torque = smoothed_samples(trajectory.q, trajectory.tau, dataset.sample_period, window)
        rigid, fixed = regressor.rigid_body_rows(q, v, vd)
        parts.append(IdentificationData(rigid, fixed, v, vd, torque))
    return IdentificationData(*(np.concatenate([getattr(part, field.name) for part in parts])
                                for field in dataclasses.fields(IdentificationData)))


def relative_torque_error(predicted: np.ndarray, torque: np.ndarray) -> tuple[float, np.ndarray]:
    """(RMS(predicted − tau) / RMS(tau) over all joints, the same per joint (n,)) for (N, n) arrays."""
    error = predicted - torque
    overall = float(np.sqrt(np.mean(error ** 2)) / np.sqrt(np.mean(torque ** 2)))
    per_joint = np.sqrt(np.mean(error ** 2, axis=0)) / np.sqrt(np.mean(torque ** 2, axis=0))
    return overall, per_joint


@dataclasses.dataclass
class LeastSquaresFit:
    """Ordinary least squares on the base parameters.

    parameters (P,): the base parameters' values (each absorbing the combinations of the others), 0
    elsewhere; base (r,) their indices; covariance (r, r) of the base parameters; condition: of the
    base regressor with unit-RMS columns; residual_std: sigma N m."""
    parameters: np.ndarray
    base: np.ndarray
    covariance: np.ndarray
    condition: float
    residual_std: float


def column_scales(rows: np.ndarray) -> np.ndarray:
    """The RMS of each column of `rows` (1 for an all-zero column)."""
    scale = np.sqrt(np.mean(rows ** 2, axis=0))
    return np.where(scale > 0, scale, 1.0)


def least_squares(rows: np.ndarray, target: np.ndarray, tolerance: float = 1e-9) -> LeastSquaresFit:
    """`LeastSquaresFit` of rows (M, P) pi = target (M,); a column whose pivot is below `tolerance` times
    the largest (scaled columns) depends on the ones before it."""
    from scipy.linalg import qr
    scale = column_scales(rows)
    scaled = rows / scale
    _, r, pivots = qr(scaled, mode="economic", pivoting=True)
    diagonal = np.abs(np.diag(r))
    rank = int(np.sum(diagonal > tolerance * diagonal[0]))
    base = np.sort(pivots[:rank])
    solution, *_ = np.linalg.lstsq(scaled[:, base], target, rcond=None)
    parameters = np.zeros(rows.shape[1])
    parameters[base] = solution / scale[base]
    residual = target - rows @ parameters
    degrees = max(len(target) - rank, 1)
    variance = float(residual @ residual) / degrees
    normal = rows[:, base].T @ rows[:, base]
    covariance = variance * np.linalg.inv(normal)
    return LeastSquaresFit(parameters=parameters, base=base, covariance=covariance,
                           condition=float(np.linalg.cond(scaled[:, base])), residual_std=float(np.sqrt(variance)))


def consistent_fit(rows: np.ndarray, target: np.ndarray, prior: np.ndarray, num_links: int,
                   regularization: float, minimum_mass: float = 1e-6, zero=()) -> np.ndarray:
    """Parameters (P,) minimizing ‖rows pi − target‖² / M + lambda ‖s ⊙ (pi − prior)‖² (s: `column_scales`,
    lambda: `regularization` >= 0) with each of the `num_links` links' pseudo-inertia PSD and mass >=
    `minimum_mass` kg, the 3n joint parameters after them >= 0, and the parameters of indices `zero` 0.
    InputError when the solver fails."""
    from pydrake.solvers import ClarabelSolver, MathematicalProgram
    if not (np.isfinite(regularization) and regularization >= 0):
        raise InputError(f"regularization must be a finite number >= 0, got {regularization}")
    count = rows.shape[1]
    scale = column_scales(rows)
    # the solver's variables z = s ⊙ pi; the data term through the QR factor of the scaled rows (P x P),
    # the whole objective as one norm ‖A z − b‖ (a second-order cone: squaring it changes no minimizer)
    q_factor, r_factor = np.linalg.qr(rows / scale)
    weight = 1.0 / np.sqrt(len(target))
    A = np.vstack([weight * r_factor, np.sqrt(regularization) * np.eye(count)])
    b = np.concatenate([weight * (q_factor.T @ target), np.sqrt(regularization) * scale * prior])
    program = MathematicalProgram()
    z = program.NewContinuousVariables(count, "z")
    program.AddL2NormCostUsingConicConstraint(A, -b, z)
    parameters = np.array([variable * (1.0 / factor) for variable, factor in zip(z, scale)])
    for link in range(num_links):
        block = parameters[10 * link:10 * link + 10]
        program.AddPositiveSemidefiniteConstraint(pseudo_inertia(block))
        program.AddLinearConstraint(z[10 * link] >= minimum_mass * scale[10 * link])
    joints = np.arange(10 * num_links, count)
    program.AddBoundingBoxConstraint(0.0, np.inf, z[joints])
    if len(zero):
        program.AddBoundingBoxConstraint(0.0, 0.0, z[np.asarray(zero, dtype=int)])
    result = ClarabelSolver().Solve(program)
    if not result.is_success():
        raise InputError(f"the physically consistent fit failed ({result.get_solution_result()}); the data may not "
                         "excite the robot (see the condition number) or hold non-finite values")
    solution = result.GetSolution(z) / scale
    for link in range(num_links):   # onto the constraints exactly (the solver meets them to its tolerance)
        solution[10 * link:10 * link + 10] = nearest_physical(solution[10 * link:10 * link + 10])
    solution[joints] = np.maximum(solution[joints], 0.0)
    solution[np.asarray(zero, dtype=int)] = 0.0
    return solution


def nearest_physical(parameters: np.ndarray) -> np.ndarray:
    """One link's 10 parameters with the negative eigenvalues of its pseudo-inertia set to 0 (the nearest
    physical parameters in that matrix's Frobenius norm): I = tr(Σ) 1 − Σ from J = [[Σ, h], [hᵀ, m]]."""
    matrix = pseudo_inertia(np.asarray(parameters, dtype=float)).astype(float)
    values, vectors = np.linalg.eigh(matrix)
    if values.min() >= 0:
        return np.asarray(parameters, dtype=float)
    matrix = (vectors * np.maximum(values, 0.0)) @ vectors.T
    second_moment, first, mass = matrix[:3, :3], matrix[:3, 3], matrix[3, 3]
    inertia = np.trace(second_moment) * np.eye(3) - second_moment
    return np.concatenate([[mass], first, np.diag(inertia), [inertia[0, 1], inertia[0, 2], inertia[1, 2]]])
