"""One piece of a log (rows without a gap, pause or mode change) onto the sample period: a trajectory.

The grid is the log's own clock: t_k = t_0 + k h, t_0 the piece's first stamp corrected by the mean offset of
its stamps from a regular clock of the log's period (so jittered stamps do not shift the grid). Angles by cubic
Hermite interpolation of the logged (q, q̇) between the bracketing rows, velocities linearly, the plan by cubic
Hermite of (q_d, q̇_d) and (q̇_d, q̈_d) and its accelerations linearly, the torque over [t_k, t_k + h) the mean of
the commands whose rows fall in it (a row belongs to the period its stamp rounds into; a period without a row,
after a dropped one, takes the nearest row's). Derivative targets: the Savitzky-Golay differentiator (cubic)
of the resampled angles (v_smoothed, qdd_smoothed) and velocities (qdd_measured)."""
import numpy as np
from scipy.interpolate import CubicHermiteSpline
from scipy.signal import savgol_filter

from stdm_drake.data.dataset import Trajectory
from stdm_drake.data.logs.rows import Rows

SMOOTHING_ORDER = 3


def clock_offsets(t: np.ndarray, origin: float, period: float) -> np.ndarray:
    """(N,) s: each stamp's offset from the tick of the clock (`origin`, `period`) it rounds to."""
    return (t - origin) - np.round((t - origin) / period) * period


def clock_origin(t: np.ndarray, period: float) -> float:
    """The first tick of the regular clock of `period` (s) that the stamps t (N,) follow: t_0 plus their
    mean offset from the ticks they round to."""
    return float(t[0] + clock_offsets(t, t[0], period).mean())


def hermite3(s, span, y0, d0, y1, d1):
    """The cubic Hermite interpolant at s in [0, 1] of an interval of length `span` (values y and first
    derivatives d at both ends)."""
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    return h00 * y0 + h10 * span * d0 + h01 * y1 + h11 * span * d1


def grid_size(piece: Rows, period: float, sample_period: float) -> int:
    """How many samples (K + 1) the piece gives on the grid."""
    origin = clock_origin(piece.t, period)
    return int(np.floor((piece.t[-1] - origin) / sample_period + 1e-9)) + 1


def _linear(t: np.ndarray, values: np.ndarray, grid: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(grid, t, values[:, j]) for j in range(values.shape[1])], axis=1)


def _hermite(t, values, slopes, grid) -> np.ndarray:
    return CubicHermiteSpline(t, values, slopes, axis=0, extrapolate=True)(grid)


def held_torques(t: np.ndarray, tau: np.ndarray, origin: float, period: float, sample_period: float,
                 periods: int) -> np.ndarray:
    """(periods + 1, m) the torque over each grid period [t_k, t_k + h), k = 0..periods (the last one: the
    command after the trajectory's end, its tau_next): the mean of the rows that round into it; an empty
    period, the nearest row's."""
    bins = np.floor((t - origin + period / 2) / sample_period).astype(np.int64)
    inside = (bins >= 0) & (bins <= periods)
    counts = np.bincount(bins[inside], minlength=periods + 1)
    sums = np.stack([np.bincount(bins[inside], weights=tau[inside, j], minlength=periods + 1)
                     for j in range(tau.shape[1])], axis=1)
    held = sums / np.maximum(counts, 1)[:, None]
    empty = np.flatnonzero(counts == 0)
    if len(empty):
        centers = origin + (empty + 0.5) * sample_period - period / 2
        nearest = np.clip(np.searchsorted(t, centers), 1, len(t) - 1)
        nearest -= (centers - t[nearest - 1]) < (t[nearest] - centers)
        held[empty] = tau[nearest]
    return held


def resample(piece: Rows, period: float, sample_period: float, window: int) -> tuple[Trajectory, float]:
    """(the piece's Trajectory on the grid, its grid's first time t_0 in the log's clock, s). period: the log's
    row period (s); sample_period: the dataset's (s); window: the smoothing window (samples, odd; the piece has
    at least that many grid samples)."""
    origin = clock_origin(piece.t, period)
    samples = grid_size(piece, period, sample_period)
    grid = origin + sample_period * np.arange(samples)
    t = piece.t
    held = held_torques(t, piece.tau, origin, period, sample_period, samples - 1)
    arrays = dict(q=_hermite(t, piece.q, piece.v, grid), v=_linear(t, piece.v, grid), tau=held[:-1], tau_next=held[-1])
    if piece.has_plan:
        arrays.update(q_planned=_hermite(t, piece.q_planned, piece.v_planned, grid),
                      v_planned=_hermite(t, piece.v_planned, piece.qdd_planned, grid),
                      qdd_planned=_linear(t, piece.qdd_planned, grid))
    smooth = dict(window_length=window, polyorder=SMOOTHING_ORDER, delta=sample_period, axis=0, mode="interp")
    arrays.update(v_smoothed=savgol_filter(arrays["q"], deriv=1, **smooth),
                  qdd_smoothed=savgol_filter(arrays["q"], deriv=2, **smooth),
                  qdd_measured=savgol_filter(arrays["v"], deriv=1, **smooth))
    return Trajectory(**arrays), origin


# leave-one-out error / the interpolation error at the log's spacing: 16 for smooth (C4) motion, 4 where the
# acceleration steps between rows (held torques): the import states the conservative one
LEAVE_ONE_OUT_FACTOR = 4.0


def leave_one_out_errors(piece: Rows) -> tuple[float, int]:
    """(sum of squared errors, count) of predicting each inner row's angles from its two neighbours by the
    resampling's cubic Hermite interpolation (interval 2Δ): LEAVE_ONE_OUT_FACTOR times the error at Δ or more."""
    t, q, v = piece.t, piece.q, piece.v
    if len(t) < 3:
        return 0.0, 0
    left, right = slice(0, -2), slice(2, None)
    span = (t[right] - t[left])[:, None]
    s = (t[1:-1, None] - t[left, None]) / span
    errors = hermite3(s, span, q[left], v[left], q[right], v[right]) - q[1:-1]
    return float(np.sum(errors**2)), errors.size
