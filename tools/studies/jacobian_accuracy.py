"""The torque Jacobian's accuracy: a learned model's d q̇_k+1 / d τ_k against the plant's.

At the true states and recorded torques of held-out trajectories of the UR-10: for each joint j it prints the
relative error ||B_learned[:, j] - B_plant[:, j]|| / ||B_plant[:, j]|| of the velocity rows of
B = d x_k+1 / d τ_k, averaged over every 10th step of up to 3 held-out trajectories (the checkpoint's test
split when it was trained on this dataset). A model an MPC can use gets a few percent; models trained on
closed-loop data without excitation get 30-100 %.

    python tools/study.py jacobian-accuracy DATASET.h5 CHECKPOINT.pt [CHECKPOINT.pt ...]
"""
import argparse
import pathlib

import numpy as np

WRITES_RESULTS = False   # (it prints: the launcher does not ask for a clean checkout)


def torque_jacobian_errors(model, plant, dataset, indices, stride: int = 10) -> np.ndarray:
    """Relative error per joint column of d v_next / d tau (`model` and `plant`: DynamicsModels of one robot),
    mean over the sampled steps: (m,)."""
    errors = []
    for index in indices:
        traj = dataset.trajectory(index)
        x = np.hstack([traj.q_true, traj.v_true])[:-1:stride]
        u = traj.tau[::stride]
        _, B_plant = plant.jacobians(x, u)
        _, B_model = model.jacobians(x, u)
        joints = traj.q_true.shape[1]
        velocity_rows = slice(joints, 2 * joints)
        difference = np.linalg.norm(B_model[:, velocity_rows] - B_plant[:, velocity_rows], axis=1)
        errors.append(difference / np.linalg.norm(B_plant[:, velocity_rows], axis=1))
    return np.concatenate(errors).mean(axis=0)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dataset", type=pathlib.Path)
    parser.add_argument("checkpoints", type=pathlib.Path, nargs="+")
    parser.add_argument("--trajectories", type=int, default=3)


def run(args: argparse.Namespace) -> int:
    import torch

    from stdm_drake.closed_loop.comparison import held_out_references
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.dynamics.model_files import load_model
    from stdm_drake.dynamics.physics import PlantModel
    from stdm_drake.robots.robot import UR10_CONFIG, load_robot
    torch.set_num_threads(1)
    robot = load_robot(UR10_CONFIG)
    dataset = load_dataset(args.dataset)
    plant = PlantModel(dataset.sample_period, robot=robot)
    print("relative error of d qdot_next / d tau, per joint column: " + ", ".join(robot.joint_names))
    for path in args.checkpoints:
        model = load_model(path, robot)
        indices = [index for index, _ in held_out_references(dataset, [model.checkpoint], args.trajectories)]
        errors = torque_jacobian_errors(model, plant, dataset, indices)
        print(f"{path}: " + " ".join(f"{100 * error:.1f}%" for error in errors))
    return 0
