"""One evaluation job, the library's `evaluate`: a model file's one-step and multi-step test errors on a
dataset, beside the physics baselines, printed and returned (and written as JSON)."""
from __future__ import annotations

import dataclasses
import json
import pathlib

import numpy as np

from stdm_drake.errors import InputError, check_seed
from stdm_drake.files import finite_json, line_text, write_text_atomic
from stdm_drake.dynamics.compiled_core import IMPLEMENTATIONS
from stdm_drake.learning.evaluate import (REPORT_STEPS, compare_with_baselines, physics_baselines,
                                          trajectory_rollout_data, times_better)
from stdm_drake.outputs import check_output_file
from stdm_drake.learning.learned_model import LearnedModel
from stdm_drake.dynamics.model_files import load_model, load_model_file
from stdm_drake.dynamics.physics import PlantModel
from stdm_drake.dynamics.verdict import FLOOR_FACTOR, LEARNED_FACTOR, floor_not_held_note


@dataclasses.dataclass
class EvaluationJob:
    """What one evaluation needs.

    model: a model file (a checkpoint `train` wrote, .pt, or an identified robot `identify` wrote, .yaml);
    dataset: the .h5 file; robot: its config YAML (None: the shipped preset the dataset was collected with,
    else the UR-10's where the dataset is its; another robot's data then get no plant baseline); split:
    "test", "val", "train" (the model's split of this dataset) or "all"; horizon: multi-step steps (None:
    the shortest trajectory's length, capped at 100); propagation "mean", "ts1" or "tsinf" with `particles`
    and `seed` (None: 20 and 0; refused with "mean"); implementation: the learned model's rollout code,
    "compiled" (the compiled core where it covers the model) or "numpy" (the reference); no_plant: leave out the
    plant baselines; json: also write the report there; force: replace a JSON file stdm-drake did not write."""
    model: pathlib.Path
    dataset: pathlib.Path
    robot: pathlib.Path | None = None
    split: str = "test"
    horizon: int | None = None
    propagation: str = "mean"
    particles: int | None = None
    seed: int | None = None
    implementation: str = "compiled"
    no_plant: bool = False
    json: pathlib.Path | None = None
    force: bool = False


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


def rollout_code(model, propagation: str, implementation: str) -> str:
    """Which code ran a model's open-loop rollouts: "compiled", or "numpy" with why where the compiled core was
    not asked for or does not cover the model or the propagation (`LearnedModel.rollout_implementation`)."""
    if not isinstance(model, LearnedModel):
        return f"numpy ({type(model).__name__})"
    if implementation == "numpy":
        return "numpy (--implementation numpy)"
    if propagation != "mean":
        return f"numpy ({propagation} propagation)"
    return model.rollout_implementation


def evaluate_job(job: EvaluationJob) -> dict:
    """Run `job` (checks first), print its tables and verdict, and return the report (what --json writes)."""
    from stdm_drake.data.compatibility import resolve_robot, robot_for   # lazy: pydrake
    from stdm_drake.data.dataset import load_dataset   # lazy: pydrake, h5py

    if job.propagation == "mean" and (job.particles is not None or job.seed is not None):
        raise InputError("--particles and --seed are for --propagation ts1 or tsinf (trajectory sampling); mean "
                         "propagation uses neither")
    particles, seed = (20 if job.particles is None else job.particles), (0 if job.seed is None else job.seed)
    check_seed("--seed", seed)
    if job.implementation not in IMPLEMENTATIONS:
        raise InputError(f"--implementation must be one of {', '.join(IMPLEMENTATIONS)}, got {job.implementation!r}")
    check_output_file("--json", job.json, kind="json", inputs=[job.model, job.dataset, job.robot],
                      force=job.force)
    dataset = load_dataset(job.dataset)
    if job.robot is not None:
        robot = robot_for(job.robot, dataset)
    else:  # the shipped preset the dataset records, else the UR-10's; another robot's data get no plant baseline
        try:
            robot = resolve_robot(None, dataset)
        except InputError:
            robot = None
    source = load_model_file(job.model)   # a checkpoint or an identified robot: which dataset and split
    source.check_fits(dataset)
    trained_on_this = source.trained_on(dataset)
    if job.split == "all":
        indices = np.arange(dataset.num_trajectories)
    else:
        split = source.split_indices(dataset, job.split)
        if split is None:
            raise InputError(f"{job.dataset} is not the dataset {job.model} was trained on (sha256 differs), "
                             f"so its {job.split} split does not apply; use --split all")
        indices = np.asarray(split, dtype=int)
        if not len(indices):
            raise InputError(f"the model's {job.split} split is empty")
    shortest = min(dataset.trajectory(int(i)).num_steps for i in indices)
    if job.horizon is not None and not 1 <= job.horizon <= shortest:
        raise InputError(f"--horizon must be in 1..{shortest} (the shortest selected trajectory's steps), "
                         f"got {job.horizon}")
    model = load_model(source, robot, check_robot=robot is not None)
    transitions = dataset.transitions(indices)
    rollout_data = trajectory_rollout_data(dataset, indices, job.horizon or min(shortest, 100))
    plant = robot is not None and not job.no_plant
    baselines = physics_baselines(dataset.sample_period, model.state_dim, model.action_dim, robot=robot, plant=plant,
                                  plant_config=dataset.metadata.plant_config(effects=False))
    if plant:   # the plant model the MPC predicts with, beside the simulator's
        baselines.append(PlantModel(dataset.sample_period, robot=robot, integrator="rk4", name="plant (RK4)"))
    from stdm_drake.data.inspect import noise_floor   # lazy: pydrake, h5py
    floor = noise_floor(dataset, indices)
    rows = compare_with_baselines([model] + baselines, transitions, rollout_data, propagation=job.propagation,
                                  particles=particles, seed=seed, noise_floor=floor,
                                  implementation=job.implementation)
    rollouts = rollout_code(model, job.propagation, job.implementation)
    print(model.describe())
    print(f"dataset {job.dataset} ({'the training dataset' if trained_on_this else 'another dataset'}); "
          f"split {job.split}: {len(indices)} trajectories, {rows[0].one_step.transitions} transitions")
    multi = rows[0].multi_step
    shown = sorted({s for s in REPORT_STEPS if s <= multi.horizon} | {multi.horizon})
    print(f"one-step MSE and open-loop ({multi.propagation} propagation, {multi.horizon} steps, mean over "
          f"{multi.trajectories} trajectories; {model.name}'s rollouts: {rollouts}) q MSE at step k, beside the "
          "physics baselines:")
    header = f"  {'model':<12} {'q [rad^2]':>10} {'v [(rad/s)^2]':>13}  " + " ".join(f"{'q@' + str(k):>9}" for k in shown)
    print(header)
    for row in rows:
        print(f"  {row.name[:12]:<12} {row.one_step.angle_mse:>10.3e} {row.one_step.velocity_mse:>13.3e}  "
              + " ".join(f"{row.multi_step.angle_mse[k - 1]:>9.2e}" for k in shown))
    by_name = {row.name: row for row in rows}
    if {"Euler step", "stays put"} <= set(by_name) and np.array_equal(by_name["Euler step"].multi_step.angle_mse,
                                                                         by_name["stays put"].multi_step.angle_mse):
        print("  (the Euler step and 'stays put' coincide open loop: the trajectories start at rest, so 'v "
              "unchanged' keeps v = 0 and q where it started; one step ahead they differ)")
    if not plant:
        print("  (no plant baseline: " + ("--no-plant" if job.no_plant else "pass the dataset's robot with --robot")
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
        note = floor_not_held_note(learned.ratio_q, learned.ratio_v, learned.floor_ratio_q, learned.floor_ratio_v)
        if note:
            print(f"  {note}")
    print(f"{model.name} against the physics-free baselines: one-step q {times_better(learned.ratio_q)} than the Euler "
          f"step, v {times_better(learned.ratio_v)} than 'v unchanged' -> {learned.verdict}"
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
                  + (" (null in --json)" if job.json else ""))
    report = dict(written_by="stdm-drake evaluate", checkpoint=str(job.model), dataset=str(job.dataset),
                  dataset_sha256=dataset.sha256, robot=None if robot is None else robot.record(),
                  trained_on_this_dataset=trained_on_this, split=job.split,
                  structure=model.structure.as_dict() if hasattr(model, "structure") else None,
                  model=model.describe(), rollout_implementation=rollouts, trajectories=[int(i) for i in indices],
                  one_step=learned.one_step.as_dict(), multi_step=multi.as_dict(),
                  ratio_to_euler_q=learned.ratio_q, ratio_to_velocity_unchanged_v=learned.ratio_v,
                  over_noise_floor_q=learned.floor_ratio_q, over_noise_floor_v=learned.floor_ratio_v,
                  noise_floor=floor, verdict=learned.verdict, baselines=[row.as_dict() for row in rows[1:]])
    if job.json:
        write_text_atomic(job.json, json.dumps(finite_json(report), indent=2, allow_nan=False) + "\n")
        print(f"wrote {line_text(job.json)}")
    return report
