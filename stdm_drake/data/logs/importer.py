"""`import_log`: a real robot's log (RTDE CSV or ROS 2 bag) as a dataset of protocol "logged".

Rows stream in blocks from the log's reader; `Pieces` cuts them into pieces at gaps, pauses, mode changes and
the longest duration; each piece is resampled onto the sample period (`resample`), checked against the robot
and written at once (`DatasetWriter`): memory holds one block and one piece. Nothing is written unless the
whole log imports (the writer's temporary file is removed on any error)."""
import dataclasses
import itertools
import pathlib

import numpy as np

from stdm_drake.data.writer import DatasetWriter, package_versions
from stdm_drake.data.logs import resample as resampling, rtde, ros2
from stdm_drake.data.logs.mapping import LogMapping
from stdm_drake.data.logs.rows import Rows
from stdm_drake.errors import InputError
from stdm_drake.data.logs.rtde import looks_like_rtde
from stdm_drake.robots.plant import robot_joint_limits
from stdm_drake.data.dataset import file_sha256

POSITION_MARGIN = 0.02      # of each joint's range: logged angles beyond the limits by more are not this robot's
LIMIT_FACTOR = 1.5          # logged velocities and torques beyond this times the limits are not in SI units
VELOCITY_RATIO = (0.5, 2.0)  # RMS of the logged q̇ over RMS of the angles' own rate of change


def detect_format(path, given: str = "") -> str:
    """"ros2_bag" (a bag folder with metadata.yaml, or a .db3 / .mcap file) or "rtde_csv" (a text file whose
    header names RTDE fields); `given` (the mapping's or --format) wins."""
    path = pathlib.Path(path)
    if given:
        return given
    if path.is_dir() or path.suffix in (".db3", ".mcap"):
        return "ros2_bag"
    if looks_like_rtde(path):
        return "rtde_csv"
    raise InputError(f"{path}: not a log this import reads (an RTDE CSV with a header of field names, or a ROS 2 "
                     "bag folder, .db3 or .mcap); say which with --format")


def log_rows(path, robot, mapping: LogMapping):
    """The log's rows as `Rows` blocks in the robot's joint order, torques in N m (logged currents times the
    mapping's torque constants with torque_source current)."""
    constants = None
    if mapping.torque_source == "current":
        constants = np.asarray(mapping.torque_constants, dtype=float)
        if constants.shape != (robot.num_joints,):
            raise InputError(f"torque_constants has {len(constants)} values, the robot has {robot.num_joints} joints")
    if mapping.format == "rtde_csv":
        blocks = rtde.rows(path, robot.num_joints, mapping)
    else:
        blocks = ros2.rows(path, robot, mapping)
    for block in blocks:
        if constants is not None:
            block.tau = block.tau * constants
        yield block


@dataclasses.dataclass
class Counts:
    """How the rows became trajectories (the metadata's import.trajectories)."""
    rows: int = 0
    rows_not_running: int = 0
    gaps: int = 0
    mode_changes: int = 0
    pauses: int = 0
    cuts: int = 0
    kept: int = 0
    dropped_short: int = 0


class Pieces:
    """Cuts a stream of rows into pieces: at a gap (consecutive rows more than gap_factor x h apart), at a mode
    change (the mode code differs, or rows not running lie between), around a pause (every joint slower than
    pause_velocity for pause_duration or longer: its rows are left out) and after max_duration (the next piece
    starts at the last row of the cut one). `feed(block)` returns the pieces it closes; `finish()` the last.
    Holds at most one piece's rows (and, inside a pause, none)."""

    def __init__(self, mapping: LogMapping, sample_period: float, counts: Counts):
        self.mapping, self.h, self.counts = mapping, sample_period, counts
        self.parts: list[Rows] = []       # the open piece's rows, its trailing rest rows included
        self.rest_since = None            # stamp where the trailing rest run began (None: moving)
        self.in_pause = False             # the trailing rest run is a pause: its rows are left out
        self.last = None                  # the last kept row (stamp, mode) and whether rows not running followed it
        self.closed: list[Rows] = []

    def feed(self, block: Rows) -> list[Rows]:
        self.counts.rows += len(block)
        keep = np.ones(len(block), bool) if block.running is None else block.running
        self.counts.rows_not_running += int((~keep).sum())
        index = np.flatnonzero(keep)
        skipped_before = np.zeros(len(index), bool)   # rows not running between this kept row and the previous one
        if len(index):
            skipped_before[1:] = np.diff(index) > 1
            skipped_before[0] = index[0] > 0 or (self.last is not None and self.last[2])
        kept = block.take(index)
        trailing_skip = len(block) > 0 and not keep[-1]
        if not len(kept):
            if trailing_skip and self.last is not None:
                self.last = (self.last[0], self.last[1], True)
            return self._take_closed()
        previous_t = np.concatenate([[np.nan if self.last is None else self.last[0]], kept.t[:-1]])
        gap = (kept.t - previous_t) > min(self.mapping.gap_factor * self.h, self.mapping.max_duration)
        mode_change = skipped_before.copy()
        if kept.mode is not None:
            previous_mode = np.concatenate([[kept.mode[0] if self.last is None else self.last[1]], kept.mode[:-1]])
            mode_change |= kept.mode != previous_mode
        breaks = gap | mode_change
        if self.last is None:
            breaks[0] = False
        rest = np.all(np.abs(kept.v) < self.mapping.pause_velocity, axis=1)
        # runs of rows alike in rest state and not broken inside
        boundary = np.flatnonzero(breaks[1:] | (rest[1:] != rest[:-1])) + 1
        starts = np.concatenate([[0], boundary])
        stops = np.concatenate([boundary, [len(kept)]])
        for start, stop in zip(starts, stops):
            if breaks[start]:
                self.counts.mode_changes += int(mode_change[start])     # (rows not running leave a gap too)
                self.counts.gaps += int(gap[start] and not mode_change[start])
                self._close()
            run = kept.take(slice(start, stop))
            if rest[start]:
                self._rest(run)
            else:
                self._move(run)
        self.last = (float(kept.t[-1]), None if kept.mode is None else kept.mode[-1], bool(trailing_skip))
        return self._take_closed()

    def finish(self) -> list[Rows]:
        self._close()
        return self._take_closed()

    def _take_closed(self) -> list[Rows]:
        closed, self.closed = self.closed, []
        return closed

    def _rest(self, run: Rows) -> None:
        if self.rest_since is None:
            self.rest_since = float(run.t[0])
        if self.in_pause:
            return
        self.parts.append(run)
        if run.t[-1] - self.rest_since >= self.mapping.pause_duration:   # a pause: what came before it is a piece
            self._emit(self._before(self.rest_since))
            self.parts, self.in_pause = [], True
            self.counts.pauses += 1

    def _move(self, run: Rows) -> None:
        self.in_pause = False
        self.rest_since = None
        self.parts.append(run)
        self._cut()

    def _cut(self) -> None:
        """Pieces of max_duration off the open piece's front while it is longer (the next starts at the last row
        of the one cut off)."""
        while self.parts and self.parts[-1].t[-1] - self.parts[0].t[0] > self.mapping.max_duration:
            rows = Rows.concatenate(self.parts)
            end = max(int(np.searchsorted(rows.t, rows.t[0] + self.mapping.max_duration, side="right")), 2)
            self._emit(rows.take(slice(0, end)))
            self.parts = [rows.take(slice(end - 1, None))]
            self.counts.cuts += 1

    def _before(self, stamp: float):
        rows = Rows.concatenate(self.parts) if self.parts else None
        return None if rows is None else rows.take(slice(0, int(np.searchsorted(rows.t, stamp))))

    def _close(self) -> None:
        if self.parts and not self.in_pause:
            rows = Rows.concatenate(self.parts)
            if self.rest_since is not None and rows.t[-1] - self.rest_since >= self.mapping.pause_duration:
                rows = self._before(self.rest_since)
            self.parts = [rows] if rows is not None and len(rows) else []
            self._cut()
            if self.parts:
                self._emit(Rows.concatenate(self.parts))
        self.parts, self.rest_since, self.in_pause = [], None, False

    def _emit(self, rows) -> None:
        if rows is not None and len(rows):
            self.closed.append(rows)


def sample_period_of(block: Rows, given: float) -> tuple[float, float]:
    """(the log's row period, the dataset's sample period) in s. The row period: the first block's elapsed time
    over its clock ticks (spacings within 3.5 median spacings, counted in ticks: jitter cancels along a run and
    dropped rows count twice), to the microsecond when that is within 1e-4 of it; the sample period `given`, or
    the row period."""
    steps = np.diff(block.t)
    steps = steps[steps > 0]
    if not len(steps):
        raise InputError("the log's first rows do not advance in time")
    base = float(np.median(steps))
    ticks = np.round(steps / base)
    inside = (ticks >= 1) & (ticks <= 3)
    period = float(steps[inside].sum() / ticks[inside].sum())
    rounded = round(period, 6)
    if rounded > 0 and abs(rounded - period) <= 1e-4 * period:
        period = rounded
    return period, (given or period)


def check_stamps(block: Rows, previous: float | None, source: str, place: str) -> None:
    """InputError naming the row where a stamp repeats or goes back."""
    t = block.t if previous is None else np.concatenate([[previous], block.t])
    steps = np.diff(t)
    bad = np.flatnonzero(steps <= 0)
    if len(bad):
        where = block.where[bad[0] + (1 if previous is None else 0)]   # (the row whose stamp does not increase)
        kind = "repeats" if steps[bad[0]] == 0 else "goes back in time"
        raise InputError(f"{source}: the timestamp at {place} {where} {kind} ({float(t[bad[0] + 1])!r} s after "
                         f"{float(t[bad[0]])!r} s); a log's stamps must increase")


class LimitCheck:
    """The robot's limits against a resampled trajectory (units: a log in degrees or mN m fails here), and the
    logged velocities against the angles' own rate of change over the whole log."""

    def __init__(self, robot, source: str, place: str):
        self.robot, self.source, self.place = robot, source, place
        self.limits = robot_joint_limits(robot)
        self.sums = np.zeros(3)   # sums of squares of the logged q̇ and the angles' rate, and their count

    def trajectory(self, trajectory, start_where) -> None:
        limits, names = self.limits, self.robot.joint_names
        span = limits.position_upper - limits.position_lower
        margin = np.where(np.isfinite(span), POSITION_MARGIN * span, 0.0)
        checks = (("angle", trajectory.q, limits.position_lower - margin, limits.position_upper + margin, "rad"),
                  ("velocity", trajectory.v, -LIMIT_FACTOR * limits.velocity, LIMIT_FACTOR * limits.velocity, "rad/s"),
                  ("torque", trajectory.tau, -LIMIT_FACTOR * limits.effort, LIMIT_FACTOR * limits.effort, "N m"))
        for what, values, low, high, unit in checks:
            outside = (values < low) | (values > high)
            if outside.any():
                step, joint = np.argwhere(outside)[0]
                hint = {"angle": "degrees instead of radians, or another robot's log?",
                        "velocity": "degrees per second?", "torque": "another unit, or wrong torque constants?"}[what]
                raise InputError(f"{self.source}: {names[joint]}'s {what} is {values[step, joint]:.4g} {unit} in the piece "
                                 f"starting at {self.place} {start_where}, beyond robot {self.robot.name}'s limits "
                                 f"({low[joint]:.4g}..{high[joint]:.4g}); {hint}")

    def rows(self, piece: Rows) -> None:
        rate = np.diff(piece.q, axis=0) / np.diff(piece.t)[:, None]
        self.sums += [float(np.sum((piece.v[1:] + piece.v[:-1]) ** 2 / 4)), float(np.sum(rate ** 2)), rate.size]

    def finish(self) -> float | None:
        """The RMS ratio logged q̇ / the angles' rate (None where the robot hardly moved), checked."""
        logged, derived, count = self.sums
        if derived < 1e-6 * max(count, 1):   # (RMS rate below 1 mrad/s: no motion to compare with)
            return None
        ratio = float(np.sqrt(logged / derived))
        if not VELOCITY_RATIO[0] <= ratio <= VELOCITY_RATIO[1]:
            raise InputError(f"{self.source}: the logged velocities are {ratio:.3g}x the angles' own rate of change "
                             f"(RMS); they should agree (units, or columns of another joint?)")
        return ratio


def import_log(path, robot, mapping: LogMapping, output, announce=None) -> dict:
    """Import the log at `path` of `robot` (a Robot) with `mapping` into the dataset file `output`; returns the
    metadata's "import" record. InputError (one line) for any problem; then nothing is written."""
    path = pathlib.Path(path)
    robot.check_fully_actuated("importing a log")
    mapping = mapping.with_format(detect_format(path, mapping.format))
    source = f"{'ROS 2 bag' if mapping.format == 'ros2_bag' else 'RTDE log'} {path}"
    place = "joint-state message" if mapping.format == "ros2_bag" else "line"
    blocks = log_rows(path, robot, mapping)
    first = next(blocks, None)
    if first is None or len(first) < 3:
        raise InputError(f"{source}: fewer than 3 rows")
    period, sample_period = sample_period_of(first, mapping.sample_period)
    if sample_period < period * (1 - 1e-6):
        raise InputError(f"sample period {sample_period:g} s is shorter than the log's row period {period:g} s: "
                         "resampling would invent samples")
    if mapping.max_duration < 10 * sample_period or mapping.max_duration <= mapping.gap_factor * period:
        raise InputError(f"max_duration {mapping.max_duration:g} s must be at least 10 sample periods "
                         f"({10 * sample_period:g} s) and longer than a gap (gap_factor x the log's period, "
                         f"{mapping.gap_factor * period:g} s)")
    counts = Counts()
    pieces = Pieces(mapping, period, counts)
    checks = LimitCheck(robot, source, place)
    sums = dict(loo=0.0, loo_count=0, jitter=0.0, jitter_count=0, longest=0.0)   # over the pieces written
    starts, spans = [], []
    metadata = dict(protocol="logged", sample_period=sample_period, seed=None, joint_names=list(robot.joint_names),
                    robot_model_sha256=robot.model_sha256(), robot=dataclasses.asdict(robot.config),
                    package_versions=package_versions("rosbags" if mapping.format == "ros2_bag" else "scipy"),
                    torque_hold="the mean of the logged commands over each sample period")
    previous = None
    with DatasetWriter(output, metadata) as writer:
        for block in itertools.chain([first], blocks):
            if not len(block):
                continue
            check_stamps(block, previous, source, place)
            previous = float(block.t[-1])
            for piece in pieces.feed(block):
                _write_piece(piece, writer, checks, mapping, period, sample_period, counts, sums, starts, spans)
        for piece in pieces.finish():
            _write_piece(piece, writer, checks, mapping, period, sample_period, counts, sums, starts, spans)
        if not writer.count:
            raise InputError(f"{source}: no piece of the log is {mapping.min_duration:g} s long and "
                             f"{mapping.smoothing_window} samples or more after splitting ({counts.rows} rows, "
                             f"{counts.gaps} gaps, {counts.pauses} pauses, {counts.mode_changes} mode changes)")
        ratio = checks.finish()
        leave_one_out = float(np.sqrt(sums["loo"] / max(sums["loo_count"], 1)))
        record = dict(
            format=mapping.format, source=str(path), source_sha256=None if path.is_dir() else file_sha256(path),
            mapping=dataclasses.asdict(mapping), torque_source=mapping.torque_source,
            derivatives=dict(planned=writer.has_plan, smoothed=f"Savitzky-Golay, cubic, window "
                             f"{mapping.smoothing_window} samples, of the resampled angles (v_smoothed, qdd_smoothed) and "
                             "velocities (qdd_measured)"),
            resampling=dict(method="angles: cubic Hermite of the logged (q, q̇) between the bracketing rows; velocities "
                                   "and planned accelerations: linear; planned angles and velocities: cubic Hermite; "
                                   "torque: the mean command over each period; grid: the log's clock",
                            log_period_s=period, jitter_rms_s=float(np.sqrt(sums["jitter"] / max(sums["jitter_count"], 1))),
                            longest_interval_s=sums["longest"],
                            leave_one_out_q_rms_rad=leave_one_out,
                            estimated_q_error_rad=leave_one_out / resampling.LEAVE_ONE_OUT_FACTOR),
            velocity_ratio=ratio, trajectories=dataclasses.asdict(counts), start_times_s=starts, rows_spanned=spans)
        writer.metadata["import"] = record
    if announce:
        announce(f"{counts.kept} trajectories from {counts.rows} rows")
    return record


def _write_piece(piece: Rows, writer, checks: LimitCheck, mapping, period, sample_period, counts: Counts, sums,
                 starts, spans) -> None:
    samples = resampling.grid_size(piece, period, sample_period) if len(piece) >= 2 else 0
    if piece.t[-1] - piece.t[0] < mapping.min_duration or samples < max(mapping.smoothing_window, 3):
        counts.dropped_short += 1
        return
    trajectory, origin = resampling.resample(piece, period, sample_period, mapping.smoothing_window)
    checks.trajectory(trajectory, int(piece.where[0]))
    checks.rows(piece)
    loo, count = resampling.leave_one_out_errors(piece)
    offsets = resampling.clock_offsets(piece.t, origin, period)
    sums.update(loo=sums["loo"] + loo, loo_count=sums["loo_count"] + count,
                jitter=sums["jitter"] + float(np.sum(offsets ** 2)), jitter_count=sums["jitter_count"] + len(offsets),
                longest=max(sums["longest"], float(np.diff(piece.t).max())))
    writer.add(trajectory, 0)
    counts.kept += 1
    starts.append(origin)
    spans.append([int(piece.where[0]), int(piece.where[-1])])
