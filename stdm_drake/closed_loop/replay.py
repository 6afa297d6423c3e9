"""One replay job, the library's `view`: recorded trajectories of a dataset and a model's open-loop prediction
from the same initial state and torques, side by side in Meshcat (the prediction as a translucent ghost),
live and/or as a standalone HTML file, with each trajectory's open-loop error printed.

    job = ReplayJob(model=pathlib.Path("runs/dd/seed0/checkpoint.pt"), dataset=pathlib.Path("data.h5"),
                    html=pathlib.Path("replay.html"))
    record = replay_job(job)          # the trajectories replayed and where a rollout diverged
"""
from __future__ import annotations

import dataclasses
import pathlib

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.outputs import check_output_file
from stdm_drake.dynamics.model_files import load_model
from stdm_drake.report import open_loop_error_line
from stdm_drake.dynamics.physics import PlantModel

DEFAULT_TRAJECTORIES = 3


@dataclasses.dataclass
class ReplayJob:
    """What one replay needs.

    model: a model file (a checkpoint `train` wrote, .pt, or an identified robot `identify` wrote, .yaml);
    dataset: the .h5 file with the recorded trajectories; trajectories: how many to replay (>= 1; None: 3),
    taken from the model's test split of this dataset when it has one, else the dataset's last ones; index:
    the trajectory indices to replay instead (not with `trajectories`); html: the standalone HTML file to
    write (None: none); meshcat: play live in Meshcat (prints its URL; serves until Ctrl+C); at least one of
    html and meshcat; robot: the robot config YAML (None: the shipped preset the dataset was collected
    with, else the UR-10's; must be the dataset's robot); visualization: Drake's VisualizationConfig YAML of
    the recording (None: the illustration geometry only); force: replace an HTML file stdm-drake did not
    write."""
    model: pathlib.Path
    dataset: pathlib.Path
    trajectories: int | None = None
    index: tuple | list | None = None
    html: pathlib.Path | None = None
    meshcat: bool = False
    robot: pathlib.Path | None = None
    visualization: pathlib.Path | None = None
    force: bool = False


def held_after_divergence(q: np.ndarray) -> tuple[np.ndarray, int | None]:
    """q (T + 1, n) rad of a rollout from its start: the rows from the first non-finite one (a diverged
    rollout) replaced by the last finite row, and that step (None: none)."""
    finite = np.isfinite(q).all(axis=1)
    if finite.all():
        return q, None
    first = int(np.argmin(finite))
    held = q.copy()
    held[first:] = q[first - 1]
    return held, first


def replay_job(job: ReplayJob) -> dict:
    """Run `job`: every check first (what to show, the trajectory choice, the HTML file, Meshcat allowed, the
    visualization, dataset, robot and model, the model fitting the dataset), then per trajectory its
    open-loop error line (and the nominal plant's, for data of an affected plant) and the recording; returns
    dict(model=its name, trajectories=the indices replayed, diverged={index: the step its rollout diverged}).
    InputError (one line) for a bad input."""
    from stdm_drake.data.compatibility import resolve_robot   # lazy: pydrake
    from stdm_drake.data.dataset import load_dataset   # lazy: pydrake, h5py
    # lazy: pydrake, matplotlib
    from stdm_drake.robots.recorder import TrajectoryRecorder, check_meshcat_allowed, recording_visualization

    if not (job.html or job.meshcat):
        raise InputError("nothing to show: give --html FILE and/or --meshcat")
    if job.index and job.trajectories is not None:
        raise InputError("--index names the trajectories to replay and --trajectories how many to pick: give one")
    count = DEFAULT_TRAJECTORIES if job.trajectories is None else job.trajectories
    if not job.index and count < 1:
        raise InputError(f"--trajectories must be >= 1, got {count}")
    check_output_file("--html", job.html, kind="html",
                      inputs=[job.model, job.dataset, job.robot, job.visualization], force=job.force)
    check_meshcat_allowed("--html" if job.html else "--meshcat")
    visualization = recording_visualization(job.visualization, True)
    dataset = load_dataset(job.dataset)
    robot = resolve_robot(job.robot, dataset)
    model = load_model(job.model, robot)
    model.checkpoint.check_fits(dataset)
    if job.index:
        indices = list(job.index)
    else:
        test = model.checkpoint.split_indices(dataset, "test")
        pool = test if test is not None else list(range(dataset.num_trajectories))[::-1]
        indices = pool[:count]
    nominal = None
    if dataset.metadata.plant_effects is not None:   # data of an affected plant: the user's model beside the learned
        nominal = PlantModel(dataset.sample_period, dataset.metadata.plant_config(effects=False), robot=robot)
        print(f"plant effects of the data: {dataset.metadata.plant_effects.summary()}; 'nominal plant': the robot's "
              "description stepping the same torques")
    recorder = TrajectoryRecorder(dataset.sample_period, ghost=True, robot=robot, visualization=visualization)
    if job.meshcat:
        print(f"Meshcat: {recorder.meshcat.web_url()}")
    diverged_at = {}
    for index in indices:
        if not 0 <= index < dataset.num_trajectories:
            raise InputError(f"trajectory index {index} out of range 0..{dataset.num_trajectories - 1}")
        traj = dataset.trajectory(index)
        x0 = np.concatenate([traj.q[0], traj.v[0]])
        predicted = model.rollout(x0[None], traj.tau[None]).mean[0]
        ghost_q, diverged = held_after_divergence(np.vstack([traj.q[:1], predicted[:, :robot.num_joints]]))
        errors_q = ghost_q.copy()
        if diverged is not None:   # (an infinite error from there on; the ghost holds its last pose)
            errors_q[diverged:] = np.inf
            diverged_at[int(index)] = diverged
        print(f"trajectory {index}: {open_loop_error_line(model.name, traj.q, traj.v[0], errors_q, dataset.sample_period)}"
              + ("" if diverged is None else f"; the rollout diverged at step {diverged} (the ghost holds its pose "
                                             "from there)"))
        if nominal is not None:
            plant_q = np.vstack([traj.q[:1], nominal.rollout(x0[None], traj.tau[None]).mean[0][:, :robot.num_joints]])
            print(f"  {open_loop_error_line('nominal plant', traj.q, traj.v[0], plant_q, dataset.sample_period)}")
        recorder.add(traj.q_true if traj.is_simulated else traj.q, ghost_q, realtime=job.meshcat)
    recorder.finish(job.html, keep_serving=job.meshcat,
                    what=f"robot: recorded; translucent orange: {model.name} open-loop prediction")
    return dict(model=model.name, trajectories=[int(index) for index in indices], diverged=diverged_at)
