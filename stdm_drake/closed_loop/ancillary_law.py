"""The samplers' ancillary control law (`sampling.SamplingSolver`): the computed-torque law in the model's own
inertia that every rollout, sampled or applied, runs on its own state, and the gains it can run with.

Shapes for n joints, m actuated, horizon H, state S = 2n: x (S,) rad and rad/s, torques (H, m) N m."""
import numpy as np

from stdm_drake.errors import InputError, bound_text


def check_law_stable(settings, h: float) -> None:
    """InputError unless the ancillary law (feedback_kp 1/s², feedback_kd 1/s) settles the tracking error at the
    model's period h s (0: no period, no check). Over one period the torque is held, so the error e and its rate
    w = h de/dt follow e' = (1 - a/2) e + (1 - b/2) w, w' = -a e + (1 - b) w with a = kp h², b = kd h (a constant
    acceleration, exact; the trapezoid rule of velocity-structured models is the same map); its eigenvalues lie
    inside the unit circle exactly where b < 2 and a < 2 b, i.e. kd h < 2 and kp h < 2 kd (kp 0: the law only damps)."""
    kp, kd = settings.feedback_kp, settings.feedback_kd
    if h <= 0 or (h * kd < 2 and (kp == 0 or kp * h < 2 * kd)):
        return
    unstable = f"makes each rollout's control law unstable at the model's period {h:g} s (the torque held over a period)"
    if h * kd >= 2:
        raise InputError(f"{settings.tag()} feedback_kd {kd:g} 1/s {unstable}: give kd h < 2 "
                         f"(kd < {bound_text(2 / h, at_least=False)})")
    if kp * h ** 2 >= 4:
        raise InputError(f"{settings.tag()} feedback_kp {kp:g} 1/s² {unstable} with any feedback_kd: give kp h² < 4 "
                         f"(kp < {bound_text(4 / h ** 2, at_least=False)}) and kp h < 2 kd < 4 / h")
    lower = f"kp below {bound_text(2 * kd / h, at_least=False, digits=6)} with this kd" if kd > 0 else "kp 0"
    raise InputError(f"{settings.tag()} feedback_kp {kp:g} 1/s² with feedback_kd {kd:g} 1/s {unstable}: give kp h < "
                     f"2 kd ({lower}, or kd in ({bound_text(kp * h / 2, at_least=True, digits=6)}, "
                     f"{bound_text(2 / h, at_least=False, digits=6)}) 1/s)")


def law_eigenvalues(kp: float, kd: float, h: float) -> np.ndarray:
    """The eigenvalues (2,) of the law's held-torque error map at period h s (`check_law_stable`'s map)."""
    a, b = kp * h ** 2, kd * h
    return np.linalg.eigvals(np.array([[1 - a / 2, 1 - b / 2], [-a, 1 - b]]))


def law_radius(kp: float, kd: float, h: float) -> float:
    """The spectral radius of the law's held-torque error map at period h s (`law_eigenvalues`); below 1 the
    tracking error settles, each period by about this factor (the defaults, kp 225 and kd 30 at 10 ms: 0.886)."""
    return float(np.abs(law_eigenvalues(kp, kd, h)).max())


def computed_torque_law(following: np.ndarray, B: np.ndarray, x0: np.ndarray, reference: np.ndarray,
                        u_ff: np.ndarray, offset: np.ndarray, settings, period: float, joints: int):
    """(feedforward (H, m) N m, gain (m, S) N m per (rad, rad/s), acceleration map (n, m) N m per rad/s^2) of the
    law at x0, from the model's step there under u_ff,0: following (S,) its next state, B (S, m) its torque
    Jacobian, B_v = B[n:] = d v_1 / d u. The drift it predicts without the torque beyond gravity,
    c = f_v(x0, u_ff,0) + d_v - v_0 (Coriolis, friction, its own gravity, the disturbance estimate d = offset), is
    taken as constant over the horizon and cancelled: feedforward_k = u_ff,k + B_v^+ (v_ref,k+1 - v_ref,k - c);
    gain = B_v^+ h [kp I, kd I] (settings.feedback_kp 1/s^2, feedback_kd 1/s; h = period s); map = h B_v^+^T.
    A model whose B_v is not finite gets u_ff, no gain and the identity map."""
    n = len(x0) // 2
    velocity = B[n:]
    if not (np.all(np.isfinite(velocity)) and np.all(np.isfinite(following))):
        return u_ff, np.zeros((joints, len(x0))), np.eye(n, joints)
    inverse = np.linalg.pinv(velocity)                                    # (m, n)
    drift = following[n:] + offset[n:] - x0[n:]
    law = period * np.hstack([settings.feedback_kp * np.eye(n), settings.feedback_kd * np.eye(n)])
    return (u_ff + (np.diff(reference[:, n:], axis=0) - drift) @ inverse.T, inverse @ law, period * inverse.T)
