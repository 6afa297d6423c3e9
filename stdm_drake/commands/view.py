"""`stdm-drake view`: a recorded trajectory and a learned model's open-loop prediction from the same
initial state and actions, side by side in Meshcat (the prediction as a translucent ghost)."""
import pathlib

import numpy as np

from stdm_drake.commands.arguments import (add_robot_argument, add_visualization_argument, check_meshcat_allowed,
                                            command_robot, command_visualization)
from stdm_drake.learning.evaluate import open_loop_error_line
from stdm_drake.outputs import add_force_argument, check_output_file
from stdm_drake.robots.recorder import TrajectoryRecorder


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


def add_arguments(parser) -> None:
    parser.add_argument("checkpoint", type=pathlib.Path, metavar="MODEL",
                        help="trained model (checkpoint.pt) or identified robot (identified.yaml)")
    parser.add_argument("dataset", type=pathlib.Path, help="dataset with the trajectories to replay")
    parser.add_argument("--trajectories", type=int,
                        help="how many test trajectories (the checkpoint's test split when it was trained on "
                             "this dataset, else the dataset's last ones; default 3)")
    parser.add_argument("--index", type=int, action="append",
                        help="replay these trajectory indices instead (repeat the flag for several)")
    parser.add_argument("--html", type=pathlib.Path, help="save the recording as a standalone HTML file")
    parser.add_argument("--meshcat", action="store_true", help="play live in Meshcat (prints the URL)")
    add_robot_argument(parser, "must be the dataset's robot")
    add_visualization_argument(parser)
    add_force_argument(parser)


def run(args) -> int:
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.errors import InputError
    from stdm_drake.commands.arguments import command_model
    if not (args.html or args.meshcat):
        raise InputError("nothing to show: give --html FILE and/or --meshcat")
    if args.index and args.trajectories is not None:
        raise InputError("--index names the trajectories to replay and --trajectories how many to pick: give one")
    if args.trajectories is None:
        args.trajectories = 3
    if not args.index and args.trajectories < 1:
        raise InputError(f"--trajectories must be >= 1, got {args.trajectories}")
    check_output_file("--html", args.html, kind="html",
                      inputs=[args.checkpoint, args.dataset, args.robot, args.visualization], force=args.force)
    check_meshcat_allowed("--html" if args.html else "--meshcat")
    visualization = command_visualization(args)
    dataset = load_dataset(args.dataset)
    robot = command_robot(args, dataset)
    model = command_model(args.checkpoint, robot)
    model.checkpoint.check_fits(dataset)
    if args.index:
        indices = args.index
    else:
        test = model.checkpoint.split_indices(dataset, "test")
        pool = test if test is not None else list(range(dataset.num_trajectories))[::-1]
        indices = pool[:args.trajectories]
    nominal = None
    if dataset.metadata.plant_effects is not None:   # data of an affected plant: the user's model beside the learned
        from stdm_drake.learning.physics import PlantModel
        nominal = PlantModel(dataset.sample_period, robot=robot)
        print(f"plant effects of the data: {dataset.metadata.plant_effects.summary()}; 'nominal plant': the robot's "
              "description stepping the same torques")
    recorder = TrajectoryRecorder(dataset.sample_period, ghost=True, robot=robot, visualization=visualization)
    if args.meshcat:
        print(f"Meshcat: {recorder.meshcat.web_url()}")
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
        print(f"trajectory {index}: {open_loop_error_line(model.name, traj.q, traj.v[0], errors_q, dataset.sample_period)}"
              + ("" if diverged is None else f"; the rollout diverged at step {diverged} (the ghost holds its pose "
                                             "from there)"))
        if nominal is not None:
            plant_q = np.vstack([traj.q[:1], nominal.rollout(x0[None], traj.tau[None]).mean[0][:, :robot.num_joints]])
            print(f"  {open_loop_error_line('nominal plant', traj.q, traj.v[0], plant_q, dataset.sample_period)}")
        recorder.add(traj.q_true if traj.is_simulated else traj.q, ghost_q, realtime=args.meshcat)
    recorder.finish(args.html, keep_serving=args.meshcat,
                    what=f"robot: recorded; translucent orange: {model.name} open-loop prediction")
    return 0
