"""One collection job, the library's `collect`: simulate a robot under a data protocol, write the dataset and,
where asked, every tracking plan for a real controller and a Meshcat recording of the trajectories.

    job = CollectJob(output=pathlib.Path("data.h5"), protocol="excitation", count=20)
    record = collect_job(job)         # the dataset written, its trajectories and the simulation's speed
"""
from __future__ import annotations

import dataclasses
import pathlib
import sys
import time

from stdm_drake.collection.collect import CollectionRequest, collect, collection_request, tracking_warning
from stdm_drake.data.writer import HDF5_RESERVE_BYTES, write_dataset
from stdm_drake.errors import InputError, warn
from stdm_drake.files import check_free_space, line_text
from stdm_drake.outputs import check_output_file
from stdm_drake.robots.plant import DEFAULT_PLANT_TIME_STEP
from stdm_drake.robots.robot import UR10_CONFIG
from stdm_drake.robots.station import DEFAULT_SAMPLE_PERIOD, loop_settings
from stdm_drake.collection.export import check_export_folder, export_plans


@dataclasses.dataclass
class CollectJob:
    """What one collection needs.

    output: the dataset file to write (.h5); protocol: "excitation" or "tracking" (None: the one the
    `config` file's tag names, else tracking); count: trajectories, 1..100000 (None: the paper's, 200
    excitation / 100 tracking); seed: the random seed (>= 0; the same seed gives the same file); config:
    the protocol YAML (None: the file the robot config's `defaults` names, else derived from the robot);
    controller: the tracking controller's gains YAML (None: controllers/inverse_dynamics.yaml; tracking
    only); sensor: the sensor noise/filter YAML (None: controllers/sensor.yaml for tracking, an ideal
    sensor for excitation); robot: the robot config YAML (None: the UR-10's); sample_period: the data's
    sample period, s; plant_time_step: the discrete plant's step, s (the period a whole multiple of it);
    workers: worker processes (>= 1; the data do not depend on it; None: `collect.default_workers`, 1 for a small
    job, 2 from 25,000 plant steps); plant_effects: the plant effects YAML
    the data come from (None: the robot's description as it is); meshcat: show each trajectory live in
    Meshcat as it is collected (prints the URL; from a terminal it serves until Ctrl+C); html: a standalone
    Meshcat HTML file replaying every trajectory (None: none); visualization: Drake's VisualizationConfig
    YAML of that recording (only with meshcat or html); export_plans: a new or empty folder for every
    tracking plan as CSV files, a ROS 2 bag and plans.json (None: none); progress: the progress bar;
    force: replace files stdm-drake did not write."""
    output: pathlib.Path
    protocol: str | None = None
    count: int | None = None
    seed: int = 0
    config: pathlib.Path | None = None
    controller: pathlib.Path | None = None
    sensor: pathlib.Path | None = None
    robot: pathlib.Path | None = None
    sample_period: float = DEFAULT_SAMPLE_PERIOD
    plant_time_step: float = DEFAULT_PLANT_TIME_STEP
    workers: int | None = None
    plant_effects: pathlib.Path | None = None
    meshcat: bool = False
    html: pathlib.Path | None = None
    visualization: pathlib.Path | None = None
    export_plans: pathlib.Path | None = None
    progress: bool = True
    force: bool = False


def job_request(job: CollectJob) -> CollectionRequest:
    """The `CollectionRequest` of `job` (`collection_request`: every config file read and checked against the
    robot, the numbers checked; the robot: `job.robot`, else the UR-10's)."""
    return collection_request(job.protocol, count=job.count, seed=job.seed, config=job.config,
                              controller=job.controller, sensor=job.sensor, sample_period=job.sample_period,
                              plant_time_step=job.plant_time_step, robot=job.robot or UR10_CONFIG,
                              workers=job.workers, plant_effects=job.plant_effects)


def check_export_plans(job: CollectJob, protocol: str) -> None:
    """The checks of `job.export_plans` (before the outputs' locks, which would put files in a new folder)."""
    if protocol != "tracking":
        raise InputError("--export-plans: plans exist only with --protocol tracking")
    if pathlib.Path(job.output).absolute().is_relative_to(pathlib.Path(job.export_plans).absolute()):
        raise InputError(f"-o/--output {job.output} is inside --export-plans {job.export_plans}; write the "
                         "dataset elsewhere")
    check_export_folder(job.export_plans, job.force)


def collect_job(job: CollectJob) -> dict:
    """Run `job`: every check first (the request with its config files and numbers, the visualization, the
    plans' folder, the output files, Meshcat allowed), then the simulation, the dataset written and one line
    on it, the plans exported and the recording finished; returns dict(path=the dataset written,
    protocol, trajectories=their number, simulated_s, elapsed_s, plans=the files exported or None).
    InputError (one line) for a bad input."""
    from stdm_drake.robots.recorder import check_meshcat_allowed, recording_visualization   # lazy: matplotlib
    request = job_request(job)
    robot = request.settings.robot
    inputs = [job.config, job.controller, job.sensor, job.robot, robot.model_path, job.visualization,
              job.plant_effects]
    visualization = recording_visualization(job.visualization, bool(job.meshcat or job.html))
    if job.export_plans is not None:
        check_export_plans(job, request.protocol)
    check_output_file("-o/--output", job.output, kind="dataset", inputs=inputs, force=job.force)
    check_output_file("--html", job.html, kind="html", inputs=inputs + [job.output], force=job.force)
    recorder = None
    if job.meshcat or job.html:
        check_meshcat_allowed("--meshcat" if job.meshcat else "--html")
        from stdm_drake.robots.recorder import TrajectoryRecorder   # lazy: matplotlib
        recorder = TrajectoryRecorder(request.settings.sample_period, robot=robot, visualization=visualization)
        if job.meshcat:
            print(f"Meshcat: {recorder.meshcat.web_url()}", file=sys.stderr)
    started = time.perf_counter()
    trajectories, groups, metadata = collect(
        request, progress=job.progress,
        on_trajectory=None if recorder is None else lambda traj: recorder.add(traj.q_true, realtime=job.meshcat),
        check_size=lambda size: check_free_space(job.output, size + HDF5_RESERVE_BYTES))
    elapsed = time.perf_counter() - started
    path = write_dataset(job.output, trajectories, groups, metadata)
    if request.protocol == "tracking" and not any(request.settings.controller.dither_std):   # (dithered data
        line = tracking_warning(trajectories, robot.joint_names, loop_settings(request.settings))   # leave it by design)
        if line:
            warn(line)
    simulated = sum(len(t.tau) for t in trajectories) * request.settings.sample_period
    print(f"wrote {line_text(path)}: {len(trajectories)} {request.protocol} trajectories, {simulated:.1f} s simulated "
          f"in {elapsed:.1f} s ({simulated / elapsed:.1f}x real time)")
    written = None
    if job.export_plans is not None:
        written = export_plans(job.export_plans, trajectories, metadata, robot, job.force)
        print(f"wrote {len(trajectories)} plans to {line_text(job.export_plans)} ({len(written)} files: CSV, a ROS 2 bag, "
              "plans.json); run them on the robot, then `stdm-drake import` its log")
    if recorder is not None:
        recorder.finish(job.html, keep_serving=job.meshcat)
    return dict(path=path, protocol=request.protocol, trajectories=len(trajectories), simulated_s=simulated,
                elapsed_s=elapsed, plans=written)
