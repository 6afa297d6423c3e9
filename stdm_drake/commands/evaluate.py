"""`stdm-drake evaluate`: one-step and multi-step test errors of a trained model on a dataset, beside the
physics baselines."""
from __future__ import annotations

import argparse
import pathlib

from stdm_drake.dynamics.model import PROPAGATIONS
from stdm_drake.dynamics.compiled_core import IMPLEMENTATIONS
from stdm_drake.outputs import add_force_argument


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", type=pathlib.Path, metavar="MODEL",
                        help="model checkpoint written by `stdm-drake train` (.pt), or an identified robot written by "
                             "`stdm-drake identify` (.yaml)")
    parser.add_argument("dataset", type=pathlib.Path, help="dataset file (.h5)")
    parser.add_argument("--robot", type=pathlib.Path,
                        help="robot config YAML (default: the shipped preset the dataset was collected with, else the "
                             "UR-10's when the dataset is its): the plant "
                             "baseline and the nominal model; a dataset collected with another robot is refused")
    parser.add_argument("--split", choices=("test", "val", "train", "all"), default="test",
                        help="trajectories to evaluate: the checkpoint's split of this dataset, or all (default test)")
    parser.add_argument("--horizon", type=int,
                        help="multi-step horizon in steps, at most the trajectories' length (default: that length, "
                             "capped at 100)")
    parser.add_argument("--propagation", choices=PROPAGATIONS, default="mean",
                        help="multi-step propagation: mean, ts1 or tsinf (PETS; default mean)")
    parser.add_argument("--particles", type=int, help="particles per trajectory for ts1/tsinf (default 20)")
    parser.add_argument("--seed", type=int, help="seed of the ts1/tsinf particles (default 0)")
    parser.add_argument("--implementation", choices=IMPLEMENTATIONS, default="compiled",
                        help="the learned model's rollout code: compiled (C++, where the compiled core covers the "
                             "model: the MLPs, mean propagation) or numpy (the reference; default compiled)")
    parser.add_argument("--no-plant", action="store_true",
                        help="leave out the plant baseline (the robot's rigid-body plant stepping the recorded torque: "
                             "about a millisecond per step)")
    parser.add_argument("--json", type=pathlib.Path, help="also write every number (and the curves) to this JSON file")
    add_force_argument(parser)


def run(args: argparse.Namespace) -> int:
    from stdm_drake.learning.evaluation_job import EvaluationJob, evaluate_job
    evaluate_job(EvaluationJob(model=args.checkpoint, dataset=args.dataset, robot=args.robot, split=args.split,
                               horizon=args.horizon, propagation=args.propagation, particles=args.particles,
                               seed=args.seed, implementation=args.implementation, no_plant=args.no_plant,
                               json=args.json, force=args.force))
    return 0
