"""One identification job, the library's `identify`: a robot's link inertias and joint friction from one of its
datasets, written as an identified robot (.yaml, a model every command takes) with its report beside it (.json).

    job = IdentifyJob(dataset=pathlib.Path("data.h5"), output=pathlib.Path("identified.yaml"))
    report = identify_job(job)        # what identified.json holds
"""
from __future__ import annotations

import dataclasses
import json
import pathlib
import sys

from stdm_drake.errors import InputError, warn
from stdm_drake.files import atomic_paths, json_default, line_text
from stdm_drake.identification.identify import (REGULARIZATIONS, SMOOTHING_WINDOWS, VELOCITY_SCALES, usable_scales,
                                                IdentifySettings, identify, usable_windows)
from stdm_drake.outputs import check_output_file
from stdm_drake.data.compatibility import resolve_robot
from stdm_drake.identification.identified import identified_text


@dataclasses.dataclass
class IdentifyJob:
    """What one identification needs.

    dataset: the robot's .h5 file; output: the identified robot to write (.yaml; the report goes beside it,
    .json); robot: the robot config YAML whose description's parameters are identified (None: the shipped
    preset the dataset was collected with, else the UR-10's; must be the dataset's robot); derivatives:
    "true" (the simulation's states and accelerations) or "smoothed" (central differences of the
    Savitzky-Golay-smoothed angles); None: true for simulated data, smoothed for a log; velocity_scales:
    candidate Coulomb smoothing scales, rad/s (> 0); regularizations: candidate weights toward the
    description's parameters (>= 0); windows: candidate Savitzky-Golay windows in samples (1, or odd >= 5;
    only with smoothed derivatives; None: `SMOOTHING_WINDOWS`); train, val, test: trajectories of each
    split (per group with per_group; None: the defaults, test all the rest); per_group: "on"/"off", split
    per initial-pose group (None: on for tracking data); split_seed: the split's seed (the same split as
    `train` with the same options); progress: the split and each candidate fit as lines on stderr;
    force: replace files stdm-drake did not write."""
    dataset: pathlib.Path
    output: pathlib.Path
    robot: pathlib.Path | None = None
    derivatives: str | None = None
    velocity_scales: tuple = VELOCITY_SCALES
    regularizations: tuple = REGULARIZATIONS
    windows: tuple | None = None
    train: int | None = None
    val: int | None = None
    test: int | None = None
    per_group: str | None = None
    split_seed: int = 0
    progress: bool = True
    force: bool = False


def identify_job(job: IdentifyJob) -> dict:
    """Run `job`: every check first (the output's suffix, the output and report files, the candidate settings,
    the dataset, the derivative source against the windows, the robot fully actuated, the split), then the
    identification, its summary printed and both files written; returns the report (what the .json holds).
    InputError (one line) for a bad input."""
    from stdm_drake.data.dataset import load_dataset   # lazy: h5py
    from stdm_drake.data.dataset import check_split_options, dataset_split   # lazy: h5py
    output = pathlib.Path(job.output)
    if output.suffix.lower() not in (".yaml", ".yml"):
        raise InputError(f"-o/--output {job.output}: an identified robot is a .yaml file")
    report_path = output.with_suffix(".json")
    inputs = [job.dataset, job.robot]
    check_output_file("-o/--output", output, kind="identified", inputs=inputs, force=job.force)
    check_output_file("report", report_path, kind="json", inputs=inputs, force=job.force)
    settings = IdentifySettings(derivative_source=job.derivatives or "true", velocity_scales=tuple(job.velocity_scales),
                                regularizations=tuple(job.regularizations),
                                windows=tuple(job.windows or SMOOTHING_WINDOWS))   # (None: not given)
    settings.validate()     # (before any work: windows, scales and weights)
    check_split_options(job.train, job.val, job.test, job.split_seed)
    dataset = load_dataset(job.dataset)
    if job.derivatives is None and not dataset.is_simulated:
        settings.derivative_source = "smoothed"     # (a log has no true accelerations)
    if settings.derivative_source == "true" and job.windows is not None:
        raise InputError("--windows are the smoothing windows of --derivatives smoothed; with the simulation's true "
                         "derivatives they would be ignored")
    robot = resolve_robot(job.robot, dataset)
    robot.check_fully_actuated("identification")
    usable_scales(settings, robot, given=tuple(job.velocity_scales) != VELOCITY_SCALES)
    beyond = dataset.metadata.plant_effects.beyond_rigid_bodies() if dataset.metadata.plant_effects else []
    if beyond:   # (held-out run 29: a real arm has such effects too, so the fit runs; the user hears what it misses)
        warn(f"stdm-drake identify: warning: {job.dataset}'s plant has {', '.join(beyond)}, which no rigid-body model "
             "holds: the identified robot is the rigid-body fit closest to its data, not a model of those effects")
    split, _ = dataset_split(dataset, job)   # (the job's train, val, test, per_group and split_seed)
    usable_windows(dataset, split, settings, given=job.windows is not None)   # (before the first line: a window no trajectory fits is the refusal)
    if job.progress:
        print(f"identify {robot.name} from {job.dataset}: train {len(split.train)} / val {len(split.val)} / "
              f"test {len(split.test)} trajectories, derivatives {settings.derivative_source}", file=sys.stderr)
    announce = (lambda line: print(line, file=sys.stderr, flush=True)) if job.progress else (lambda line: None)
    identified, report = identify(dataset, robot, split, settings, announce=announce)
    text, report_text = identified_text(identified), json.dumps(report, indent=1, default=json_default) + "\n"
    print(report_summary(report))
    with atomic_paths([report_path, output]) as (report_temp, temp):   # (the pair as one: a signal replaces neither)
        report_temp.write_text(report_text)
        temp.write_text(text)
    print(f"wrote {line_text(job.output)} (use it as a model: evaluate/view {line_text(job.output)}, mpc --model "
          f"NAME={line_text(job.output)}) "
          f"and {report_path}")
    return report


EXACT_TORQUE_ERROR = 1e-9   # a relative torque RMS error at rounding: the model that simulated the data


def report_summary(report: dict) -> str:
    """The report's numbers as lines: the excitation, the chosen setting, the test torque errors and, for
    simulated data, each friction coefficient against the truth."""
    ordinary, chosen = report["least_squares"], report["chosen"]
    lines = [f"excitation: {ordinary['base_parameters']} identifiable (base) parameters of {len(report['parameters'])}, "
             f"condition number {ordinary['condition_number']:.3g} (columns scaled to unit RMS); "
             f"{report['samples_train']} training samples",
             f"chosen on validation: Coulomb velocity scale {chosen['velocity_scale']:g} rad/s, regularization "
             f"{chosen['regularization']:g} (validation torque error {chosen['val_torque_error']:.3g})"]
    if chosen.get("coulomb_held_at_zero"):   # (held-out run 30: viscous friction on a light joint)
        lines.append(f"  Coulomb friction held at 0 on {', '.join(chosen['coulomb_held_at_zero'])}: its fitted explicit "
                     "term was unstable at the plant step (there the data do not tell it from viscous friction)")
    test = report.get("test")
    if test:
        lines.append(f"test torque RMS error / torque RMS: identified (consistent) {test['torque_error']:.3g}, "
                     f"least squares {test['least_squares_torque_error']:.3g}, description "
                     f"{test['description_torque_error']:.3g}; per joint "
                     + ", ".join(f"{value:.3g}" for value in test["torque_error_per_joint"]))
        if "torque_error_on_true_states" in test:
            lines.append(f"  on the true states and accelerations: {test['torque_error_on_true_states']:.3g}")
        lines.append("  (least squares fits the torques best but may give a body no physics has, e.g. a negative "
                     "mass; the identified robot is the best fit among physically consistent ones, the one written)")
        if max(test["torque_error"], test["description_torque_error"]) <= EXACT_TORQUE_ERROR:
            lines.append(f"  both the identified robot and the description predict the test torques to rounding "
                         f"({test['torque_error']:.3g} and {test['description_torque_error']:.3g}): data the "
                         "description simulated, which identification cannot improve on")
        elif test["torque_error"] >= test["description_torque_error"]:
            lines.append(f"warning: the identified robot predicts the test torques no better than the description "
                         f"({test['torque_error']:.3g} against {test['description_torque_error']:.3g}): more or richer "
                         "data (excitation), or keep the description")
        else:
            lines.append(f"  the identified robot predicts the test torques "
                         f"{test['description_torque_error'] / max(test['torque_error'], 1e-300):.3g}x better than "
                         "the description")
    truth = report.get("truth")
    if truth:
        for kind, values in truth["joints"].items():
            pairs = ", ".join(f"{mine:.4g} ({true:.4g})" for mine, true in zip(values["identified"], values["true"]))
            known = [error for error in values["relative_error"] if error is not None]
            worst = f"; largest relative error {max(known):.2%}" if known else ""
            lines.append(f"{kind.replace('_', ' ')} per joint, identified (true): {pairs}{worst}")
    return "\n".join(lines)
