"""One import job, the library's `import`: a real robot's log (UR RTDE CSV, ROS 2 bag) as a validated dataset of
protocol "logged" (docs/real_logs.md), with what was kept, cut and resampled printed.

    job = ImportJob(log=pathlib.Path("robot.csv"), output=pathlib.Path("logged.h5"), robot=pathlib.Path("arm.yaml"))
    record = import_job(job)          # the dataset's "import" record
"""
from __future__ import annotations

import dataclasses
import pathlib

from stdm_drake.errors import InputError
from stdm_drake.files import line_text
from stdm_drake.outputs import check_output_file
from stdm_drake.data.logs.mapping import LogMapping, check_settings_used, load_mapping


@dataclasses.dataclass
class ImportJob:
    """What one import needs.

    log: the log, an RTDE CSV file or a ROS 2 bag (its folder, or one .db3 / .mcap file); output: the dataset
    file to write (.h5); robot: the logged arm's config YAML (None: the UR-10's); mapping: the typed YAML
    of what the log does not say (None: the defaults); the settings below override it where given (None:
    the mapping's): format: the log's format ("rtde_csv" or "ros2_bag"; None: from the file); sample_period:
    the dataset's sample period, s (0: the log's median period); torque_source: "target_moment" or
    "current" (RTDE), "effort" (bags); torque_constants: per joint, N m / A, for the current; the bags'
    joint_states_topic and controller_state_topic; joint_names: the log's name of each of the robot's arm
    joints, in the robot's order; progress: the two lines on what was imported (False: `--quiet`); force: replace a file
    stdm-drake did not write."""
    log: pathlib.Path
    output: pathlib.Path
    robot: pathlib.Path | None = None
    mapping: pathlib.Path | None = None
    format: str | None = None
    sample_period: float | None = None
    torque_source: str | None = None
    torque_constants: list | None = None
    joint_states_topic: str | None = None
    controller_state_topic: str | None = None
    joint_names: list | None = None
    progress: bool = True
    force: bool = False


def job_mapping(job: ImportJob, log):
    """The LogMapping of `job.mapping` (defaults without it) with the job's settings that are given applied
    over it, for the format of `log`, checked (a setting given, as the job's or a file's key, must be one the
    import uses)."""
    from stdm_drake.config import file_keys   # lazy: pydrake
    from stdm_drake.data.logs.importer import detect_format   # lazy: pydrake, h5py
    mapping = load_mapping(job.mapping) if job.mapping is not None else LogMapping()
    options = dict(format=job.format, sample_period=job.sample_period, torque_source=job.torque_source,
                   torque_constants=job.torque_constants, joint_states_topic=job.joint_states_topic,
                   controller_state_topic=job.controller_state_topic, joint_names=job.joint_names)
    options = {key: value for key, value in options.items() if value is not None}
    mapping = dataclasses.replace(mapping, **options)
    mapping.validate()
    mapping = mapping.with_format(detect_format(log, mapping.format))
    check_settings_used(mapping, set(options) | file_keys(job.mapping))
    return mapping


def import_job(job: ImportJob) -> dict:
    """Run `job`: every check first (the log there, the output an .h5 file outside a bag folder and free to
    write, the mapping, the robot), then the import and two lines on it; returns the dataset's "import"
    record (`importer.import_log`). InputError (one line) for a bad input; then nothing is written."""
    from stdm_drake.data.compatibility import resolve_robot   # lazy: pydrake
    from stdm_drake.data.logs.importer import import_log   # lazy: pydrake, h5py
    log, output = pathlib.Path(job.log), pathlib.Path(job.output)
    if not (log.exists() or log.is_symlink()):
        raise InputError(f"log not found: {log}")
    if not (log.is_file() or log.is_dir()):
        raise InputError(f"log {log} is not a file or a bag folder")
    if output.suffix.lower() not in (".h5", ".hdf5"):
        raise InputError(f"-o/--output {output}: a dataset is an .h5 file")
    if log.is_dir() and output.absolute().parent == log.absolute():
        raise InputError(f"-o/--output {output} is inside the bag folder {log}; write the dataset elsewhere")
    check_output_file("-o/--output", output, kind="dataset", inputs=[log, job.mapping, job.robot], force=job.force)
    mapping = job_mapping(job, log)
    robot = resolve_robot(job.robot)
    if mapping.joint_names and len(mapping.joint_names) != robot.num_joints:
        raise InputError(f"joint_names names {len(mapping.joint_names):,} joints, robot {robot.name} has "
                         f"{robot.num_joints}")
    # no line before the import: a refusal found reading the log is then the only line
    record = import_log(log, robot, mapping, output)
    pieces, resampling = record["trajectories"], record["resampling"]
    if job.progress:
        print(f"wrote {line_text(output)} from the {mapping.format} log {line_text(log.name)} of a {line_text(robot.name)}: "
              f"{pieces['kept']} trajectories from {pieces['rows']} rows at a sample period of "
              f"{record['mapping']['sample_period'] or resampling['log_period_s']:g} s (split at {pieces['gaps']} gaps, "
              f"{pieces['pauses']} pauses, {pieces['mode_changes']} mode changes, {pieces['cuts']} cuts; "
              f"{pieces['dropped_short']} short pieces dropped, {pieces['rows_not_running']} rows not running left out)")
        print(f"resampling: log period {resampling['log_period_s']:g} s, stamp jitter RMS {resampling['jitter_rms_s']:.3g} s, "
              f"estimated angle error {resampling['estimated_q_error_rad']:.3g} rad; torque from "
              f"{record['torque_source']}; derivative targets: "
              + ("the logged plan, " if record["derivatives"]["planned"] else "")
              + "measured, smoothed (Savitzky-Golay)"
              + ("; train chooses between the plan (when close to the logged motion) and the smoothed ones by validation"
                 if record["derivatives"]["planned"] else "; train uses the smoothed ones"))
    return record
