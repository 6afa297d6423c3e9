"""The project's simulated datasets written as a real robot's recorders write their logs: UR RTDE CSV files and
ROS 2 bags (sqlite3 or MCAP, written with `rosbags`). They are what the import's tests and benchmark read.

A log samples each trajectory at its dataset's instants t_k = k h, each moved by timing jitter (a normal deviation
of `jitter` s, clipped at 3 of them): the values are those at the jittered instant, the motion between samples
taken as the quintic Hermite interpolant of the simulation's true q, q̇ and q̈ (q̈ just after t_k and just before
t_k+1: the held torque steps at samples), plus the sample's own measurement error of the dataset's sensor model
(q - q_true, v - v_true). A fraction `drop` of the rows (never two in a row, never a trajectory's first or last)
is left out; trajectories follow each other after `pause` s without rows. Torques are the held commands;
the plan (tracking data) is the cubic Hermite interpolant of the planned (q, q̇) and (q̇, q̈)."""
import dataclasses
import pathlib

import numpy as np

from stdm_drake.data.logs.resample import hermite3
from stdm_drake.errors import InputError
from stdm_drake.data.logs.ros2 import CONTROLLER_STATE, CONTROLLER_STATE_DEFINITION, JOINT_STATE, typestore

JOINT_STATE_RATE_DIVIDER = 5      # bags: a controller-state message every this many joint states (and at the end)
LOG_CLOCK_START = 1234.5          # s: the RTDE controller's time at the first row
BAG_CLOCK_SECONDS = 1_700_000_000   # s: the bag's stamps are a wall clock's (added to the log's times as whole seconds)
EXTRA_JOINT = "gripper_finger_joint"   # a joint state the robot does not have (the import ignores it)
# RTDE torque constants (N m / A) of the simulated log's actual_current_* (illustrative values of the right size)
TORQUE_CONSTANTS = (13.0, 13.0, 13.0, 9.0, 9.0, 9.0)


def torque_constants(joints: int) -> np.ndarray:
    """(joints,) N m / A: the simulated logs' torque constants (TORQUE_CONSTANTS, or 10 for every joint of an arm
    with more joints than it names)."""
    return np.asarray(TORQUE_CONSTANTS[:joints] if joints <= len(TORQUE_CONSTANTS) else [10.0] * joints)


@dataclasses.dataclass
class LogTiming:
    """Where a log's rows fall: per trajectory, its log time at sample 0 (s) and the kept samples' indices and
    their jittered log times (s)."""
    starts: list
    samples: list
    times: list


def log_timing(dataset, jitter: float = 1.5e-4, drop: float = 0.01, pause: float = 1.0, seed: int = 0,
               clock_start: float = LOG_CLOCK_START) -> LogTiming:
    """The rows of a log of `dataset`: the same seed gives the same jitter and drops."""
    rng = np.random.default_rng(seed)
    h = dataset.sample_period
    if not 0 <= jitter < h / 6:
        raise InputError(f"jitter must be in [0, {h / 6:g}) s (3 deviations inside half a sample period), got {jitter}")
    starts, samples, times, start = [], [], [], clock_start
    for index in range(dataset.num_trajectories):
        count = dataset.trajectory(index).num_steps + 1
        keep = np.ones(count, bool)
        dropped = rng.random(count) < drop
        dropped[[0, -1]] = False
        for k in np.flatnonzero(dropped):
            if keep[k - 1]:
                keep[k] = False
        offsets = np.clip(rng.normal(0.0, jitter, count), -3 * jitter, 3 * jitter) if jitter > 0 else np.zeros(count)
        kept = np.flatnonzero(keep)
        starts.append(start)
        samples.append(kept)
        times.append(start + kept * h + offsets[kept])
        start += (count - 1) * h + pause
    return LogTiming(starts, samples, times)


def _hermite5(s, span, y0, d0, a0, y1, d1, a1):
    """The quintic Hermite interpolant at s in [0, 1] of an interval of length `span` (values, first and second
    derivatives at both ends)."""
    s2, s3, s4, s5 = s**2, s**3, s**4, s**5
    h0, h1, h2 = 1 - 10 * s3 + 15 * s4 - 6 * s5, s - 6 * s3 + 8 * s4 - 3 * s5, 0.5 * (s2 - 3 * s3 + 3 * s4 - s5)
    g0, g1, g2 = 10 * s3 - 15 * s4 + 6 * s5, -4 * s3 + 7 * s4 - 3 * s5, 0.5 * (s3 - 2 * s4 + s5)
    return h0 * y0 + h1 * span * d0 + h2 * span**2 * a0 + g0 * y1 + g1 * span * d1 + g2 * span**2 * a1


def true_state_at(trajectory, h: float, times: np.ndarray) -> tuple:
    """(q, v) (len(times), n) of a simulated trajectory's true motion at `times` (s from its sample 0, inside
    [0, T h]): the quintic Hermite interpolant of (q_true, v_true, q̈) for q, the cubic one of (v_true, q̈) for v."""
    steps = trajectory.num_steps
    k = np.clip(np.floor(times / h).astype(int), 0, steps - 1)
    s = ((times - k * h) / h)[:, None]
    q0, q1, v0, v1 = trajectory.q_true[k], trajectory.q_true[k + 1], trajectory.v_true[k], trajectory.v_true[k + 1]
    a0, a1 = trajectory.qdd[k], trajectory.qdd_end[k]
    return _hermite5(s, h, q0, v0, a0, q1, v1, a1), hermite3(s, h, v0, a0, v1, a1)


def planned_at(trajectory, h: float, times: np.ndarray) -> tuple:
    """(q_d, v_d, a_d) of a trajectory's plan at `times` (s from sample 0): cubic Hermite, a_d linear."""
    steps = trajectory.num_steps
    k = np.clip(np.floor(times / h).astype(int), 0, steps - 1)
    s = ((times - k * h) / h)[:, None]
    p, v, a = trajectory.q_planned, trajectory.v_planned, trajectory.qdd_planned
    return (hermite3(s, h, p[k], v[k], p[k + 1], v[k + 1]), hermite3(s, h, v[k], a[k], v[k + 1], a[k + 1]),
            a[k] + s * (a[k + 1] - a[k]))


def logged_values(dataset, index: int, timing: LogTiming) -> dict:
    """The log's rows of trajectory `index`: t (N,) log time, q, v (N, n) measured, tau (N, m) held, and the
    plan (N, n) where the dataset has one."""
    trajectory, h = dataset.trajectory(index), dataset.sample_period
    kept, times = timing.samples[index], timing.times[index]
    local = times - timing.starts[index]
    q, v = true_state_at(trajectory, h, np.clip(local, 0.0, trajectory.num_steps * h))
    q += (trajectory.q - trajectory.q_true)[kept]
    v += (trajectory.v - trajectory.v_true)[kept]
    torques = np.vstack([trajectory.tau, trajectory.tau_next[None]])
    values = dict(t=times, q=q, v=v, tau=torques[kept])
    if trajectory.has_plan:
        values["q_planned"], values["v_planned"], values["qdd_planned"] = planned_at(
            trajectory, h, np.clip(local, 0.0, trajectory.num_steps * h))
    return values


def write_rtde_csv(dataset, path, *, delimiter: str = " ", timing: LogTiming | None = None,
                   torque: str = "target_moment") -> pathlib.Path:
    """The dataset as an RTDE recording (space delimited as the RTDE client's recorder writes it, or "," as
    ur_rtde's): timestamp, target_q/qd/qdd (tracking data), target_moment, actual_q, actual_qd,
    actual_current (the torque over TORQUE_CONSTANTS), robot_mode, safety_mode, runtime_state (running)."""
    if not dataset.is_simulated:
        raise InputError("a simulated log needs simulated data (its true motion)")
    timing = timing or log_timing(dataset)
    n = dataset.trajectory(0).q.shape[1]
    constants = torque_constants(n)
    names = ["timestamp"]
    if dataset.has_plan:
        names += [f"{field}_{j}" for field in ("target_q", "target_qd", "target_qdd") for j in range(n)]
    names += [f"{field}_{j}" for field in ("target_moment", "actual_q", "actual_qd", "actual_current") for j in range(n)]
    names += ["robot_mode", "safety_mode", "runtime_state"]
    path = pathlib.Path(path)
    with open(path, "w", encoding="utf-8") as file:
        file.write(delimiter.join(names) + "\n")
        for index in range(dataset.num_trajectories):
            values = logged_values(dataset, index, timing)
            parts = [values["t"][:, None]]
            if dataset.has_plan:
                parts += [values["q_planned"], values["v_planned"], values["qdd_planned"]]
            parts += [values["tau"], values["q"], values["v"], values["tau"] / constants,
                      np.tile([7.0, 1.0, 2.0], (len(values["t"]), 1))]
            block = np.hstack(parts)
            for row in block:
                file.write(delimiter.join(map(repr, row[:-3].tolist())) + delimiter
                           + delimiter.join(str(int(code)) for code in row[-3:]) + "\n")
    return path


def write_ros2_bag(dataset, path, joint_names: list, *, storage: str = "sqlite3", timing: LogTiming | None = None,
                   controller_state: bool = True, topic: str = "/joint_states",
                   controller_topic: str = "/joint_trajectory_controller/controller_state",
                   effort_as_current: bool = False, reference_accelerations: bool = True) -> pathlib.Path:
    """The dataset as a ROS 2 bag (folder `path`, storage "sqlite3" or "mcap"): JointState messages (the robot's
    joints in `joint_names`, then EXTRA_JOINT, which the robot does not have) stamped at the log's times and, for
    tracking data with `controller_state`, JointTrajectoryControllerState messages every
    JOINT_STATE_RATE_DIVIDER rows and at each trajectory's last row (the plan as `reference`).
    effort_as_current: effort holds the torque over TORQUE_CONSTANTS (A), as UR's ROS 2 driver reports it;
    reference_accelerations False: the reference carries no accelerations (a controller without an acceleration
    interface, as UR's scaled trajectory controller)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    if not dataset.is_simulated:
        raise InputError("a simulated log needs simulated data (its true motion)")
    timing = timing or log_timing(dataset, clock_start=0.5)
    store = typestore()
    types = store.types
    Header, Time = types["std_msgs/msg/Header"], types["builtin_interfaces/msg/Time"]
    JointState, Point = types[JOINT_STATE], types["trajectory_msgs/msg/JointTrajectoryPoint"]
    MultiPoint, ControllerState = types["trajectory_msgs/msg/MultiDOFJointTrajectoryPoint"], types[CONTROLLER_STATE]
    Duration = types["builtin_interfaces/msg/Duration"]
    names = list(joint_names) + [EXTRA_JOINT]
    n = len(joint_names)
    constants = torque_constants(n)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    empty = np.zeros(0)

    def point(q=empty, v=empty, a=empty):
        return Point(positions=np.asarray(q, float), velocities=np.asarray(v, float), accelerations=np.asarray(a, float),
                     effort=empty, time_from_start=Duration(sec=0, nanosec=0))

    def stamp(t: float):   # the log's time t (s, from 0) on the wall clock, to the nanosecond
        nanoseconds = int(round(t * 1e9))
        return Time(sec=BAG_CLOCK_SECONDS + nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)

    empty_multi = MultiPoint(transforms=[], velocities=[], accelerations=[], time_from_start=Duration(sec=0, nanosec=0))
    with Writer(pathlib.Path(path), version=9, storage_plugin=plugin) as writer:
        states = writer.add_connection(topic, JOINT_STATE, typestore=store)
        control = None
        if controller_state and dataset.has_plan:
            control = writer.add_connection(controller_topic, CONTROLLER_STATE, typestore=store,
                                            msgdef=CONTROLLER_STATE_DEFINITION, rihs01=store.hash_rihs01(CONTROLLER_STATE))
        for index in range(dataset.num_trajectories):
            values = logged_values(dataset, index, timing)
            count = len(values["t"])
            for row in range(count):
                header = Header(stamp=stamp(values["t"][row]), frame_id="")
                extra = np.zeros(1)
                effort = values["tau"][row] / constants if effort_as_current else values["tau"][row]
                message = JointState(header=header, name=names, position=np.concatenate([values["q"][row], extra]),
                                     velocity=np.concatenate([values["v"][row], extra]),
                                     effort=np.concatenate([effort, extra]))
                received = (BAG_CLOCK_SECONDS + values["t"][row]) * 1e9 // 1 + 200_000   # (received 0.2 ms after its stamp)
                received = int(received)
                writer.write(states, received, store.serialize_cdr(message, JOINT_STATE))
                if control is not None and (row % JOINT_STATE_RATE_DIVIDER == 0 or row == count - 1):
                    reference = point(values["q_planned"][row], values["v_planned"][row],
                                      values["qdd_planned"][row] if reference_accelerations else empty)
                    feedback = point(values["q"][row], values["v"][row])
                    state = ControllerState(header=header, joint_names=list(joint_names), reference=reference,
                                            feedback=feedback, error=point(), output=point(), desired=reference,
                                            actual=feedback, multi_dof_joint_names=[], multi_dof_reference=empty_multi,
                                            multi_dof_feedback=empty_multi, multi_dof_error=empty_multi,
                                            multi_dof_output=empty_multi, multi_dof_desired=empty_multi,
                                            multi_dof_actual=empty_multi)
                    writer.write(control, received + 1000, store.serialize_cdr(state, CONTROLLER_STATE))
    return pathlib.Path(path)
