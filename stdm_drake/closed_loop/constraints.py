"""The robot's limits inside the MPC's optimizers (the MPC settings' `constraints:` block).

Torques: hard box constraints of every optimizer's problem, -effort_limit <= u_k <= effort_limit (m,) N m: the
real-time iteration's Gauss-Newton step is a box-constrained QP (`CondensedQp`), the iLQR's backward pass solves a
box QP at every node and keeps its feedback on the free torques only (box-DDP, Tassa, Mansard & Todorov 2014,
`box_qp`), the samplers keep every rollout's torques in the box.

Joint positions and velocities of the predicted states x_1..x_H: soft constraints, lower <= x_k <= upper with
lower/upper the plant's limits moved inside by `position_margin` rad and `velocity_margin` rad/s. Each crossing
is a slack s >= 0 priced by an exact penalty, `penalty_weight` (s + s^2 / 2) per node and state component (s in
rad or rad/s): the linear term makes the penalty exact (no slack is used while the limits can be met and the
weight exceeds the constraint's multiplier), the quadratic one keeps the QP strictly convex. The problem is
therefore always feasible: a limit that cannot be met costs slack, never a failed solve. `mode: hard` drops the
slack where the limits can be met (the real-time iteration's QP with the state rows as hard constraints) and uses
it only in a step whose hard QP is infeasible (the iLQR and the samplers price crossings alike in both modes); `mode: off` is the controller before constraints: an unconstrained step, torques clipped
to the box afterwards, the state limits ignored (the reference the study compares against).

The QPs are solved by DAQP (Arnström, Bemporad & Axehill 2022), a dual active-set solver: exact solutions (to
round-off) on the small dense problems of one control step, warm-started from the previous step's active set
shifted by one period. Shapes for n joints, m actuated, horizon H, state S = 2n.
"""

import dataclasses

import numpy as np

from stdm_drake.errors import InputError

MODES = ("soft", "hard", "off")
MAX_PENALTY = 1e12          # a penalty weight beyond this swamps every other term of the cost
# the smallest: a weight of 1e-320 (0 in all but name) switches the soft limits off, which mode: off says openly
MIN_PENALTY = 1e-12
ACTIVE_TOLERANCE = 1e-9     # a torque within this of its bound (N m), a state row within it (rad, rad/s): active
SLACK_TOLERANCE = 1e-7      # slack beyond this (rad, rad/s) counts as used
MAX_ROUNDS = 20             # constraint-generation rounds of one QP (rows are only added: it ends far sooner)
SENSE_ACTIVE, SENSE_LOWER = 1, 2   # DAQP's constraint flags: active in the warm start, at its lower bound
INFINITE = 1e30             # DAQP's bound beyond which a side is none
MAX_QP_ITERATIONS = 300     # DAQP's active-set changes per control step over all its rounds: beyond, the step
                            # keeps the torque box alone (bounded work where a model's predictions leave every limit)


@dataclasses.dataclass
class Constraints:
    """How the MPC keeps the robot's limits (YAML `constraints: {mode, position_margin, velocity_margin,
    penalty_weight}`; module docstring): mode "soft" (the default: torque box hard, state limits soft), "hard"
    (state limits hard in the real-time iteration's QP, slack only where they cannot be met; the iLQR and the
    samplers price crossings the same way in both modes) or "off" (torques clipped after an unconstrained
    step, state limits ignored); the margins (rad, rad/s) inside the plant's position and velocity limits;
    penalty_weight: the exact penalty's weight per rad (rad/s) of slack and node (and of half its square)."""
    # (a bare `off` loads as written: `yaml_values.boolean_words_as_text` reads the choices; YAML 1.1's other
    # boolean words, `No`, `false`, `Off`, stay booleans and are refused: held-out run 36 found them run as "off")
    mode: str = dataclasses.field(default="soft", metadata=dict(choices=MODES))
    position_margin: float = 0.02
    velocity_margin: float = 0.05
    penalty_weight: float = 1e5

    def validate(self) -> None:
        """InputError (one line) for settings no optimizer can use: an unknown mode, margins negative or not
        finite, a penalty weight not in [MIN_PENALTY, MAX_PENALTY]."""
        if isinstance(self.mode, bool) or self.mode not in MODES:
            raise InputError(f"mpc constraints mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        for name in ("position_margin", "velocity_margin"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (np.isfinite(value) and value >= 0):
                raise InputError(f"mpc constraints {name} must be a number >= 0, got {value!r}")
        weight = self.penalty_weight
        if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not (
                np.isfinite(weight) and MIN_PENALTY <= weight <= MAX_PENALTY):
            raise InputError(f"mpc constraints penalty_weight must be in [{MIN_PENALTY:g}, {MAX_PENALTY:g}], got {weight!r}")

    def check_used(self, path, optimizer, hard_capable: bool) -> None:
        """InputError (one line) where the MPC settings file at `path` sets what its `optimizer` (hard_capable: the
        real-time iteration) would not use: mode hard with an optimizer that runs it as soft, or a margin or the
        penalty weight with mode off (held-out run 28)."""
        from stdm_drake.config import read_yaml_document   # lazy: pydrake
        given = (read_yaml_document(path) or {}).get("constraints")
        ignored = sorted((set(given) if isinstance(given, dict) else set())
                         & {"position_margin", "velocity_margin", "penalty_weight"})
        if self.mode == "hard" and not hard_capable:
            raise InputError(f"{path}: constraints mode hard makes the real-time iteration's state limits hard; "
                             f"!{type(optimizer).__name__} prices crossings the same way in both modes, so it would "
                             "run as soft: write mode: soft")
        if self.mode == "off" and ignored:
            raise InputError(f"{path}: constraints mode off leaves the state limits out of the optimizer, so its "
                             f"{', '.join(ignored)} would be ignored; leave them out, or use mode soft or hard")

    def bounds(self, position_lower, position_upper, velocity, names=None) -> "StateBounds | None":
        """The state bounds of these settings for a robot's limits: position_lower/upper (n,) rad, velocity (n,)
        rad/s (inf or -inf: none); None with mode off. InputError where a margin leaves a joint no room (its
        bounds would cross), naming the joint (`names`, else its index)."""
        self.validate()
        if self.mode == "off":
            return None
        limits_lower = np.concatenate([np.asarray(position_lower, dtype=float), -np.asarray(velocity, dtype=float)])
        limits_upper = np.concatenate([np.asarray(position_upper, dtype=float), np.asarray(velocity, dtype=float)])
        joints = len(limits_lower) // 2
        margins = np.repeat([self.position_margin, self.velocity_margin], joints)
        lower, upper = limits_lower + margins, limits_upper - margins
        for index in np.flatnonzero(~(lower < upper)):
            joint = index % joints
            name = repr(names[joint]) if names is not None else str(joint)
            what, margin = (("position", "position_margin") if index < joints else ("velocity", "velocity_margin"))
            raise InputError(f"mpc constraints {margin} leaves joint {name} no room inside its {what} limits "
                             f"[{limits_lower[index]:.4g}, {limits_upper[index]:.4g}] ({getattr(self, margin):g} on "
                             "each side); use a smaller margin")
        return StateBounds(lower=lower, upper=upper, hard=self.mode == "hard", penalty_weight=float(self.penalty_weight))


@dataclasses.dataclass(frozen=True)
class StateBounds:
    """Bounds on every predicted state x_1..x_H: lower, upper (S,) = [q rad, v rad/s] (-inf, inf: none), hard
    (module docstring: slack only where the hard QP is infeasible), penalty_weight of the slack."""
    lower: np.ndarray
    upper: np.ndarray
    hard: bool
    penalty_weight: float

    def violation(self, x: np.ndarray) -> np.ndarray:
        """How far states x (..., S) lie outside the bounds (..., S), >= 0 (rad, rad/s)."""
        return np.maximum(x - self.upper, 0.0) + np.maximum(self.lower - x, 0.0)

    def penalty(self, x: np.ndarray) -> float:
        """The exact penalty of states x (H, S): penalty_weight sum (s + s^2 / 2) over the slack s they need."""
        slack = self.violation(x)
        return float(self.penalty_weight * (slack.sum() + 0.5 * (slack ** 2).sum()))

    def penalty_derivatives(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gradient (H, S) and the diagonal of the Hessian (H, S) of `penalty` at states x (H, S): penalty_weight
        (1 + s) times the side's sign, and penalty_weight, where a bound is crossed by s (0 elsewhere). The penalty
        has a kink at the bound, which a Newton model does not see: the iLQR's line search keeps its steps where the
        cost falls (on a linear arm it reaches the constrained optimum to 3e-4 of the effort limit with a moderate
        penalty weight, tests/test_constraints.py; with a large one it may stop short of it at the kink; the
        real-time iteration's QP treats the slack exactly)."""
        above, below = x > self.upper, x < self.lower
        slack = self.violation(x)
        gradient = self.penalty_weight * (1.0 + slack) * (above.astype(float) - below.astype(float))
        return gradient, self.penalty_weight * (above | below).astype(float)


def limits_status(bounds: "StateBounds", x: np.ndarray, u: np.ndarray, effort_limit: np.ndarray) -> tuple[bool, float]:
    """How a solution meets the limits: (a torque at its effort limit or a state at or beyond its bound, the largest
    crossing it accepts, rad or rad/s) for predicted states x (H, S) and torques u (H, m)."""
    slack = float(bounds.violation(x).max(initial=0.0))
    near = (x >= bounds.upper - ACTIVE_TOLERANCE) | (x <= bounds.lower + ACTIVE_TOLERANCE)
    return bool(np.any(np.abs(u) >= effort_limit - ACTIVE_TOLERANCE) or np.any(near)), slack


@dataclasses.dataclass
class QpSolution:
    """delta (N,): the step; active: any bound of the box or any state row active at it; slack: the largest
    slack used (rad or rad/s; 0: every state row met)."""
    delta: np.ndarray
    active: bool
    slack: float


def _daqp(hessian, gradient, rows, upper, lower, sense, iterations: int = MAX_QP_ITERATIONS):
    """DAQP on min 1/2 x^T hessian x + gradient^T x, lower <= [x; rows x] <= upper (the first len(x) bounds simple),
    solved in Jacobi-scaled variables y = x sqrt(hessian_ii) (the torque steps and the slacks differ in curvature by
    up to 1e10; scaled, DAQP takes 5-10x fewer iterations on such steps); at most `iterations` iterations.
    (x, DAQP's exit flag: 1 optimal, -1 infeasible, -4 iteration limit, ...; the iterations it took)."""
    import daqp
    scale = 1.0 / np.sqrt(np.diag(hessian))
    count = len(gradient)
    scaled_upper, scaled_lower = np.array(upper, dtype=float), np.array(lower, dtype=float)
    scaled_upper[:count] = np.where(np.abs(upper[:count]) >= INFINITE, upper[:count], upper[:count] / scale)
    scaled_lower[:count] = np.where(np.abs(lower[:count]) >= INFINITE, lower[:count], lower[:count] / scale)
    y, _, exitflag, info = daqp.solve(hessian * scale[:, None] * scale[None], gradient * scale,
                                   np.ascontiguousarray(rows * scale[None]), scaled_upper, scaled_lower, sense,
                                   iter_limit=max(int(iterations), 1))
    return np.asarray(y, dtype=float) * scale, int(exitflag), int(info["iterations"])


def box_qp(hessian: np.ndarray, gradient: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """min 1/2 d^T hessian d + gradient^T d over lower <= d <= upper (N,), hessian (N, N) positive definite:
    (d (N,), clamped (N,) bool: the bounds active at d). ArithmeticError if DAQP finds no solution."""
    count = len(gradient)
    d, exitflag, _ = _daqp(np.ascontiguousarray(hessian), np.asarray(gradient, dtype=float), np.zeros((0, count)),
                           np.asarray(upper, dtype=float), np.asarray(lower, dtype=float), np.zeros(count, dtype=np.intc))
    if exitflag < 1:
        raise ArithmeticError(f"box QP not solved (DAQP exit flag {exitflag})")
    tolerance = ACTIVE_TOLERANCE * np.maximum(1.0, np.maximum(np.abs(lower), np.abs(upper)))   # (round-off of the scaling)
    clamped = (d <= lower + tolerance) | (d >= upper - tolerance)
    return d, clamped


class CondensedQp:
    """The real-time iteration's constrained Gauss-Newton step over torque steps δ (N = H m,):

        min 1/2 δ^T P δ + g^T δ + 1/2 penalty_weight sum_i (s_i + s_i^2 / 2)
        s.t. lower_u <= δ <= upper_u,   lower_i - s_i <= c_i + G_i δ <= upper_i + s_i,   s_i >= 0,

    G (H S, N) the states' response to δ and c (H S,) the states at δ = 0 (the linear prediction); P and g are
    those of half the MPC's cost (its Gauss-Newton form), so the penalty enters at half its weight. Only the state
    rows in a working set enter (with their slacks): the rows that cross their bounds at the solution are added and
    the QP solved again, until none does (each round only adds rows, so the last solution is the whole problem's).
    The working set and the active torque bounds of a solve warm-start the next control step's, shifted by one
    node. With `bounds.hard` the rows first enter without slack; a step whose hard QP is infeasible is solved soft."""

    def __init__(self, bounds: "StateBounds", joints: int):
        self.bounds, self.joints = bounds, joints
        self.state_dim = len(bounds.lower)
        self._rows = np.zeros(0, dtype=int)      # working set of state rows (index into the H S stacked states)
        self._budget = MAX_QP_ITERATIONS         # DAQP's iterations left to the current control step
        self._active = None                      # DAQP flags of the torque bounds at the last solution (N,)

    def solve(self, hessian: np.ndarray, gradient: np.ndarray, lower: np.ndarray, upper: np.ndarray,
              response: np.ndarray, prediction: np.ndarray) -> QpSolution:
        """hessian (N, N) positive definite, gradient (N,); lower, upper (N,) the torque steps' bounds; response
        G (H S, N); prediction c (H S,). ArithmeticError where DAQP finds no solution."""
        lower_rows = np.tile(self.bounds.lower, len(prediction) // self.state_dim)
        upper_rows = np.tile(self.bounds.upper, len(prediction) // self.state_dim)
        rows = self._warm_rows(len(prediction))
        hard = self.bounds.hard
        self._budget = MAX_QP_ITERATIONS          # DAQP's iterations left to this control step's rounds
        for _ in range(MAX_ROUNDS):
            try:
                delta, slack, active = self._solve_rows(hessian, gradient, lower, upper, response, prediction,
                                                        lower_rows, upper_rows, rows, hard)
            except ArithmeticError:
                if not len(rows):
                    raise
                return self._box_only(hessian, gradient, lower, upper, response, prediction, lower_rows, upper_rows)
            if delta is None:                    # the hard rows cannot be met: the soft problem
                hard = False
                continue
            states = prediction + response @ delta
            crossed = np.flatnonzero((states > upper_rows + ACTIVE_TOLERANCE) | (states < lower_rows - ACTIVE_TOLERANCE))
            crossed = np.setdiff1d(crossed, rows)
            if not len(crossed):
                break
            rows = np.union1d(rows, crossed)
        else:   # (rows only ever added: not reached in practice; bounded work all the same)
            return self._box_only(hessian, gradient, lower, upper, response, prediction, lower_rows, upper_rows)
        near = (states > upper_rows - ACTIVE_TOLERANCE) | (states < lower_rows + ACTIVE_TOLERANCE)
        self._rows = np.flatnonzero(near)
        self._active = active
        return QpSolution(delta, bool(np.any(active) or np.any(near)), slack)

    def _box_only(self, hessian, gradient, lower, upper, response, prediction, lower_rows, upper_rows) -> QpSolution:
        """The step of a QP whose state rows DAQP cannot settle within MAX_QP_ITERATIONS (over the step's rounds) or
        MAX_ROUNDS (a prediction far outside every limit, e.g. an untrained model's): the torque box alone, the
        crossings it leaves reported as slack."""
        self._budget = MAX_QP_ITERATIONS          # (the box's own QP: a budget of its own)
        delta, _, active = self._solve_rows(hessian, gradient, lower, upper, response, prediction, lower_rows,
                                            upper_rows, np.zeros(0, dtype=int), False)
        states = prediction + response @ delta
        slack = float(self.bounds.violation(states.reshape(-1, self.state_dim)).max(initial=0.0))
        self._rows, self._active = np.zeros(0, dtype=int), active
        return QpSolution(delta, True, slack)

    def forget(self) -> None:
        """No warm start for the next solve (a step whose unconstrained solution kept every limit)."""
        self._rows, self._active = np.zeros(0, dtype=int), None

    def _warm_rows(self, total: int) -> np.ndarray:
        """The last working set shifted by one node (its first node's rows dropped, the last node's kept)."""
        rows = self._rows[self._rows < total]          # (a solve over a shorter horizon keeps what it has)
        shifted = rows - self.state_dim
        last = rows[rows >= total - self.state_dim]
        return np.union1d(shifted[shifted >= 0], last).astype(int)

    def _solve_rows(self, hessian, gradient, lower, upper, response, prediction, lower_rows, upper_rows, rows, hard):
        """(δ, slack used, DAQP flags of the torque bounds) of the QP with the state rows `rows`; δ None where the
        hard QP is infeasible."""
        count, chosen = len(gradient), len(rows)
        G, c = response[rows], prediction[rows]
        row_lower, row_upper = lower_rows[rows] - c, upper_rows[rows] - c
        sense_box = np.zeros(count, dtype=np.intc)
        if self._active is not None and len(self._active) == count:
            sense_box[:-self.joints] = self._active[self.joints:]     # the previous solution, one node on
        if hard or chosen == 0:
            sense = np.concatenate([sense_box, np.zeros(chosen, dtype=np.intc)])
            delta, exitflag, used = _daqp(hessian, gradient, np.ascontiguousarray(G),
                                          np.concatenate([upper, np.minimum(row_upper, INFINITE)]),
                                          np.concatenate([lower, np.maximum(row_lower, -INFINITE)]), sense, self._budget)
            self._budget -= used
            if exitflag < 1:
                if hard and chosen:     # infeasible (-1), or no answer within the iterations: the soft problem
                    return None, 0.0, None
                raise ArithmeticError(f"constrained QP not solved (DAQP exit flag {exitflag})")
            return delta, 0.0, self._flags(delta, lower, upper)
        # the soft rows: variables [δ, s]; rows G δ - s <= upper - c and G δ + s >= lower - c
        weight = 0.5 * self.bounds.penalty_weight      # (the QP is half the MPC's cost)
        full = np.zeros((count + chosen, count + chosen))
        full[:count, :count] = hessian
        full[count:, count:] = weight * np.eye(chosen)
        linear = np.concatenate([gradient, np.full(chosen, weight)])
        matrix = np.zeros((2 * chosen, count + chosen))
        matrix[:chosen, :count], matrix[chosen:, :count] = G, G
        matrix[:chosen, count:], matrix[chosen:, count:] = -np.eye(chosen), np.eye(chosen)
        none = np.full(chosen, INFINITE)
        row_upper_all = np.concatenate([np.minimum(row_upper, INFINITE), none])      # G δ - s <= upper - c
        row_lower_all = np.concatenate([-none, np.maximum(row_lower, -INFINITE)])    # G δ + s >= lower - c
        sense = np.concatenate([sense_box, np.zeros(3 * chosen, dtype=np.intc)])
        solution, exitflag, used = _daqp(full, linear, matrix, np.concatenate([upper, none, row_upper_all]),
                                         np.concatenate([lower, np.zeros(chosen), row_lower_all]), sense, self._budget)
        self._budget -= used
        if exitflag < 1:
            raise ArithmeticError(f"constrained QP not solved (DAQP exit flag {exitflag})")
        delta, slack = solution[:count], solution[count:]
        return delta, float(max(slack.max(initial=0.0), 0.0)), self._flags(delta, lower, upper)

    @staticmethod
    def _flags(delta, lower, upper) -> np.ndarray:
        """DAQP's warm-start flags of the torque bounds active at δ: active (upper), active and lower."""
        flags = np.zeros(len(delta), dtype=np.intc)
        flags[delta >= upper - ACTIVE_TOLERANCE] = SENSE_ACTIVE
        flags[delta <= lower + ACTIVE_TOLERANCE] = SENSE_ACTIVE | SENSE_LOWER
        return flags
