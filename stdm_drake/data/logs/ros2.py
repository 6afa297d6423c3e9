"""ROS 2 bags (sqlite3 or MCAP storage; a bag folder with metadata.yaml, or one .db3 / .mcap file) read with
`rosbags` (pure Python, no ROS installation): `sensor_msgs/msg/JointState` on the mapping's joint-states topic
(stamp: header.stamp; position rad, velocity rad/s, effort N m, matched to the robot's arm joints by name, other
joints ignored; effort is a torque, or with torque_source current a motor current times the mapping's torque
constants: UR's ROS 2 driver reports currents there) and, when the bag has it, the plan from
`control_msgs/msg/JointTrajectoryControllerState` (the `reference` point, or `desired` from controllers before it
existed; its accelerations, which a controller without an acceleration interface leaves empty, else the
derivative of its velocities) interpolated to each joint state's stamp. Message definitions come from the bag
where it carries them (rosbag2 since Iron, MCAP), else from ROS 2 Humble's (control_msgs:
`CONTROLLER_STATE_DEFINITION`, its 4.x layout). Joint states stream in blocks; the controller state (published at
the controller's rate) is read first, whole. controller_state_topic "none": the plan is not read."""
import pathlib

import numpy as np
from scipy.interpolate import CubicHermiteSpline

from stdm_drake.data.logs.rows import Rows
from stdm_drake.errors import InputError

JOINT_STATE = "sensor_msgs/msg/JointState"
CONTROLLER_STATE = "control_msgs/msg/JointTrajectoryControllerState"
BLOCK_MESSAGES = 65536
# the message layout of control_msgs 4.x (ROS 2 Humble to Jazzy), without its comments
CONTROLLER_STATE_DEFINITION = """std_msgs/Header header
string[] joint_names
trajectory_msgs/JointTrajectoryPoint reference
trajectory_msgs/JointTrajectoryPoint feedback
trajectory_msgs/JointTrajectoryPoint error
trajectory_msgs/JointTrajectoryPoint output
trajectory_msgs/JointTrajectoryPoint desired
trajectory_msgs/JointTrajectoryPoint actual
string[] multi_dof_joint_names
trajectory_msgs/MultiDOFJointTrajectoryPoint multi_dof_reference
trajectory_msgs/MultiDOFJointTrajectoryPoint multi_dof_feedback
trajectory_msgs/MultiDOFJointTrajectoryPoint multi_dof_error
trajectory_msgs/MultiDOFJointTrajectoryPoint multi_dof_output
trajectory_msgs/MultiDOFJointTrajectoryPoint multi_dof_desired
trajectory_msgs/MultiDOFJointTrajectoryPoint multi_dof_actual
"""


def typestore(connection=None):
    """ROS 2 Humble's message types with a connection's own definition registered where the bag carries one, and
    control_msgs' controller state (4.x) where it does not."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    store = get_typestore(Stores.ROS2_HUMBLE)
    if connection is None or not _register_own(connection, store):
        store.register(get_types_from_msg(CONTROLLER_STATE_DEFINITION, CONTROLLER_STATE))
    return store


class BagError(InputError):
    """A bag that does not read (truncated, not a bag, unknown message types)."""


def open_bag(path):
    """An open rosbags Reader of `path` (BagError with one line when it does not open)."""
    from rosbags.rosbag2 import Reader
    path = pathlib.Path(path)
    if path.is_dir() and not (path / "metadata.yaml").exists():
        raise InputError(f"ROS 2 bag {path}: the folder holds no metadata.yaml (a rosbag2 bag folder has one; or give "
                         "its .db3 / .mcap file)")
    try:
        reader = Reader(pathlib.Path(path))
        reader.open()
    except FileNotFoundError:
        raise InputError(f"ROS 2 bag not found: {path}") from None
    except Exception as error:   # rosbags' reader errors, sqlite3's and the MCAP parser's: a bag that does not read
        raise BagError(f"ROS 2 bag {path}: does not read ({_first_line(error)}); truncated, or not a rosbag2 bag?") from None
    return reader


def _first_line(error: BaseException) -> str:
    text = " ".join(str(error).split())
    return text or type(error).__name__


def _topic(reader, path, topic: str, msgtype: str, required: bool):
    """The connection of `topic` (checked to carry `msgtype`); with topic "" the first connection of that type."""
    found = [c for c in reader.connections if (c.topic == topic if topic else c.msgtype == msgtype)]
    if not found:
        if required or topic:
            topics = ", ".join(f"{c.topic} ({c.msgtype})" for c in reader.connections) or "none"
            raise InputError(f"ROS 2 bag {path}: no topic {topic or 'of type ' + msgtype} (topics: {topics})")
        return None
    if found[0].msgtype != msgtype:
        raise InputError(f"ROS 2 bag {path}: topic {found[0].topic} carries {found[0].msgtype}, not {msgtype}")
    return found[0]


def _register_own(connection, store) -> bool:
    """Register in `store` the message definition the bag carries for `connection` (its type and the types it
    uses that Humble lacks); False when it carries none, or one rosbags cannot read or that contradicts Humble's
    own types (then Humble's stay)."""
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.typesys import get_types_from_idl, get_types_from_msg
    definition = connection.msgdef
    if definition is None or definition.format == MessageDefinitionFormat.NONE or not definition.data:
        return False
    try:
        if definition.format == MessageDefinitionFormat.MSG:
            types = get_types_from_msg(definition.data, connection.msgtype)
        else:
            types = get_types_from_idl(definition.data)
        store.register({name: fields for name, fields in types.items() if name not in store.types or
                        name == connection.msgtype})
    except Exception:   # rosbags' parse and registration errors: the definition is not usable
        return False
    return connection.msgtype in store.types


def _messages(reader, path, connection, store):
    """(index from 1, message) of a connection, deserialized (BagError naming the message that does not)."""
    try:
        for index, (_, _, raw) in enumerate(reader.messages(connections=[connection]), start=1):
            try:
                message = store.deserialize_cdr(raw, connection.msgtype)
            except Exception as error:
                raise BagError(f"ROS 2 bag {path}: message {index} on {connection.topic} does not decode as "
                               f"{connection.msgtype} ({_first_line(error)})") from None
            yield index, message
    except BagError:
        raise
    except Exception as error:   # the storage gives out mid-way: a truncated bag
        raise BagError(f"ROS 2 bag {path}: reading {connection.topic} failed ({_first_line(error)}); truncated?") from None


def _stamp(message, origin: int) -> float:
    """The message's stamp in s from the whole second `origin` (the first joint state's): seconds since 1970 as
    one float would lose the microseconds."""
    return float(message.header.stamp.sec - origin) + 1e-9 * float(message.header.stamp.nanosec)


def first_stamp_second(reader, path, connection, store) -> int:
    """The whole second of the first message's stamp on `connection` (the bag's time origin)."""
    for _, message in _messages(reader, path, connection, store):
        return int(message.header.stamp.sec)
    raise InputError(f"ROS 2 bag {path}: no message on {connection.topic}")


def _columns(names, wanted: list, path, what: str, index: int, cache: dict) -> np.ndarray:
    key = tuple(names)
    if key not in cache:
        where = {name: i for i, name in enumerate(names)}
        missing = [name for name in wanted if name not in where]
        if missing:
            raise InputError(f"ROS 2 bag {path}: {what} message {index} lacks joint {missing[0]} (its joints: "
                             f"{list(names)}); the robot's arm joints must be in every message (--mapping joint_names "
                             "renames them)")
        cache[key] = np.asarray([where[name] for name in wanted])
    return cache[key]


def controller_plan(reader, path, connection, store, wanted: list, origin: int):
    """(stamps (K,) s from `origin`, q_d, v_d, a_d (K, n)) of the controller-state messages, or None without them."""
    stamps, q, v, a, cache = [], [], [], [], {}
    with_accelerations = None
    for index, message in _messages(reader, path, connection, store):
        point = getattr(message, "reference", None)
        if point is None or not len(point.positions):
            point = getattr(message, "desired", None)
        joints = len(message.joint_names)
        if point is None or not (len(point.positions) == len(point.velocities) == joints):
            raise InputError(f"ROS 2 bag {path}: controller-state message {index} has no reference (positions and "
                             "velocities of every joint)")
        has = len(point.accelerations) == joints
        if with_accelerations is not None and has != with_accelerations:
            raise InputError(f"ROS 2 bag {path}: controller-state message {index} {'has' if has else 'lacks'} the "
                             "reference accelerations the messages before it "
                             f"{'lack' if has else 'have'}")
        with_accelerations = has
        columns = _columns(message.joint_names, wanted, path, "controller-state", index, cache)
        stamps.append(_stamp(message, origin))
        q.append(np.asarray(point.positions)[columns])
        v.append(np.asarray(point.velocities)[columns])
        if has:
            a.append(np.asarray(point.accelerations)[columns])
    if not stamps:
        return None
    stamps = np.asarray(stamps)
    if np.any(np.diff(stamps) <= 0):
        bad = int(np.flatnonzero(np.diff(stamps) <= 0)[0]) + 2
        raise InputError(f"ROS 2 bag {path}: controller-state message {bad}'s stamp does not increase")
    v = np.asarray(v)
    if not with_accelerations:   # (a controller without an acceleration interface: the velocities' derivative)
        a = np.gradient(v, stamps, axis=0) if len(stamps) > 1 else np.zeros_like(v)
    return stamps, np.asarray(q), v, np.asarray(a)


def rows(path, robot, mapping, block_messages: int = BLOCK_MESSAGES):
    """The bag's joint states as `Rows` blocks in the robot's joint order, stamps in s from the whole second of the
    first one (the plan where the bag has the controller state: rows outside its messages' time span count as not
    running)."""
    wanted = list(mapping.joint_names) or list(robot.joint_names)
    if len(wanted) != robot.num_joints:
        raise InputError(f"joint_names names {len(wanted)} joints, robot {robot.name} has {robot.num_joints}")
    reader = open_bag(path)
    try:
        states = _topic(reader, path, mapping.joint_states_topic, JOINT_STATE, required=True)
        control = None if mapping.controller_state_topic == "none" else \
            _topic(reader, path, mapping.controller_state_topic, CONTROLLER_STATE, required=False)
        store = typestore(states)
        origin = first_stamp_second(reader, path, states, store)
        plan = None
        if control is not None:
            plan = controller_plan(reader, path, control, typestore(control), wanted, origin)
        yield from _joint_state_blocks(reader, path, states, store, wanted, plan, block_messages, origin)
    finally:
        reader.close()


def _joint_state_blocks(reader, path, connection, store, wanted, plan, block_messages, origin):
    if plan is not None:
        stamps, q_d, v_d, a_d = plan
        plan_q = CubicHermiteSpline(stamps, q_d, v_d, axis=0, extrapolate=False) if len(stamps) > 1 else None
        plan_v = CubicHermiteSpline(stamps, v_d, a_d, axis=0, extrapolate=False) if len(stamps) > 1 else None
    cache, block = {}, dict(t=[], q=[], v=[], tau=[], where=[])
    count = 0
    for index, message in _messages(reader, path, connection, store):
        columns = _columns(message.name, wanted, path, "joint-state", index, cache)
        if len(message.position) != len(message.name) or len(message.velocity) != len(message.name):
            raise InputError(f"ROS 2 bag {path}: joint-state message {index} has {len(message.position)} positions and "
                             f"{len(message.velocity)} velocities for {len(message.name)} joints")
        if len(message.effort) != len(message.name):
            raise InputError(f"ROS 2 bag {path}: joint-state message {index} carries no effort for its joints; the "
                             "import needs the joint torques")
        block["t"].append(_stamp(message, origin))
        block["q"].append(np.asarray(message.position)[columns])
        block["v"].append(np.asarray(message.velocity)[columns])
        block["tau"].append(np.asarray(message.effort)[columns])
        block["where"].append(index)
        count += 1
        if count == block_messages:
            yield _rows(block, plan, path, plan_q if plan else None, plan_v if plan else None)
            block, count = dict(t=[], q=[], v=[], tau=[], where=[]), 0
    if count:
        yield _rows(block, plan, path, plan_q if plan else None, plan_v if plan else None)


def _rows(block: dict, plan, path, plan_q, plan_v) -> Rows:
    arrays = {key: np.asarray(values, dtype=float) for key, values in block.items() if key != "where"}
    where = np.asarray(block["where"])
    finite = np.all(np.isfinite(arrays["q"]), axis=1) & np.all(np.isfinite(arrays["v"]), axis=1) & \
        np.all(np.isfinite(arrays["tau"]), axis=1)
    if not finite.all():
        raise InputError(f"ROS 2 bag {path}: joint-state message {where[np.flatnonzero(~finite)[0]]} holds NaN or inf")
    rows = Rows(t=arrays["t"], q=arrays["q"], v=arrays["v"], tau=arrays["tau"], where=where)
    if plan is None:
        return rows
    stamps, _, _, a_d = plan
    inside = (arrays["t"] >= stamps[0]) & (arrays["t"] <= stamps[-1])
    t = np.clip(arrays["t"], stamps[0], stamps[-1])
    n = arrays["q"].shape[1]
    if plan_q is None:   # one controller-state message: its point held
        q_planned, v_planned = np.tile(plan[1][0], (len(t), 1)), np.tile(plan[2][0], (len(t), 1))
    else:
        q_planned, v_planned = plan_q(t), plan_v(t)
    qdd_planned = np.stack([np.interp(t, stamps, a_d[:, j]) for j in range(n)], axis=1)
    rows.q_planned, rows.v_planned, rows.qdd_planned = q_planned, v_planned, qdd_planned
    rows.running = inside
    return rows
