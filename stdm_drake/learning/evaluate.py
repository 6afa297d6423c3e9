"""Test errors of trained STDMs and `stdm-drake evaluate`.

One-step error: predict x_{t+1} from the recorded (x_t, a_t) of every test transition.
Multi-step error: from each test trajectory's x_0, roll the model out open loop under the
recorded torques and compare with the recorded states step by step (paper V.B.3, Fig. 18-19).
Errors are mean squared errors reported separately for joint angles q (rad²) and joint
velocities v ((rad/s)²): the state is x = [q, v], so q is the first half and v the second half.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.files import write_text_atomic
from stdm_drake.outputs import add_force_argument, check_output_file
from stdm_drake.learning.predict import PROPAGATIONS, as_inference_model, predict, rollout

REPORT_STEPS = (1, 5, 10, 20, 50, 100)


def _halves(config) -> int:
    if config.state_dim % 2:
        raise InputError(f"angle/velocity errors need a state [q, v] of even size, the model's has {config.state_dim}")
    return config.state_dim // 2


@dataclasses.dataclass
class OneStepErrors:
    """One-step MSE over N transitions: totals and per joint (n,) for angles q and velocities v."""
    transitions: int
    angle_mse: float
    velocity_mse: float
    angle_mse_per_joint: np.ndarray
    velocity_mse_per_joint: np.ndarray

    def as_dict(self) -> dict:
        return {key: (value.tolist() if isinstance(value, np.ndarray) else value)
                for key, value in dataclasses.asdict(self).items()}


@dataclasses.dataclass
class MultiStepErrors:
    """Open-loop MSE at steps 1..H averaged over B trajectories (curves (H,)), their spread over
    trajectories (std (H,)) and the horizon means."""
    trajectories: int
    horizon: int
    propagation: str
    angle_mse: np.ndarray
    velocity_mse: np.ndarray
    angle_mse_std: np.ndarray
    velocity_mse_std: np.ndarray

    @property
    def angle_mse_mean(self) -> float:
        return float(self.angle_mse.mean())

    @property
    def velocity_mse_mean(self) -> float:
        return float(self.velocity_mse.mean())

    def as_dict(self) -> dict:
        result = {key: (value.tolist() if isinstance(value, np.ndarray) else value)
                  for key, value in dataclasses.asdict(self).items()}
        result.update(angle_mse_mean=self.angle_mse_mean, velocity_mse_mean=self.velocity_mse_mean)
        return result


def one_step_errors(model, states, actions, next_states) -> OneStepErrors:
    """states (N, S) [q, v], actions (N, A), next_states (N, S) -> OneStepErrors of the ensemble mean."""
    engine = as_inference_model(model)
    joints = _halves(engine.config)
    truth = np.asarray(next_states, dtype=np.float64)
    if truth.ndim != 2 or truth.shape[1] != engine.state_dim:
        raise InputError(f"next_states must have shape (N, {engine.state_dim}), got {truth.shape}")
    predicted = predict(engine, states, actions).mean.astype(np.float64)
    if predicted.shape != truth.shape:
        raise InputError(f"states and next_states differ in shape: {predicted.shape} and {truth.shape}")
    squared = (predicted - truth) ** 2
    return OneStepErrors(transitions=len(truth), angle_mse=float(squared[:, :joints].mean()),
                         velocity_mse=float(squared[:, joints:].mean()),
                         angle_mse_per_joint=squared[:, :joints].mean(axis=0),
                         velocity_mse_per_joint=squared[:, joints:].mean(axis=0))


def multi_step_errors(model, initial_states, actions, true_states, *, propagation: str = "mean",
                      particles: int = 20, seed: int = 0) -> MultiStepErrors:
    """initial_states (B, S), actions (B, H, A), true_states (B, H, S) of steps 1..H -> MultiStepErrors
    of the rollout mean."""
    engine = as_inference_model(model)
    joints = _halves(engine.config)
    truth = np.asarray(true_states, dtype=np.float64)
    result = rollout(engine, initial_states, actions, propagation=propagation, particles=particles, seed=seed)
    predicted = result.mean.astype(np.float64)
    if predicted.shape != truth.shape:
        raise InputError(f"rollout has shape {predicted.shape}, true_states {truth.shape}")
    squared = (predicted - truth) ** 2
    per_trajectory_q = squared[..., :joints].mean(axis=-1)     # (B, H)
    per_trajectory_v = squared[..., joints:].mean(axis=-1)
    return MultiStepErrors(trajectories=len(truth), horizon=truth.shape[1], propagation=propagation,
                           angle_mse=per_trajectory_q.mean(axis=0), velocity_mse=per_trajectory_v.mean(axis=0),
                           angle_mse_std=per_trajectory_q.std(axis=0), velocity_mse_std=per_trajectory_v.std(axis=0))


def trajectory_rollout_data(dataset, indices, horizon: int | None = None):
    """(x_0 (B, 12), tau (B, H, 6), [q, v] of steps 1..H (B, H, 12)) for dataset trajectories; H is the
    shortest selected trajectory's length, capped at `horizon`."""
    trajectories = [dataset.trajectory(int(i)) for i in indices]
    if not trajectories:
        raise InputError("no trajectories selected")
    length = min(len(t["tau"]) for t in trajectories)
    if horizon is not None:
        if horizon < 1:
            raise InputError(f"horizon must be >= 1, got {horizon}")
        length = min(length, horizon)
    states = np.stack([np.hstack([t["q"][:length + 1], t["v"][:length + 1]]) for t in trajectories])
    actions = np.stack([t["tau"][:length] for t in trajectories])
    return states[:, 0], actions, states[:, 1:]


# -- `stdm-drake evaluate` --------------------------------------------------------------------------

def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", type=pathlib.Path, help="model checkpoint written by `stdm-drake train`")
    parser.add_argument("dataset", type=pathlib.Path, help="dataset file (.h5)")
    parser.add_argument("--robot", type=pathlib.Path,
                        help="robot config YAML: refuse a dataset collected with another robot (default: no check)")
    parser.add_argument("--split", choices=("test", "val", "train", "all"), default="test",
                        help="trajectories to evaluate: the checkpoint's split of this dataset, or all (default test)")
    parser.add_argument("--horizon", type=int,
                        help="multi-step horizon in steps, at most the trajectories' length (default: that length, "
                             "capped at 100)")
    parser.add_argument("--propagation", choices=PROPAGATIONS, default="mean",
                        help="multi-step propagation: mean, ts1 or tsinf (PETS; default mean)")
    parser.add_argument("--particles", type=int, default=20, help="particles per trajectory for ts1/tsinf")
    parser.add_argument("--seed", type=int, default=0, help="seed of the TS particles")
    parser.add_argument("--json", type=pathlib.Path, help="also write every number (and the curves) to this JSON file")
    add_force_argument(parser)


def run(args: argparse.Namespace) -> int:
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.learning.checkpoint import load_checkpoint

    check_output_file("--json", args.json, kind="json", inputs=[args.checkpoint, args.dataset, args.robot],
                      force=args.force)
    dataset = load_dataset(args.dataset)
    if args.robot is not None:
        from stdm_drake.robot import robot_for
        robot_for(args.robot, dataset)
    checkpoint = load_checkpoint(args.checkpoint)
    checkpoint.check_fits(dataset)
    trained_on_this = checkpoint.trained_on(dataset)
    if args.split == "all":
        indices = np.arange(dataset.num_trajectories)
    else:
        split = checkpoint.split_indices(dataset, args.split)
        if split is None:
            raise InputError(f"{args.dataset} is not the dataset {args.checkpoint} was trained on (sha256 differs), "
                             f"so its {args.split} split does not apply; use --split all")
        indices = np.asarray(split, dtype=int)
        if not len(indices):
            raise InputError(f"the checkpoint's {args.split} split is empty")
    engine = as_inference_model(checkpoint.model)
    transitions = dataset.transitions(indices)
    one_step = one_step_errors(engine, transitions.state, transitions.action, transitions.next_state)
    shortest = min(len(dataset.trajectory(int(i))["tau"]) for i in indices)
    if args.horizon is not None and not 1 <= args.horizon <= shortest:
        raise InputError(f"--horizon must be in 1..{shortest} (the shortest selected trajectory's steps), "
                         f"got {args.horizon}")
    x0, actions, truth = trajectory_rollout_data(dataset, indices, args.horizon or min(shortest, 100))
    multi = multi_step_errors(engine, x0, actions, truth, propagation=args.propagation,
                              particles=args.particles, seed=args.seed)
    config = checkpoint.model_config
    alpha = checkpoint.training_config.alpha if checkpoint.training_config else float("nan")
    name = checkpoint.metadata.model_type or "?"
    print(f"model {name}: {config.hidden_layers}x{config.hidden_width} {config.activation}, "
          f"{config.ensemble_size} member(s), {'probabilistic' if config.probabilistic else 'deterministic'}, "
          f"{'delta' if config.residual else 'direct'}, derivative alpha {alpha:g}")
    print(f"dataset {args.dataset} ({'the training dataset' if trained_on_this else 'another dataset'}); "
          f"split {args.split}: {len(indices)} trajectories, {one_step.transitions} transitions")
    print(f"one-step MSE        q {one_step.angle_mse:.4e} rad^2    v {one_step.velocity_mse:.4e} (rad/s)^2")
    print(f"multi-step MSE ({multi.propagation} propagation, {multi.horizon} steps, "
          f"mean +- std over {multi.trajectories} trajectories):")
    print(f"  {'step':>5}  {'q [rad^2]':>24}  {'v [(rad/s)^2]':>24}")
    shown = sorted({s for s in REPORT_STEPS if s <= multi.horizon} | {multi.horizon})
    for step in shown:
        i = step - 1
        print(f"  {step:>5}  {multi.angle_mse[i]:>11.4e} +- {multi.angle_mse_std[i]:<9.2e}  "
              f"{multi.velocity_mse[i]:>11.4e} +- {multi.velocity_mse_std[i]:<9.2e}")
    print(f"  {'mean':>5}  {multi.angle_mse_mean:>11.4e}{'':13}  {multi.velocity_mse_mean:>11.4e}")
    if args.json:
        report = dict(written_by="stdm-drake evaluate", checkpoint=str(args.checkpoint), dataset=str(args.dataset), dataset_sha256=dataset.sha256,
                      trained_on_this_dataset=trained_on_this, split=args.split,
                      trajectories=[int(i) for i in indices], one_step=one_step.as_dict(), multi_step=multi.as_dict())
        write_text_atomic(args.json, json.dumps(report, indent=2) + "\n")
        print(f"wrote {args.json}")
    return 0
