"""Closed-loop comparison of prediction models under the same MPC on held-out plans (metrics, summary,
plots), what `stdm-drake mpc` runs (`study.run_mpc_study`)."""
import dataclasses
import math

import numpy as np

from stdm_drake.closed_loop.constraints import SLACK_TOLERANCE
from stdm_drake.closed_loop.mpc import MpcConfig, MpcLog, Reference, run_closed_loop
from stdm_drake.closed_loop.optimizer import OptimizerSettings
from stdm_drake.dynamics.physics import PlantModel
from stdm_drake.errors import InputError
from stdm_drake.report import markdown_table
from stdm_drake.robots.plant import Dynamics, PlantConfig, joint_limits
from stdm_drake.robots.robot import Robot
from stdm_drake.files import atomic_path
from stdm_drake.dynamics.model_files import load_model


@dataclasses.dataclass
class ClosedLoopResult:
    """One closed-loop run: model name, reference index, and its metrics (units in the names)."""
    model: str
    trajectory: int
    q_mse_rad2: float
    v_mse: float
    torque_rms_nm: float
    effort_beyond_gravity_rms_nm: float
    limit_violations: int
    fallbacks: int
    constraint_active_steps: int   # control steps with a torque bound or a state limit active in the MPC's solution
    slack_steps: int               # control steps whose solution accepted a crossing of a state limit (its slack)
    solve_ms_mean: float
    solve_ms_p95: float
    steps: int
    q_error: list  # per-step RMS joint-angle error (rad), for plots
    implementation: str = ""   # the control step's (`mpc.control_step_implementation`)


def closed_loop_metrics(name: str, index: int, log: MpcLog, reference: Reference, limits, gravity) -> ClosedLoopResult:
    """gravity: (N, n) torque holding the arm at each reference sample (N >= the run's steps)."""
    states, torques = np.array(log.state), np.array(log.torque)
    steps, n = len(states), torques.shape[1]
    error = states - reference.window(0, steps)
    q_error, v_error = error[:, :n], error[:, n:]
    finite = np.all(np.isfinite(states), axis=1)
    outside = ((states[:, :n] < limits.position_lower) | (states[:, :n] > limits.position_upper)
               | (np.abs(states[:, n:]) > limits.velocity))
    solve_ms = 1e3 * np.array(log.solve_seconds)
    return ClosedLoopResult(
        model=name, trajectory=index,
        q_mse_rad2=float(np.mean(q_error ** 2)), v_mse=float(np.mean(v_error ** 2)),
        torque_rms_nm=float(np.sqrt(np.mean(torques ** 2))),
        effort_beyond_gravity_rms_nm=float(np.sqrt(np.mean((torques - gravity[:steps]) ** 2))),
        limit_violations=int(np.count_nonzero(outside.any(axis=1) | ~finite)),
        fallbacks=int(np.count_nonzero(log.fallback)),
        constraint_active_steps=int(np.count_nonzero(log.constraint_active)),
        slack_steps=int(np.count_nonzero(np.asarray(log.slack) > SLACK_TOLERANCE)),
        solve_ms_mean=float(solve_ms.mean()), solve_ms_p95=float(np.percentile(solve_ms, 95)), steps=steps,
        q_error=np.sqrt(np.mean(q_error ** 2, axis=1)).tolist(), implementation=log.implementation)


def compare_controllers(models: list, references: list[tuple[int, Reference]], config: MpcConfig,
                        plant_config: PlantConfig | None = None, progress: bool = True, recorder=None, *,
                        robot: Robot, optimizer: OptimizerSettings | None = None, announce=None,
                        announce_after: float = 20.0, title: str = "mpc"):
    """Run plant + MPC(model) on every reference for every model (the plant of `robot`); returns
    [ClosedLoopResult]. With the plant effects' torque noise, a reference's index seeds its draws, so
    every model meets the same noise on the same plan (paired comparisons).

    optimizer: the optimizer's settings every closed loop uses (`rti.Rti`, `ilqr.Ilqr` or any
    `OptimizerSettings`), in place of those of `config` (None: the config's own, `config.optimizer`).

    recorder: an optional ghost TrajectoryRecorder; each run is added (robot = plant, ghost = reference).
    announce: called with one line after a model's first plan when its other plans will take more than
    `announce_after` s (the time of that plan and of its control steps, and the estimate), so that a
    long run says so even without the progress bar (progress=False).
    """
    import time

    from tqdm import tqdm
    if optimizer is not None:
        config = dataclasses.replace(config, optimizer=optimizer)
    config.validate()
    dynamics = Dynamics(robot)
    n = dynamics.robot.num_joints
    limits = joint_limits(dynamics.plant)
    results = []
    bar = tqdm(total=len(models) * len(references), desc=title, unit="run", disable=not progress)
    # gravity at each reference sample, held past its end like the reference (a run may outlast it)
    horizon = max(len(reference.q) for _, reference in references) + 1
    gravity = {index: np.array([dynamics.gravity_torque(q) for q in reference.window(0, horizon)[:, :n]])
               for index, reference in references}
    for model in models:
        for number, (index, reference) in enumerate(references):
            start = time.perf_counter()
            log = run_closed_loop(model, reference, config, plant_config, robot=robot, noise_seed=index)
            results.append(closed_loop_metrics(model.name, index, log, reference, limits, gravity[index]))
            elapsed, remaining = time.perf_counter() - start, len(references) - 1
            if number == 0 and announce is not None and elapsed * remaining > announce_after:
                announce(f"mpc: model {model.name}: {elapsed:.1f} s for the first plan ({1e3 * elapsed / max(len(log.state), 1):.0f} "
                         f"ms per control step); about {elapsed * remaining / 60:.1f} min more for its other {remaining} plans")
            if recorder is not None:
                q = np.array(log.state)[:, :n]
                recorder.add(q, reference.window(0, len(q))[:, :n])
            bar.update()
    bar.close()
    return results


def summarize(results: list[ClosedLoopResult], sample_period: float) -> list[dict]:
    """One row per model: means over references (solve p95 over all control steps' p95s)."""
    rows = []
    for name in dict.fromkeys(result.model for result in results):
        mine = [result for result in results if result.model == name]
        p95 = max(result.solve_ms_p95 for result in mine)
        rows.append(dict(
            model=name, runs=len(mine),
            q_mse_rad2=float(np.mean([r.q_mse_rad2 for r in mine])),
            v_mse=float(np.mean([r.v_mse for r in mine])),
            effort_beyond_gravity_rms_nm=float(np.mean([r.effort_beyond_gravity_rms_nm for r in mine])),
            limit_violations=int(sum(r.limit_violations for r in mine)),
            fallbacks=int(sum(r.fallbacks for r in mine)),
            constraint_active_steps=int(sum(r.constraint_active_steps for r in mine)),
            slack_steps=int(sum(r.slack_steps for r in mine)), steps=int(sum(r.steps for r in mine)),
            solve_ms_mean=float(np.mean([r.solve_ms_mean for r in mine])), solve_ms_p95=float(p95),
            faster_than_real_time=bool(p95 < 1e3 * sample_period), control_step=mine[0].implementation))
    plant = next((row for row in rows if row["model"] == PlantModel.name), None)
    for row in rows:  # tracking error relative to the plant-as-model MPC on the same plans
        known = plant is not None and plant["q_mse_rad2"] > 0
        row["q_mse_vs_plant"] = float(row["q_mse_rad2"] / plant["q_mse_rad2"]) if known else None
    return rows


def real_time_lines(rows: list[dict], sample_period: float) -> list[str]:
    """One line per model: its control step's implementation, its solve time per control step against the control
    period, "real time" when every plan's p95 is within the period, else "not real time", and the fastest rate
    its measured p95 allows ("real time at N Hz": 1 / p95 rounded down to two digits at least: to 10 Hz from 100 Hz,
    to 1 Hz from 10 Hz, to 0.1 Hz below)."""
    period = 1e3 * sample_period
    lines = []
    for row in rows:
        hertz = 1e3 / row["solve_ms_p95"] if row["solve_ms_p95"] > 0 else 0.0
        step_hz = 10.0 if hertz >= 100 else 1.0 if hertz >= 10 else 0.1   # (never "0 Hz", nor 19.6 Hz as "10")
        rate = f"{math.floor(round(hertz / step_hz, 9)) * step_hz:.{1 if step_hz < 1 else 0}f}"
        step = f" ({row['control_step']} control step)" if row.get("control_step") else ""
        lines.append(f"{row['model']}{step}: solve {row['solve_ms_mean']:.2f} ms mean, {row['solve_ms_p95']:.2f} ms p95 "
                     f"per control step against the {period:g} ms control period: "
                     + ("real time" if row["solve_ms_p95"] <= period else
                        f"not real time (p95 {row['solve_ms_p95'] / period:.1f}x the period)")
                     + f"; real time at {rate} Hz by its p95")
    return lines


def constraint_lines(rows: list[dict], constraints) -> list[str]:
    """One line per model: how its MPC met the robot's limits (`constraints.Constraints`): the control steps with a
    limit active in the solution and with slack used, beside the steps that crossed the plant's limits."""
    constraints.validate()
    if constraints.mode == "off":
        how = "constraints off (torques clipped after the solve, state limits not in the optimizer)"
    else:
        how = (f"torques a hard box in the optimizer, position and velocity limits {constraints.mode} "
               f"({constraints.position_margin:g} rad and {constraints.velocity_margin:g} rad/s inside)")
    return [f"{row['model']}: {how}: a limit active on {row['constraint_active_steps']} of {row['steps']} control "
            f"steps, slack used on {row['slack_steps']}; the plant's limits crossed on {row['limit_violations']}"
            for row in rows]


def summary_table(rows: list[dict]) -> str:
    """The `summarize` rows as a Markdown table."""
    header = ["model", "runs", "q MSE (rad²)", "q MSE / plant MPC", "q̇ MSE ((rad/s)²)",
              "effort beyond g, RMS (N m)", "limit violations", "constraint active (steps)", "slack used (steps)",
              "fallbacks", "solve mean (ms)", "solve p95 (ms)", "faster than real time"]
    return markdown_table(header, [
        [row["model"], row["runs"], f"{row['q_mse_rad2']:.3g}",
         "" if row.get("q_mse_vs_plant") is None else f"{row['q_mse_vs_plant']:.3g}", f"{row['v_mse']:.3g}",
         f"{row['effort_beyond_gravity_rms_nm']:.3g}", row["limit_violations"], row["constraint_active_steps"],
         row["slack_steps"], row["fallbacks"],
         f"{row['solve_ms_mean']:.2f}", f"{row['solve_ms_p95']:.2f}", "yes" if row["faster_than_real_time"] else "no"]
        for row in rows])


def plot_results(results: list[ClosedLoopResult], sample_period: float, path) -> None:
    """Per-step RMS joint-angle error of the first reference, one line per model (PNG at `path`, atomically)."""
    with atomic_path(path) as temp:
        draw_results(results, sample_period, temp)


def draw_results(results: list[ClosedLoopResult], sample_period: float, file) -> None:
    """`plot_results`' figure written to `file` as it is (a temporary file of a set written as one)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    first = results[0].trajectory
    figure, axes = plt.subplots(1, 2, figsize=(11, 4))
    for result in results:
        if result.trajectory == first:
            t = np.arange(len(result.q_error)) * sample_period
            axes[0].semilogy(t, np.maximum(result.q_error, 1e-12), label=result.model)
    axes[0].set(xlabel="time (s)", ylabel="RMS joint-angle error (rad)", title=f"MPC tracking, plan {first}")
    axes[0].legend()
    names = list(dict.fromkeys(result.model for result in results))
    means = [np.mean([r.q_mse_rad2 for r in results if r.model == name]) for name in names]
    axes[1].bar(names, means)
    axes[1].set(yscale="log", ylabel="q MSE (rad²)", title="mean over held-out plans")
    figure.tight_layout()
    figure.savefig(file, format="png", dpi=110)
    plt.close(figure)


def held_out_references(dataset, checkpoints: list, count: int) -> list[tuple[int, Reference]]:
    """`count` held-out trajectories as references: their *planned* q, v (tracking data) or
    recorded q, v (excitation data). Held out = in no checkpoint's training or validation set
    (when a checkpoint was trained on this dataset), test-split trajectories first."""
    seen, test = set(), []
    for checkpoint in checkpoints:
        if checkpoint.split_indices(dataset, "test") is not None:
            seen |= set(checkpoint.split_indices(dataset, "train")) | set(checkpoint.split_indices(dataset, "val"))
            test += [index for index in checkpoint.split_indices(dataset, "test") if index not in test]
    rest = [index for index in range(dataset.num_trajectories - 1, -1, -1) if index not in seen and index not in test]
    indices = [index for index in test if index not in seen] + rest
    if not indices:
        raise InputError(f"{dataset.path}: every trajectory was used to train or validate the models; "
                         "no held-out plan to track")
    return [(index, reference_of(dataset, index)) for index in indices[:count]]


def tuning_references(dataset, checkpoints: list, count: int, held_out: list[int]) -> list[tuple[int, Reference]]:
    """`count` plans to tune the MPC on (as `held_out_references` gives them), never one of `held_out`
    (the test plans) nor one a checkpoint trained on: the checkpoints' validation plans (of this
    dataset) first, then any other trajectory, from the start of the file."""
    trained, validation = set(), []
    for checkpoint in checkpoints:
        if checkpoint.split_indices(dataset, "train") is not None:
            trained |= set(checkpoint.split_indices(dataset, "train"))
            validation += [index for index in checkpoint.split_indices(dataset, "val") if index not in validation]
    excluded = trained | set(held_out)
    indices = [index for index in validation if index not in excluded]
    indices += [index for index in range(dataset.num_trajectories) if index not in excluded and index not in indices]
    if len(indices) < count:
        raise InputError(f"--tune {count}: {dataset.path} has only {len(indices)} plans that are neither tracked "
                         "(held out) nor trained on")
    return [(index, reference_of(dataset, index)) for index in indices[:count]]


def spec_models(specs: list, sample_period: float, plant_config: PlantConfig, *, robot: Robot) -> list:
    """The prediction models of `specs` ((name, path): a checkpoint `train` wrote or a robot `identify` wrote;
    None for the robot's description as a plant model ("plant") and "true" for the plant of `plant_config`
    itself ("true-plant")); plant models and identified robots predict with the "rk4" integrator (exact
    Jacobians, microseconds per step: `PlantModel`)."""
    return [PlantModel(sample_period, robot=robot, integrator="rk4") if path is None else
            PlantModel(sample_period, plant_config, robot=robot, integrator="rk4") if path == "true" else
            load_model(path, robot, name=name, for_control=True) for name, path in specs]


def reference_of(dataset, index: int) -> Reference:
    """Trajectory `index` as a reference: its planned q, v (data with plans) or recorded q, v (the true ones
    of excitation data, the measured ones of a log without the plan)."""
    traj = dataset.trajectory(index)
    if traj.has_plan:
        return Reference(q=traj.q_planned, v=traj.v_planned)
    if traj.is_simulated:
        return Reference(q=traj.q_true, v=traj.v_true)
    return Reference(q=traj.q, v=traj.v)


FALLBACK_FRACTION = 0.5   # a model's loops on gravity compensation on more of their steps than this are no result


def failed_steps(results: list, fraction: float = FALLBACK_FRACTION) -> int:
    """Steps of `results` (one model's loops) that make them no result (`closed_loop_failures`): outside the limits,
    and on gravity compensation where that is more than `fraction` of them."""
    steps = sum(result.steps for result in results)
    fallbacks = sum(result.fallbacks for result in results)
    return int(sum(result.limit_violations for result in results) + (fallbacks if fallbacks > fraction * steps else 0))


def closed_loop_failures(results: list[ClosedLoopResult], fraction: float = FALLBACK_FRACTION, note: str = "",
                         model_notes: dict | None = None) -> list[str]:
    """One line per model whose closed loop is not a result: it left the robot's limits (a state outside the
    position or velocity limits, or not finite, on any step of any plan) or fell back to gravity compensation
    (non-finite predictions) on more than `fraction` of its steps, both in one line where both hold; `note` (a
    setting the failure may come from, `failure_causes.loop_causes`) ends each line, after the model's own in
    `model_notes` (name: clause)."""
    failures = []
    for name in dict.fromkeys(result.model for result in results):
        said = "; ".join(filter(None, [(model_notes or {}).get(name, ""), note]))
        runs = [result for result in results if result.model == name]
        violations, fallbacks = sum(run.limit_violations for run in runs), sum(run.fallbacks for run in runs)
        steps = sum(run.steps for run in runs)
        plans = sum(1 for run in runs if run.limit_violations)
        clauses = []
        if violations:
            clauses.append(f"left the robot's joint limits on {violations} of {steps} steps "
                           f"({plans} of {len(runs)} plans)")
        if fallbacks > fraction * steps:
            clauses.append(f"fell back to gravity compensation on {fallbacks} of {steps} steps (its predictions were "
                           "not finite); its row is not a result")
        if clauses:
            failures.append(f"model {name} " + " and ".join(clauses) + (f"; {said}" if said else ""))
    return failures
