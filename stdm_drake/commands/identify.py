"""`stdm-drake identify`: the robot's link inertias and joint friction from one of its datasets (white box),
physically consistent, written as an identified robot (`identified.yaml`) that every command takes as a
model, with a report (`identified.json`) of the excitation, the fit and the test torque errors."""
import argparse
import json
import pathlib
import sys

from stdm_drake.commands.arguments import add_robot_argument, command_robot
from stdm_drake.errors import InputError
from stdm_drake.files import json_default, write_text_atomic
from stdm_drake.outputs import add_force_argument, check_output_file


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from stdm_drake.identification.identify import REGULARIZATIONS, SMOOTHING_WINDOWS, VELOCITY_SCALES
    parser.add_argument("dataset", type=pathlib.Path, help="dataset file (.h5) of the robot")
    add_robot_argument(parser, "the description whose parameters are identified; must be the dataset's robot")
    parser.add_argument("--output", "-o", type=pathlib.Path, required=True,
                        help="identified robot to write (.yaml); the report goes beside it (.json)")
    parser.add_argument("--derivatives", choices=("true", "smoothed"),
                        help="states and accelerations: the simulation's true ones (default for simulated data), or "
                             "central differences of the Savitzky-Golay-smoothed measured angles, the torques through "
                             "the same smoother (its window chosen on validation; default for a real robot's log)")
    parser.add_argument("--velocity-scales", type=float, nargs="+", default=list(VELOCITY_SCALES), metavar="V_S",
                        help="candidate Coulomb smoothing scales, rad/s (default %(default)s)")
    parser.add_argument("--regularizations", type=float, nargs="+", default=list(REGULARIZATIONS), metavar="LAMBDA",
                        help="candidate weights toward the description's parameters (default %(default)s)")
    parser.add_argument("--windows", type=int, nargs="+", metavar="SAMPLES",
                        help=f"candidate Savitzky-Golay windows with --derivatives smoothed (default {list(SMOOTHING_WINDOWS)}; 1: "
                             "no smoothing, the raw differences)")
    parser.add_argument("--train", type=int, help="training trajectories (per group with --per-group)")
    parser.add_argument("--val", type=int, help="validation trajectories (per group with --per-group)")
    parser.add_argument("--test", type=int, help="test trajectories (default: all the rest)")
    parser.add_argument("--per-group", choices=("on", "off"),
                        help="split per initial-pose group (default: on for tracking data, off otherwise)")
    parser.add_argument("--split-seed", type=int, default=0, help="seed of the trajectory split (default 0; the "
                                                                  "same split as `train` with the same options)")
    parser.add_argument("--quiet", action="store_true")
    add_force_argument(parser)


def run(args: argparse.Namespace) -> int:
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.identification.identified import identified_text
    from stdm_drake.identification.identify import SMOOTHING_WINDOWS, IdentifySettings, identify
    from stdm_drake.learning.seeds import dataset_split
    if args.output.suffix.lower() not in (".yaml", ".yml"):
        raise InputError(f"-o/--output {args.output}: an identified robot is a .yaml file")
    report_path = args.output.with_suffix(".json")
    inputs = [args.dataset, args.robot]
    check_output_file("-o/--output", args.output, kind="identified", inputs=inputs, force=args.force)
    check_output_file("report", report_path, kind="json", inputs=inputs, force=args.force)
    settings = IdentifySettings(derivative_source=args.derivatives or "true", velocity_scales=tuple(args.velocity_scales),
                                regularizations=tuple(args.regularizations),
                                windows=tuple(args.windows or SMOOTHING_WINDOWS))   # (None: not given)
    settings.validate()     # (before any work: windows, scales and weights)
    dataset = load_dataset(args.dataset)
    if args.derivatives is None and not dataset.is_simulated:
        settings.derivative_source = "smoothed"     # (a log has no true accelerations)
    if settings.derivative_source == "true" and args.windows is not None:
        raise InputError("--windows are the smoothing windows of --derivatives smoothed; with the simulation's true "
                         "derivatives they would be ignored")
    robot = command_robot(args, dataset)
    robot.check_fully_actuated("identification")
    split, _ = dataset_split(dataset, args)
    if not args.quiet:
        print(f"identify {robot.name} from {args.dataset}: train {len(split.train)} / val {len(split.val)} / "
              f"test {len(split.test)} trajectories, derivatives {settings.derivative_source}", file=sys.stderr)
    announce = (lambda line: None) if args.quiet else (lambda line: print(line, file=sys.stderr, flush=True))
    identified, report = identify(dataset, robot, split, settings, announce=announce)
    text, report_text = identified_text(identified), json.dumps(report, indent=1, default=json_default) + "\n"
    print(summary(report))
    write_text_atomic(report_path, report_text)
    write_text_atomic(args.output, text)
    print(f"wrote {args.output} (use it as a model: evaluate/view {args.output}, mpc --model NAME={args.output}) "
          f"and {report_path}")
    return 0


def summary(report: dict) -> str:
    """The report's numbers as lines: the excitation, the chosen setting, the test torque errors and, for
    simulated data, each friction coefficient against the truth."""
    ordinary, chosen = report["least_squares"], report["chosen"]
    lines = [f"excitation: {ordinary['base_parameters']} identifiable (base) parameters of {len(report['parameters'])}, "
             f"condition number {ordinary['condition_number']:.3g} (columns scaled to unit RMS); "
             f"{report['samples_train']} training samples",
             f"chosen on validation: Coulomb velocity scale {chosen['velocity_scale']:g} rad/s, regularization "
             f"{chosen['regularization']:g} (validation torque error {chosen['val_torque_error']:.3g})"]
    test = report.get("test")
    if test:
        lines.append(f"test torque RMS error / torque RMS: identified (consistent) {test['torque_error']:.3g}, "
                     f"least squares {test['least_squares_torque_error']:.3g}, description "
                     f"{test['description_torque_error']:.3g}; per joint "
                     + ", ".join(f"{value:.3g}" for value in test["torque_error_per_joint"]))
        if "torque_error_on_true_states" in test:
            lines.append(f"  on the true states and accelerations: {test['torque_error_on_true_states']:.3g}")
    truth = report.get("truth")
    if truth:
        for kind, values in truth["joints"].items():
            pairs = ", ".join(f"{mine:.4g} ({true:.4g})" for mine, true in zip(values["identified"], values["true"]))
            known = [error for error in values["relative_error"] if error is not None]
            worst = f"; largest relative error {max(known):.2%}" if known else ""
            lines.append(f"{kind.replace('_', ' ')} per joint, identified (true): {pairs}{worst}")
    return "\n".join(lines)
