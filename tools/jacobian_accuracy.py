"""How well a learned model identifies the torque response: its Jacobian d q̇_k+1 / d τ_k against the
plant's, at the true states and recorded torques of held-out trajectories.

For each joint j it prints the relative error ||B_learned[:, j] - B_plant[:, j]|| / ||B_plant[:, j]||
of the velocity rows of B = d x_k+1 / d τ_k, averaged over every 10th step of up to 3 held-out
trajectories (the checkpoint's test split when it was trained on this dataset). A model an MPC can
use gets a few percent; models trained on closed-loop data without excitation get 30-100 %.

Usage: python tools/jacobian_accuracy.py DATASET.h5 CHECKPOINT.pt [CHECKPOINT.pt ...]
"""
import argparse
import os
import pathlib
import sys

os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")

import numpy as np  # noqa: E402
import torch  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from stdm_drake.data.dataset import load_dataset  # noqa: E402
from stdm_drake.learning.learned_model import LearnedModel  # noqa: E402
from stdm_drake.learning.physics import PlantModel  # noqa: E402
from stdm_drake.closed_loop.comparison import held_out_references  # noqa: E402
from stdm_drake.robots.robot import UR10_CONFIG, load_robot  # noqa: E402

UR10 = load_robot(UR10_CONFIG)


def torque_jacobian_errors(model: LearnedModel, plant: PlantModel, dataset, indices, stride: int = 10) -> np.ndarray:
    """Relative error per joint column of d v_next / d tau, mean over the sampled steps: (m,)."""
    errors = []
    for index in indices:
        traj = dataset.trajectory(index)
        x = np.hstack([traj.q_true, traj.v_true])[:-1:stride]
        u = traj.tau[::stride]
        _, B_plant = plant.jacobians(x, u)
        _, B_model = model.jacobians(x, u)
        velocity_rows = slice(UR10.num_joints, UR10.state_dim)
        difference = np.linalg.norm(B_model[:, velocity_rows] - B_plant[:, velocity_rows], axis=1)
        errors.append(difference / np.linalg.norm(B_plant[:, velocity_rows], axis=1))
    return np.concatenate(errors).mean(axis=0)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=pathlib.Path)
    parser.add_argument("checkpoints", type=pathlib.Path, nargs="+")
    parser.add_argument("--trajectories", type=int, default=3)
    args = parser.parse_args()
    torch.set_num_threads(1)
    dataset = load_dataset(args.dataset)
    plant = PlantModel(dataset.sample_period, robot=UR10)
    print("relative error of d qdot_next / d tau, per joint column: " + ", ".join(UR10.joint_names))
    for path in args.checkpoints:
        model = LearnedModel(path, robot=UR10)
        indices = [index for index, _ in held_out_references(dataset, [model.checkpoint], args.trajectories)]
        errors = torque_jacobian_errors(model, plant, dataset, indices)
        print(f"{path}: " + " ".join(f"{100 * error:.1f}%" for error in errors))


if __name__ == "__main__":
    main()
