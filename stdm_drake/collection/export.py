"""Plans out to a real controller (`stdm-drake collect --protocol tracking --export-plans DIR`): each planned
trajectory as a CSV file (t s, then q rad, q̇ rad/s, q̈ rad/s² per joint, at the sample period) and all of them as
`trajectory_msgs/msg/JointTrajectory` messages in a ROS 2 bag (one message per plan, on the topic of the UR ROS 2
driver's trajectory controller), with `plans.json`: the robot, its joint limits, the sample period, the planner
and the sampling settings. Each plan starts at rest at its start pose (its first point, time_from_start 0):
move the robot there before sending it. What the robot logs while it executes them comes back through
`stdm-drake import`."""
import json
import pathlib

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.outputs import check_output_folder

PLAN_TOPIC = "/scaled_joint_trajectory_controller/joint_trajectory"
PLAN_TYPE = "trajectory_msgs/msg/JointTrajectory"


def check_export_folder(folder, force: bool = False) -> pathlib.Path:
    """The folder plans go to: new or empty (plans of another run are not mixed in), checked and locked as every
    output folder is (`outputs.check_output_folder`; force: inside another command's folder)."""
    folder = pathlib.Path(folder)
    if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        raise InputError(f"--export-plans {folder}: {'not a folder' if not folder.is_dir() else 'not empty'}; give a "
                         "new or empty folder")
    return check_output_folder("--export-plans", folder, force=force)


def plan_table(trajectory, sample_period: float) -> np.ndarray:
    """(T+1, 1 + 3n): t, q, q̇, q̈ of a tracked trajectory's plan."""
    t = sample_period * np.arange(len(trajectory.q_planned))
    return np.hstack([t[:, None], trajectory.q_planned, trajectory.v_planned, trajectory.qdd_planned])


def export_plans(folder, trajectories: list, metadata: dict, robot, force: bool = False) -> list[pathlib.Path]:
    """Write the plans of `trajectories` (tracking data) into `folder` (new or empty): plan_NNNN.csv,
    plans_rosbag2/ (a rosbag2 bag, sqlite3) and plans.json, all first into a temporary folder beside it that is
    renamed onto it at the end (on an error nothing is left). Returns the files written."""
    import shutil
    import tempfile
    folder = check_export_folder(folder, force)
    if folder.is_symlink():   # (a link to an empty folder: the plans go into the folder it names)
        folder = folder.resolve()
    folder.parent.mkdir(parents=True, exist_ok=True)
    temporary = pathlib.Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
    try:
        written = _write_plans(temporary, trajectories, metadata, robot)
        if folder.exists():
            folder.rmdir()      # (checked empty)
        temporary.rename(folder)
    finally:
        if temporary.exists():
            shutil.rmtree(temporary)
    return [folder / path.relative_to(temporary) for path in written]


def _write_plans(folder: pathlib.Path, trajectories: list, metadata: dict, robot) -> list[pathlib.Path]:
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore
    from stdm_drake.robots.plant import robot_joint_limits   # lazy: pydrake
    if not trajectories or trajectories[0].q_planned is None:
        raise InputError("--export-plans needs tracking data (plans)")
    sample_period = float(metadata["sample_period"])
    names = list(robot.joint_names)
    header = ",".join(["t"] + [f"{kind}_{name}" for kind in ("q", "qd", "qdd") for name in names])
    written = []
    for index, trajectory in enumerate(trajectories):
        path = folder / f"plan_{index:04d}.csv"
        np.savetxt(path, plan_table(trajectory, sample_period), delimiter=",", header=header, comments="", fmt="%.17g")
        written.append(path)
    store = get_typestore(Stores.ROS2_HUMBLE)
    types = store.types
    Duration, Time = types["builtin_interfaces/msg/Duration"], types["builtin_interfaces/msg/Time"]
    Header, Point, Message = types["std_msgs/msg/Header"], types["trajectory_msgs/msg/JointTrajectoryPoint"], types[PLAN_TYPE]
    bag = folder / "plans_rosbag2"
    with Writer(bag, version=9) as writer:
        connection = writer.add_connection(PLAN_TOPIC, PLAN_TYPE, typestore=store)
        for index, trajectory in enumerate(trajectories):
            points = []
            for k, row in enumerate(plan_table(trajectory, sample_period)):
                nanoseconds = int(round(k * sample_period * 1e9))
                q, qd, qdd = np.split(row[1:], 3)
                points.append(Point(positions=q, velocities=qd, accelerations=qdd, effort=np.zeros(0),
                                    time_from_start=Duration(sec=nanoseconds // 1_000_000_000,
                                                             nanosec=nanoseconds % 1_000_000_000)))
            # (stamp 0: start on receipt)
            message = Message(header=Header(stamp=Time(sec=0, nanosec=0), frame_id=""), joint_names=names, points=points)
            writer.write(connection, (index + 1) * 1_000_000_000, store.serialize_cdr(message, PLAN_TYPE))
    written.append(bag)
    limits = robot_joint_limits(robot)
    record = dict(written_by="stdm-drake collect --export-plans", robot=robot.name, joint_names=names,
                  limits=dict(position_lower=limits.position_lower.tolist(), position_upper=limits.position_upper.tolist(),
                              velocity=limits.velocity.tolist(), effort=limits.effort.tolist()),
                  sample_period=sample_period, plans=len(trajectories), seed=metadata.get("seed"),
                  planner=metadata.get("planner"), task_space_sampling=metadata.get("task_space_sampling"),
                  csv_columns=header.split(","), bag=dict(path=bag.name, topic=PLAN_TOPIC, type=PLAN_TYPE,
                                                          storage="sqlite3", messages="one per plan, in order"),
                  files=[path.name for path in written])
    (folder / "plans.json").write_text(json.dumps(record, indent=1) + "\n")
    return written + [folder / "plans.json"]
