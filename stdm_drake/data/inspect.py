"""Counts, ranges, tracking errors and noise floors of a dataset (what `stdm-drake inspect` prints)."""
from __future__ import annotations

import numpy as np

from stdm_drake.data.dataset import Dataset, derivative_arrays
from stdm_drake.files import line_text


def tracking_errors(dataset: Dataset) -> dict:
    """Mean squared tracking errors over all samples (data with a plan).

    measured_*: learner's (measured, filtered) state minus the plan; true_*: the plant's state
    minus the plan (simulated data only). Units rad^2 and (rad/s)^2.
    """
    stack = lambda key: np.concatenate([getattr(dataset.trajectory(i), key) for i in range(dataset.num_trajectories)])
    q_plan, v_plan = stack("q_planned"), stack("v_planned")
    errors = dict(measured_q=float(np.mean((stack("q") - q_plan) ** 2)),
                  measured_v=float(np.mean((stack("v") - v_plan) ** 2)))
    if dataset.is_simulated:
        errors.update(true_q=float(np.mean((stack("q_true") - q_plan) ** 2)),
                      true_v=float(np.mean((stack("v_true") - v_plan) ** 2)))
    return errors


def noise_floor(dataset: Dataset, indices=None) -> dict | None:
    """The one-step error floor the sensor sets, q rad^2 and v (rad/s)^2: the MSE of an oracle that knows
    the plant's true change of state over each step but, like any model, starts from the recorded state:
    x̂_{t+1} = x_t + (x^true_{t+1} - x^true_t), whose error is the change of the measurement error
    e = x - x^true over the step. For white noise of std σ on v that is 2σ²; through a w-sample moving
    average 2σ²/w² (the new sample enters, the oldest leaves); 0 for an ideal sensor. No model's one-step
    error on these data can be expected much below it. indices: the trajectories (default all). None for a
    real robot's log (no truth to measure it against)."""
    if not dataset.is_simulated:
        return None
    q_err, v_err = [], []
    for i in (range(dataset.num_trajectories) if indices is None else indices):
        traj = dataset.trajectory(int(i))
        q_err.append(np.diff(traj.q - traj.q_true, axis=0))
        v_err.append(np.diff(traj.v - traj.v_true, axis=0))
    return dict(q=float(np.mean(np.concatenate(q_err) ** 2)), v=float(np.mean(np.concatenate(v_err) ** 2)))


def plan_mismatch(dataset: Dataset, indices=None) -> dict | None:
    """How far the plan's derivatives are from the recorded motion's, as derivative targets (data with a plan):
    per joint the relative RMS difference RMS(planned - recorded) / RMS(recorded) of the accelerations q̈ and
    of the velocities q̇, over the samples of the trajectories `indices` (default all). recorded: the
    simulation's truth ("true") or, for a real robot's log, the smoothed derivatives of its measured angles
    ("smoothed"). 0 is a plan followed exactly; about 1 or more is a plan that says nothing of the
    accelerations (torque dithered every sample, poor tracking, a coarse reference). Returns
    dict(recorded=source, acceleration=mean over joints, velocity=mean over joints, acceleration_per_joint=(n,)
    list, velocity_per_joint=(n,) list), or None without a plan."""
    if not dataset.has_plan:
        return None
    recorded = "true" if dataset.is_simulated else "smoothed"
    indices = range(dataset.num_trajectories) if indices is None else [int(i) for i in indices]
    pairs = [(derivative_arrays(dataset.trajectory(i), "planned"), derivative_arrays(dataset.trajectory(i), recorded))
             for i in indices]
    result = dict(recorded=recorded)
    for position, name in ((0, "velocity"), (1, "acceleration")):
        planned = np.concatenate([plan[position] for plan, _ in pairs])
        actual = np.concatenate([motion[position] for _, motion in pairs])
        scale = np.sqrt(np.mean(actual ** 2, axis=0))
        relative = np.sqrt(np.mean((planned - actual) ** 2, axis=0)) / np.maximum(scale, np.finfo(float).tiny)
        result[name + "_per_joint"] = [float(value) for value in relative]
        result[name] = float(np.mean(relative))
    return result


def tracking_smoothness(dataset: Dataset) -> dict:
    """Per-joint measures of how smoothly the plant followed its plans (tracking data only), (n,) each.

    velocity_error_rms: RMS of the true velocity minus the planned one, rad/s.
    sign_flip_rate: fraction of consecutive sample pairs whose true velocity changes have opposite
    signs (a smooth motion flips rarely, a period-two chatter nearly always; white noise gives 2/3).
    peak_acceleration: largest |true acceleration| over all samples, rad/s^2, and peak_planned_acceleration
    the largest |planned| one.
    """
    errors, flips, pairs, peak, planned_peak = [], 0, 0, 0.0, 0.0
    for i in range(dataset.num_trajectories):
        traj = dataset.trajectory(i)
        errors.append(traj.v_true - traj.v_planned)
        change = np.diff(traj.v_true, axis=0)
        product = change[1:] * change[:-1]
        flips = flips + (product < 0).sum(axis=0)
        pairs += len(product)
        peak = np.maximum(peak, np.abs(traj.qdd).max(axis=0))
        planned_peak = np.maximum(planned_peak, np.abs(traj.qdd_planned).max(axis=0))
    return dict(velocity_error_rms=np.sqrt(np.mean(np.concatenate(errors) ** 2, axis=0)),
                sign_flip_rate=flips / max(pairs, 1), peak_acceleration=peak,
                peak_planned_acceleration=planned_peak)


def summary(dataset: Dataset) -> str:
    meta = dataset.metadata
    steps = [len(dataset.trajectory(i).tau) for i in range(dataset.num_trajectories)]
    groups, counts = np.unique(dataset.groups, return_counts=True)
    lines = [
        f"file            {line_text(dataset.path)}  (sha256 {dataset.sha256[:16]}…)",
        f"protocol        {dataset.protocol}",
        f"trajectories    {dataset.num_trajectories}  steps each {min(steps)}..{max(steps)}  "
        f"transitions {sum(steps)}",
        "groups          " + ", ".join(f"{g}: {c}" for g, c in zip(groups, counts)),
        f"sample period   {dataset.sample_period} s  " + (f"(plant step {meta.plant_time_step} s)" if dataset.is_simulated
                                                        else "(a real robot's log, resampled)"),
        f"seed            {'(none: a log)' if meta.seed is None else meta.seed}   robot model sha256 {str(meta.robot_model_sha256)[:16]}…",
    ]
    if dataset.protocol == "tracking":
        lines.append(f"planner         {meta.section('planner').get('kind')}   controller "
                     f"{meta.section('controller').get('kind')}   sensor {meta.record.get('sensor')}")
    if dataset.is_simulated:
        effects = meta.plant_effects
        lines.append("plant effects   " + ("none (the robot's description as it is)" if effects is None else
                                         effects.summary()))
    else:
        lines += import_lines(meta.section("import"))
    versions = meta.section("package_versions")
    lines.append("packages        " + ", ".join(f"{k} {v}" for k, v in sorted(versions.items())))
    labels = [name.removesuffix("_joint") for name in meta.joint_names or []]
    labels = labels or [f"joint{j}" for j in range(dataset.trajectory(0).q.shape[1])]
    header = f"{'':14s}" + "".join(f"{label:>17s}" for label in labels)
    acceleration = "qdd" if dataset.is_simulated else "qdd_smoothed"
    rows = (("q", "rad"), ("v", "rad/s"), ("tau", "N m"), (acceleration, "rad/s^2"))
    width = max(14, *(len(f"{key} {unit}") + 1 for key, unit in rows))   # (the joints' columns line up on every row)
    lines += ["", "ranges (min..max over all samples)", f"{'':{width}s}" + "".join(f"{label:>21s}" for label in labels)]
    unactuated = set(meta.section("robot").get("unactuated_joints", []))
    actuated = [j for j, name in enumerate(meta.joint_names or labels) if name not in unactuated]
    for key, unit in rows:
        values = np.concatenate([getattr(dataset.trajectory(i), key) for i in range(dataset.num_trajectories)])
        columns = actuated if key == "tau" and len(actuated) == values.shape[1] else range(values.shape[1])
        ranges = {j: f"{f'{lo:.3g}..{hi:.3g}':>21s}" for j, lo, hi in zip(columns, values.min(0), values.max(0))}
        cells = "".join(ranges.get(j, f"{'(none)':>21s}") for j in range(len(labels)))   # 2 spaces at least
        lines.append(f"{key + ' ' + unit:{width}s}{cells}")
    floor = noise_floor(dataset)
    if floor is not None:
        lines += ["", "sensor noise floor (one-step MSE of a model that knows the true change of state, from the "
                  "recorded state)",
                  f"                q {floor['q']:.3e} rad^2   v {floor['v']:.3e} (rad/s)^2"]
    if not dataset.is_simulated and dataset.has_plan:
        errors = tracking_errors(dataset)
        lines += ["", "tracking error of the log (MSE of the measured state against the logged plan)",
                  f"measured        q {errors['measured_q']:.3e} rad^2   v {errors['measured_v']:.3e} (rad/s)^2"]
    if dataset.protocol == "tracking":
        errors = tracking_errors(dataset)
        paper = "; paper's real UR-10: q 1.818e-5 rad^2, v 0.029 (rad/s)^2" if meta.robot_name == "ur10" else ""
        lines += ["", f"tracking error (MSE against the plan{paper})",
                  f"measured        q {errors['measured_q']:.3e} rad^2   v {errors['measured_v']:.3e} (rad/s)^2",
                  f"true            q {errors['true_q']:.3e} rad^2   v {errors['true_v']:.3e} (rad/s)^2"]
        smooth = tracking_smoothness(dataset)
        lines += ["", "smoothness of the true motion (per joint; v error rms in rad/s, dv sign flips as a fraction of "
                  "sample pairs, |qdd| peaks in rad/s^2)", header]
        for key, label in (("velocity_error_rms", "v error rms"), ("sign_flip_rate", "dv sign flips"),
                           ("peak_acceleration", "|qdd| peak"), ("peak_planned_acceleration", "plan |qdd| pk")):
            lines.append(f"{label:14s}" + "".join(f"{value:>17.3g}" for value in smooth[key]))
    return "\n".join(lines)


def import_lines(record: dict) -> list[str]:
    """What `stdm-drake import` recorded about a log (its metadata's "import" section) as summary lines."""
    if not record:
        return ["import          (not recorded)"]
    resampling, pieces = record.get("resampling", {}), record.get("trajectories", {})
    derivatives = record.get("derivatives", {})
    number = lambda value: "-" if value is None else f"{value:.3g}"  # noqa: E731
    exact = lambda value: "-" if value is None else f"{value:.6g}"  # noqa: E731  (as the sample period is printed)
    return [f"imported from   {record.get('format')} {record.get('source')}",
            f"resampling      cubic Hermite on the log's clock; estimated q error "
            f"{number(resampling.get('estimated_q_error_rad'))} rad; log period {exact(resampling.get('log_period_s'))} s, "
            f"stamp jitter RMS {number(resampling.get('jitter_rms_s'))} s",
            f"pieces          {pieces.get('kept')} kept, {pieces.get('dropped_short')} too short dropped; split at "
            f"{pieces.get('gaps')} gaps, {pieces.get('pauses')} pauses, {pieces.get('mode_changes')} mode changes, "
            f"{pieces.get('cuts')} cuts; {pieces.get('rows_not_running')} rows not running left out",
            f"torque          {record.get('torque_source')}",
            "derivatives     " + ("planned, " if derivatives.get("planned") else "")
            + f"measured, smoothed ({derivatives.get('smoothed')})"
            + ("; train's default chooses between planned (when close to the logged motion) and smoothed by "
               "validation" if derivatives.get("planned") else "; train's default: smoothed")]
