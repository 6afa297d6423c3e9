"""`stdm-drake evaluate`: one-step and multi-step test errors of a trained model on a dataset, beside the
physics baselines."""
from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.files import finite_json, write_text_atomic
from stdm_drake.learning.evaluate import (
    REPORT_STEPS, compare_with_baselines, physics_baselines, trajectory_rollout_data
)
from stdm_drake.learning.predict import PROPAGATIONS
from stdm_drake.outputs import add_force_argument, check_output_file


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
    parser.add_argument("--no-plant", action="store_true",
                        help="leave out the plant baseline (the robot's rigid-body plant stepping the recorded torque: "
                             "about a millisecond per step)")
    parser.add_argument("--json", type=pathlib.Path, help="also write every number (and the curves) to this JSON file")
    add_force_argument(parser)


def control_plant_difference(simulator, rk4, transitions, count: int = 2000) -> str:
    """One line: the one-step MSE of q and v between the MPC's plant model (RK4 steps of the continuous
    dynamics) and the simulator's discrete plant, on up to `count` of the transitions (evenly spaced)."""
    rows = np.unique(np.linspace(0, len(transitions.state) - 1, min(count, len(transitions.state))).astype(int))
    x, u = transitions.state[rows], transitions.action[rows]
    difference = rk4.step(x, u) - simulator.step(x, u)
    n = x.shape[1] // 2
    return (f"(plant (RK4): the plant model the MPC predicts with, the description's continuous dynamics in "
            f"{rk4.substeps} RK4 step(s) per period with exact Jacobians; its one-step difference from the simulator's "
            f"discrete plant on {len(rows)} of these transitions: q MSE {np.mean(difference[:, :n] ** 2):.3e} rad^2, "
            f"v MSE {np.mean(difference[:, n:] ** 2):.3e} (rad/s)^2)")


def run(args: argparse.Namespace) -> int:
    from stdm_drake.data.compatibility import robot_for
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.commands.arguments import command_model, load_model_file, model_description
    from stdm_drake.learning.physics import FLOOR_FACTOR, LEARNED_FACTOR
    from stdm_drake.robots.robot import UR10_CONFIG

    if args.propagation == "mean" and (args.particles is not None or args.seed is not None):
        raise InputError("--particles and --seed are for --propagation ts1 or tsinf (trajectory sampling); mean "
                         "propagation uses neither")
    particles, seed = (20 if args.particles is None else args.particles), (0 if args.seed is None else args.seed)
    check_output_file("--json", args.json, kind="json", inputs=[args.checkpoint, args.dataset, args.robot],
                      force=args.force)
    dataset = load_dataset(args.dataset)
    if args.robot is not None:
        robot = robot_for(args.robot, dataset)
    else:  # the shipped preset the dataset records, else the UR-10's; another robot's data get no plant baseline
        from stdm_drake.data.compatibility import shipped_preset_of
        try:
            robot = robot_for(shipped_preset_of(dataset) or UR10_CONFIG, dataset)
        except InputError:
            robot = None
    source = load_model_file(args.checkpoint)   # a checkpoint or an identified robot: which dataset and split
    source.check_fits(dataset)
    trained_on_this = source.trained_on(dataset)
    if args.split == "all":
        indices = np.arange(dataset.num_trajectories)
    else:
        split = source.split_indices(dataset, args.split)
        if split is None:
            raise InputError(f"{args.dataset} is not the dataset {args.checkpoint} was trained on (sha256 differs), "
                             f"so its {args.split} split does not apply; use --split all")
        indices = np.asarray(split, dtype=int)
        if not len(indices):
            raise InputError(f"the model's {args.split} split is empty")
    shortest = min(dataset.trajectory(int(i)).num_steps for i in indices)
    if args.horizon is not None and not 1 <= args.horizon <= shortest:
        raise InputError(f"--horizon must be in 1..{shortest} (the shortest selected trajectory's steps), "
                         f"got {args.horizon}")
    model = command_model(source, robot, check_robot=robot is not None)
    transitions = dataset.transitions(indices)
    rollout_data = trajectory_rollout_data(dataset, indices, args.horizon or min(shortest, 100))
    plant = robot is not None and not args.no_plant
    baselines = physics_baselines(dataset.sample_period, model.state_dim, model.action_dim, robot=robot, plant=plant)
    if plant:   # the plant model the MPC predicts with, beside the simulator's
        from stdm_drake.learning.physics import PlantModel
        baselines.append(PlantModel(dataset.sample_period, robot=robot, integrator="rk4", name="plant (RK4)"))
    from stdm_drake.data.inspect import noise_floor
    floor = noise_floor(dataset, indices)
    rows = compare_with_baselines([model] + baselines, transitions, rollout_data, propagation=args.propagation,
                                  particles=particles, seed=seed, noise_floor=floor)
    print(model_description(model))
    print(f"dataset {args.dataset} ({'the training dataset' if trained_on_this else 'another dataset'}); "
          f"split {args.split}: {len(indices)} trajectories, {rows[0].one_step.transitions} transitions")
    multi = rows[0].multi_step
    shown = sorted({s for s in REPORT_STEPS if s <= multi.horizon} | {multi.horizon})
    print(f"one-step MSE and open-loop ({multi.propagation} propagation, {multi.horizon} steps, mean over "
          f"{multi.trajectories} trajectories) q MSE at step k, beside the physics baselines:")
    header = f"  {'model':<12} {'q [rad^2]':>10} {'v [(rad/s)^2]':>13}  " + " ".join(f"{'q@' + str(k):>9}" for k in shown)
    print(header)
    for row in rows:
        print(f"  {row.name[:12]:<12} {row.one_step.angle_mse:>10.3e} {row.one_step.velocity_mse:>13.3e}  "
              + " ".join(f"{row.multi_step.angle_mse[k - 1]:>9.2e}" for k in shown))
    if not plant:
        print("  (no plant baseline: " + ("--no-plant" if args.no_plant else "pass the dataset's robot with --robot")
              + ")")
    else:
        if dataset.metadata.plant_effects is not None:
            print("  (plant: the robot's description, the nominal model; the data come from a plant with effects it "
                  f"lacks: {dataset.metadata.plant_effects.summary()})")
        print("  " + control_plant_difference(baselines[-2], baselines[-1], transitions))
    learned = rows[0]
    if floor and (floor["q"] > 0 or floor["v"] > 0):
        print(f"  {'noise floor':<12} {floor['q']:>10.3e} {floor['v']:>13.3e}  (a model that knows the true change "
              f"of state, from the recorded state; {model.name} is at {learned.floor_ratio_q or 0:.3g}x / "
              f"{learned.floor_ratio_v or 0:.3g}x of it)")
    print(f"{model.name} against the physics-free baselines: one-step q {learned.ratio_q:.3g}x better than the Euler "
          f"step, v {learned.ratio_v:.3g}x better than 'v unchanged' -> {learned.verdict}"
          + ("" if learned.verdict.startswith("learned") else
             f" (needs {LEARNED_FACTOR:g}x in both, or within {FLOOR_FACTOR:g}x of the noise floor; comparisons "
             "with other such models are uninformative)"))
    print(f"multi-step MSE of {model.name} (mean +- std over {multi.trajectories} trajectories):")
    print(f"  {'step':>5}  {'q [rad^2]':>24}  {'v [(rad/s)^2]':>24}")
    for step in shown:
        i = step - 1
        print(f"  {step:>5}  {multi.angle_mse[i]:>11.4e} +- {multi.angle_mse_std[i]:<9.2e}  "
              f"{multi.velocity_mse[i]:>11.4e} +- {multi.velocity_mse_std[i]:<9.2e}")
    print(f"  {'mean':>5}  {multi.angle_mse_mean:>11.4e}{'':13}  {multi.velocity_mse_mean:>11.4e}")
    for row in rows:
        if row.multi_step.diverged:
            print(f"{row.name}: the open-loop rollout diverged (its squared error beyond the finite numbers) in "
                  f"{row.multi_step.diverged} of {row.multi_step.trajectories} trajectories, the first at step "
                  f"{row.multi_step.first_diverged_step}; its multi-step MSE is infinite from there"
                  + (" (null in --json)" if args.json else ""))
    if args.json:
        report = dict(written_by="stdm-drake evaluate", checkpoint=str(args.checkpoint), dataset=str(args.dataset),
                      dataset_sha256=dataset.sha256, trained_on_this_dataset=trained_on_this, split=args.split,
                      structure=model.structure.as_dict() if hasattr(model, "structure") else None,
                      model=model_description(model), trajectories=[int(i) for i in indices],
                      one_step=learned.one_step.as_dict(), multi_step=multi.as_dict(),
                      ratio_to_euler_q=learned.ratio_q, ratio_to_velocity_unchanged_v=learned.ratio_v,
                      over_noise_floor_q=learned.floor_ratio_q, over_noise_floor_v=learned.floor_ratio_v,
                      noise_floor=floor, verdict=learned.verdict, baselines=[row.as_dict() for row in rows[1:]])
        write_text_atomic(args.json, json.dumps(finite_json(report), indent=2, allow_nan=False) + "\n")
        print(f"wrote {args.json}")
    return 0
