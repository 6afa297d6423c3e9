"""`stdm-drake inspect DATASET`: counts, ranges and tracking errors of a dataset file."""
from __future__ import annotations

import argparse
import pathlib

import numpy as np

from stdm_drake.dataset import Dataset, load_dataset

JOINT_LABELS = ("pan", "lift", "elbow", "wrist1", "wrist2", "wrist3")


def tracking_errors(dataset: Dataset) -> dict:
    """Mean squared tracking errors over all samples (tracking data only).

    measured_*: learner's (measured, filtered) state minus the plan; true_*: the plant's state
    minus the plan. Units rad^2 and (rad/s)^2.
    """
    stack = lambda key: np.concatenate([dataset.trajectory(i)[key] for i in range(dataset.num_trajectories)])
    q_plan, v_plan = stack("q_planned"), stack("v_planned")
    return dict(measured_q=float(np.mean((stack("q") - q_plan) ** 2)),
                measured_v=float(np.mean((stack("v") - v_plan) ** 2)),
                true_q=float(np.mean((stack("q_true") - q_plan) ** 2)),
                true_v=float(np.mean((stack("v_true") - v_plan) ** 2)))


def summary(dataset: Dataset) -> str:
    meta = dataset.metadata
    steps = [len(dataset.trajectory(i)["tau"]) for i in range(dataset.num_trajectories)]
    groups, counts = np.unique(dataset.groups, return_counts=True)
    lines = [
        f"file            {dataset.path}  (sha256 {dataset.sha256[:16]}…)",
        f"protocol        {dataset.protocol}",
        f"trajectories    {dataset.num_trajectories}  steps each {min(steps)}..{max(steps)}  "
        f"transitions {sum(steps)}",
        "groups          " + ", ".join(f"{g}: {c}" for g, c in zip(groups, counts)),
        f"sample period   {dataset.sample_period} s  (plant step {meta.get('plant', {}).get('time_step')} s)",
        f"seed            {meta.get('seed')}   robot model sha256 {str(meta.get('robot_model_sha256'))[:16]}…",
    ]
    if dataset.protocol == "tracking":
        lines.append(f"planner         {meta.get('planner', {}).get('kind')}   controller "
                     f"{meta.get('controller', {}).get('kind')}   sensor {meta.get('sensor')}")
    versions = meta.get("package_versions", {})
    lines.append("packages        " + ", ".join(f"{k} {v}" for k, v in sorted(versions.items())))
    header = f"{'':14s}" + "".join(f"{label:>17s}" for label in JOINT_LABELS)
    lines += ["", "ranges (min..max over all samples)", header]
    for key, unit in (("q", "rad"), ("v", "rad/s"), ("tau", "N m"), ("qdd", "rad/s^2")):
        values = np.concatenate([dataset.trajectory(i)[key] for i in range(dataset.num_trajectories)])
        cells = "".join(f"{lo:>8.3g}..{hi:<7.3g}" for lo, hi in zip(values.min(0), values.max(0)))
        lines.append(f"{key + ' ' + unit:14s}{cells}")
    if dataset.protocol == "tracking":
        errors = tracking_errors(dataset)
        lines += ["", "tracking error (MSE against the plan; paper's real UR-10: q 1.818e-5 rad^2, v 0.029 (rad/s)^2)",
                  f"measured        q {errors['measured_q']:.3e} rad^2   v {errors['measured_v']:.3e} (rad/s)^2",
                  f"true            q {errors['true_q']:.3e} rad^2   v {errors['true_v']:.3e} (rad/s)^2"]
    return "\n".join(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dataset", type=pathlib.Path, help="dataset file (.h5) written by `stdm-drake collect`")


def run(args: argparse.Namespace) -> int:
    print(summary(load_dataset(args.dataset)))
    return 0
