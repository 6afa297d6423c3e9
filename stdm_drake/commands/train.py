"""`stdm-drake train`: split a dataset, train one model per seed, and write checkpoints, learning curves
and the alpha selection."""
from __future__ import annotations

import argparse
import csv
import dataclasses
import io
import json
import pathlib
import sys

import numpy as np
import torch

from stdm_drake.cluster import add_runner_arguments, runner_config_from_args
from stdm_drake.commands.arguments import add_robot_argument, command_robot, parse_alpha
from stdm_drake.errors import InputError
from stdm_drake.files import atomic_path, check_free_space, write_text_atomic
from stdm_drake.learning.activations import ACTIVATION_NAMES
from stdm_drake.learning.checkpoint import HISTORY_COLUMNS
from stdm_drake.learning.models import DEFAULT_ENSEMBLE_SIZE, GREY_BOX_TYPES, MODEL_TYPES
from stdm_drake.learning.problem import training_problem
from stdm_drake.learning.seeds import dataset_split, fit_seeds
from stdm_drake.learning.settings import LOSS_KINDS, LR_SCHEDULES, TRAIN_ALPHA_GRID, TrainSettings, network_weights
from stdm_drake.learning.structure import INPUT_SETS, PREDICTS
from stdm_drake.learning.alpha_selection import AlphaSelection
from stdm_drake.outputs import add_force_argument, check_output_folder, mark_output_folder, written_by


CHECKPOINT_RESERVE_BYTES = 1 << 20   # a checkpoint's history, metadata and the seed's curves, beyond its weights

def history_csv(history: dict) -> str:
    """Learning curves as CSV text (one row per epoch, HISTORY_COLUMNS)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(HISTORY_COLUMNS)
    for values in zip(*(history[column] for column in HISTORY_COLUMNS)):
        writer.writerow([int(values[0])] + [f"{value:.9g}" for value in values[1:]])
    return buffer.getvalue()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dataset", type=pathlib.Path, help="dataset file written by `stdm-drake collect` (.h5)")
    parser.add_argument("--output", "-o", type=pathlib.Path, required=True,
                        help="output folder: seed<N>/checkpoint.pt, seed<N>/curves.csv, summary.json")
    add_robot_argument(parser, "the nominal model of nominal-acceleration inputs; a dataset collected with "
                               "another robot is refused")
    parser.add_argument("--config", type=pathlib.Path,
                        help="training settings YAML (TrainSettings: keys as the flags below with '_' for '-'); "
                             "flags given on the command line override it")
    parser.add_argument("--model", default="DD", type=str.upper, choices=tuple(MODEL_TYPES) + tuple(GREY_BOX_TYPES),
                        help="model type: D/P/DE/PE naive, DD/PD/DED/PED with the derivative loss (default DD, its "
                             "alpha and derivative targets chosen by validation, naive D among them); G/GD "
                             "the grey box: a D/DD whose delta adds to the plant model's next state (--inputs "
                             "plant_step; the plant: the robot's description, or --physics)")
    parser.add_argument("--physics", type=pathlib.Path, metavar="IDENTIFIED",
                        help="the grey box's plant: an identified robot (`stdm-drake identify`'s .yaml) instead of the "
                             "robot's description; recorded in the checkpoint")
    parser.add_argument("--derivative", choices=("on", "off"),
                        help="override the derivative loss the model type implies")
    parser.add_argument("--alpha", type=parse_alpha, default="auto",
                        help="derivative loss weight as in the paper's eq. 9 (e.g. 1e-3, the paper's number), or "
                             "'auto' (default): chosen by validation state MSE from --alpha-grid, 0 (naive training) "
                             "included, so the model is at worst naive on validation")
    parser.add_argument("--alpha-grid", type=float, nargs="+", default=list(TRAIN_ALPHA_GRID),
                        help="alphas tried by --alpha auto (default 0 and the paper's search range 1e-4 ... 1e-1)")
    parser.add_argument("--activation", choices=ACTIVATION_NAMES, default="swish", help="hidden activation")
    parser.add_argument("--hidden-width", type=int, default=100, help="units per hidden layer (default 100)")
    parser.add_argument("--hidden-layers", type=int, default=3, help="hidden layers (default 3)")
    parser.add_argument("--ensemble-size", type=int, default=DEFAULT_ENSEMBLE_SIZE,
                        help="members of DE/PE-type models (default 5)")
    parser.add_argument("--direct", action="store_true",
                        help="predict the next state (or velocity) directly instead of its delta from the current one")
    parser.add_argument("--predicts", choices=PREDICTS,
                        help="velocity: the network predicts v_{t+1} and q_{t+1} follows by the trapezoid rule "
                             "(default); state: it predicts x_{t+1} (the paper's; the default of the grey box G/GD, "
                             "whose delta then adds to the plant's whole next state)")
    parser.add_argument("--inputs", choices=INPUT_SETS, default="nominal_acceleration",
                        help="nominal_acceleration: [q, v, tau] and the acceleration the robot's nominal model "
                             "(--robot) gives (default); period_acceleration: that model's mean acceleration over "
                             "the sample period instead (for joints damped faster than the period); raw: [q, v, "
                             "tau] (the paper's); plant_step: the grey box (the network's delta adds to the plant "
                             "model's next state; what --model G/GD use)")
    parser.add_argument("--state-loss", choices=LOSS_KINDS, default="mse")
    parser.add_argument("--derivative-loss", choices=LOSS_KINDS, default="mse")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="one model per seed (default 0)")
    parser.add_argument("--train", type=int, help="training trajectories (per group with --per-group)")
    parser.add_argument("--val", type=int, help="validation trajectories (per group with --per-group)")
    parser.add_argument("--test", type=int, help="test trajectories (default: all the rest)")
    parser.add_argument("--per-group", choices=("on", "off"),
                        help="split per initial-pose group (default: on for tracking data, off otherwise)")
    parser.add_argument("--split-seed", type=int, default=0, help="seed of the trajectory split (default 0)")
    parser.add_argument("--derivative-source", choices=("true", "planned", "measured", "smoothed"),
                        help="derivative targets (default: with --alpha auto chosen by validation from the plan, where "
                             "the data have one and its accelerations are within 0.5 (relative RMS) of the recorded "
                             "ones, and the recorded motion: the simulation's truth, or a log's smoothed angles; with a "
                             "fixed alpha the first of these; measured: a log's velocities and their smoothed "
                             "derivative)")
    parser.add_argument("--action-rate", choices=("forward_difference", "zero_order_hold"),
                        default="forward_difference", help="how Δa/Δt is formed (default forward_difference)")
    parser.add_argument("--epochs", type=int, default=500, help="maximum epochs (default 500)")
    parser.add_argument("--patience", type=int, default=50, help="early-stopping patience in epochs (default 50)")
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate (default 1e-3)")
    parser.add_argument("--lr-schedule", choices=LR_SCHEDULES, default="constant",
                        help="constant, or cosine decay to --min-lr over the --epochs budget (default constant)")
    parser.add_argument("--min-lr", type=float, default=0.0, help="final learning rate of the cosine schedule")
    parser.add_argument("--weight-decay", type=float, default=0.0,
                        help="decoupled weight decay (AdamW), default 0 (plain Adam)")
    parser.add_argument("--checkpoint-every", type=int, default=10, help="epochs between checkpoint writes")
    parser.add_argument("--threads", type=int, default=1,
                        help="torch CPU threads (default 1: bitwise-reproducible on any machine)")
    parser.add_argument("--resume", action="store_true",
                        help="continue interrupted runs in the output folder (a seed with nothing written yet starts "
                             "from scratch, so a killed run can always be rerun with --resume)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    add_force_argument(parser)
    add_runner_arguments(parser)
    settings = {field.name for field in dataclasses.fields(TrainSettings)}
    for action in parser._actions:  # unset flags stay absent, so the settings file (or its defaults) decide
        if action.dest in settings:
            action.default = argparse.SUPPRESS


def training_settings(args: argparse.Namespace) -> TrainSettings:
    """The settings file (`--config`, else the defaults) with every flag given on the command line
    applied over it, validated."""
    from stdm_drake.config import file_keys, load_yaml_config
    settings = (load_yaml_config(args.config, TrainSettings, what="training settings", validate=False) if args.config
                else TrainSettings())   # (a file's value that a flag overrides is not checked: it is not used)
    flags = {field.name: getattr(args, field.name) for field in dataclasses.fields(TrainSettings)
             if hasattr(args, field.name)}
    settings = dataclasses.replace(settings, **flags)
    given = set(flags) | file_keys(args.config)
    settings.validate(given=given)
    settings.check_alpha(given)
    return settings


def alpha_selection_csv(selection: AlphaSelection) -> str:
    """The alpha grid's validation curve as CSV: alpha, derivative_source (empty: the dataset's one source),
    val_state_mse_standardized, best_epoch, chosen."""
    lines = ["alpha,derivative_source,val_state_mse_standardized,best_epoch,chosen"]
    sources = selection.sources or ("",) * len(selection.alphas)
    for index, (alpha, source, score, epoch) in enumerate(zip(selection.alphas, sources, selection.val_mse,
                                                               selection.best_epochs)):
        source = source if alpha > 0 else ""   # (naive training sees no derivative targets)
        lines.append(f"{alpha:g},{source},{score:.9g},{int(epoch)},{int(index == selection.index)}")
    return "\n".join(lines) + "\n"


def plot_alpha_selection(selection: AlphaSelection, path, title: str = "") -> pathlib.Path:
    """Validation state MSE against alpha (log axes; alpha = 0 drawn as a dashed line), PNG, atomically."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    alphas, scores = np.asarray(selection.alphas), np.asarray(selection.val_mse)
    sources = np.asarray(selection.sources if selection.sources is not None else [""] * len(alphas))
    figure, axis = plt.subplots(figsize=(5.5, 3.8))
    positive = alphas > 0
    for source, color in zip(dict.fromkeys(sources[positive]), ("tab:orange", "tab:green", "tab:purple", "tab:red")):
        rows = positive & (sources == source)
        axis.loglog(alphas[rows], scores[rows], "o-", color=color,
                    label="derivative learning" + (f" ({source} targets)" if source else ""))
    for score in scores[~positive]:
        axis.axhline(score, color="tab:blue", linestyle="--", label="naive (alpha = 0)")
    axis.plot([selection.alpha if selection.alpha > 0 else alphas[positive].min()], [scores[selection.index]], "k*",
              markersize=14, label=f"chosen: {selection.label(selection.index)}")
    axis.set_xlabel("alpha (paper eq. 9)")
    axis.set_ylabel("validation state MSE (standardized)")
    axis.set_title(title or "alpha chosen by validation")
    axis.legend(fontsize=8)
    path = pathlib.Path(path)
    with atomic_path(path) as temp:
        figure.savefig(temp, format="png", dpi=110, bbox_inches="tight")
    plt.close(figure)
    return path


def warn_about_fast_damped_joints(robot, sample_period: float) -> None:
    """One warning line when derivative learning is asked for a robot with joints whose description's
    damping stops them faster than the sample period (`Dynamics.damping_time_constants` at home): on
    such an arm the derivative targets are the fast decay itself, and a DD trained on the ABB IRB 1200's
    identification data did not learn (docs/published_arms.md)."""
    from stdm_drake.robots.plant import Dynamics
    constants = Dynamics(robot).damping_time_constants()
    fast = [(name, value) for name, value in zip(robot.joint_names, constants) if value < sample_period]
    if fast:
        listed = ", ".join(f"{name} {1e3 * value:.2g} ms" for name, value in fast)
        print(f"stdm-drake train: warning: robot {robot.name}: the damping of {listed} stops these joints faster than "
              f"the {1e3 * sample_period:g} ms period; derivative learning failed on such an arm (docs/published_arms.md), "
              "train --model D for it", file=sys.stderr)


def write_seed_files(folder: pathlib.Path, name: str, seed: int, result, selection) -> dict:
    """A trained seed's learning curves and alpha selection (CSV, PNG) beside its checkpoint, one line
    printed; returns its summary entry."""
    write_text_atomic(folder / "curves.csv", history_csv(result.history))
    entry = dict(checkpoint=str(folder / "checkpoint.pt"), epochs=result.epochs_run, stopped_early=result.stopped_early,
                 best_epochs=result.best_epochs, best_val_mse_standardized=result.best_scores)
    if selection is not None:
        write_text_atomic(folder / "alpha_selection.csv", alpha_selection_csv(selection))
        plot_alpha_selection(selection, folder / "alpha_selection.png", title=f"{name} seed {seed}")
        entry["alpha_selection"] = selection.as_dict()
        print(f"seed {seed}: chosen by validation: {selection.label(selection.index)} (validation state MSE, "
              "standardized: " + "; ".join(f"{selection.label(i)} {v:.3g}" for i, v in enumerate(selection.val_mse))
              + ")")
        if selection.gain_low is not None:
            print(f"seed {seed}: gain over naive training, 95 % lower bound: " + "; ".join(
                f"{selection.label(i)} {100 * g:+.2g} %" for i, g in enumerate(selection.gain_low) if selection.alphas[i])
                + ("" if selection.alpha > 0 else " -> naive kept: no alpha > 0 beat it beyond validation's noise"))
    print(f"seed {seed}: {result.epochs_run} epochs, best validation MSE (standardized) "
          f"{np.mean(result.best_scores):.4g} at epoch(s) {result.best_epochs} -> {folder / 'checkpoint.pt'}")
    return entry


def derivative_sources(dataset, split, settings: TrainSettings) -> tuple:
    """(derivative_source for `training_problem`, the line that states the choice or None, the plan's measured
    mismatch `data.inspect.plan_mismatch` or None). Given by the user,
    the source is used as it is (a plan far from the recorded motion gets one warning line with the measured
    mismatch); else `learning.problem.candidate_sources` on the training and validation trajectories: all of
    them (a tuple, chosen by validation) with alpha "auto", their first with a fixed alpha. A model without the
    derivative loss uses none (None, None, the mismatch)."""
    from stdm_drake.learning.problem import PLAN_MISMATCH_LIMIT, candidate_sources
    choice = candidate_sources(dataset, np.concatenate([split.train, split.val]))
    if not settings.uses_derivative():
        return None, None, choice.mismatch
    if settings.action_rate == "zero_order_hold" and "true" in choice.sources:   # (the scheme needs true targets)
        choice = dataclasses.replace(choice, sources=("true",))
    if settings.derivative_source is not None:
        if settings.derivative_source == "planned" and choice.plan_left_out():
            print(f"stdm-drake train: warning: --derivative-source planned: the plan's accelerations are "
                  f"{choice.mismatch['acceleration']:.2f} (relative RMS, mean over joints; per joint "
                  + ", ".join(f"{value:.2f}" for value in choice.mismatch["acceleration_per_joint"])
                  + f") from the recorded ones ({choice.mismatch['recorded']}), more than {PLAN_MISMATCH_LIMIT:g}: "
                  "the model is fitted to derivatives the robot did not have; leave the option out to choose by "
                  "validation", file=sys.stderr)
        return settings.derivative_source, None, choice.mismatch
    if settings.alpha_choices() is not None and len(choice.sources) > 1:
        return tuple(choice.sources), choice.describe(), choice.mismatch
    if len(choice.sources) > 1:   # a fixed alpha: the first, the plan
        return choice.sources[0], (f"derivative targets: {choice.sources[0]} (the plan's accelerations are "
                                   f"{choice.mismatch['acceleration']:.2f} from the recorded ones; --alpha auto "
                                   f"would also try {', '.join(choice.sources[1:])})"), choice.mismatch
    return choice.sources[0], choice.describe(), choice.mismatch


class ValidationVerdict:
    """What `train` ends with, per seed: the model's one-step MSE on the validation split beside the Euler step
    (q) and "v unchanged" (v), the alpha grid's naive member where it trained one and the sensor's noise floor,
    the verdict of `physics.learning_verdict`, and one warning line naming the likely cause when the model has
    not learned. Validation only: the test split stays for `evaluate`."""

    def __init__(self, dataset, split, robot, structure, name: str, settings: TrainSettings, transitions: int,
                 sources, mismatch: dict | None):
        from stdm_drake.data.inspect import noise_floor
        self.dataset, self.robot, self.structure, self.name, self.settings = dataset, robot, structure, name, settings
        self.training_transitions, self.sources, self.mismatch = transitions, sources, mismatch
        self.val = dataset.transitions(split.val)
        self.val_trajectories = len(split.val)
        self.floor = noise_floor(dataset, split.val)

    def source_record(self) -> dict:
        """The derivative sources tried and the plan's measured mismatch, for summary.json."""
        tried = list(self.sources) if isinstance(self.sources, tuple) else [self.sources] if self.sources else []
        return dict(tried=tried, plan_mismatch=self.mismatch)

    def report(self, seed: int, checkpoint: pathlib.Path, naive, selection) -> dict:
        """Print seed `seed`'s verdict (its checkpoint; naive: the grid's alpha = 0 network or None) and return
        its summary entry."""
        from stdm_drake.learning.evaluate import compare_with_baselines
        from stdm_drake.learning.learned_model import LearnedModel
        from stdm_drake.learning.physics import FLOOR_FACTOR, LEARNED_FACTOR, ConstantVelocity
        label = self.name + ("" if selection is None else " (alpha 0: naive training)" if selection.alpha == 0
                             else f" ({selection.label(selection.index)})")
        models = [LearnedModel(checkpoint, name=label, robot=self.robot, check_robot=self.robot is not None)]
        if naive is not None and selection is not None and selection.alpha > 0:
            single = "" if models[0].ensemble_size == 1 else ", one network"
            models.append(LearnedModel(naive, name=f"{self.name[0]} (alpha 0{single})", robot=self.robot,
                                       structure=self.structure, sample_period=self.dataset.sample_period))
        euler = ConstantVelocity(models[0].state_dim, models[0].action_dim, self.dataset.sample_period)
        rows = compare_with_baselines(models + [euler], self.val, None, noise_floor=self.floor)
        width = max([len(row.name) for row in rows] + [len("noise floor")]) + 2
        print(f"seed {seed} on the validation split ({self.val_trajectories} trajectories, "
              f"{rows[0].one_step.transitions} transitions), one-step MSE:")
        print(f"  {'':<{width}}{'q [rad^2]':>11} {'v [(rad/s)^2]':>14}  against the Euler step (q) / 'v unchanged' (v)")
        for row in rows[:-1]:
            print(f"  {row.name:<{width}}{row.one_step.angle_mse:>11.3e} {row.one_step.velocity_mse:>14.3e}  "
                  f"{row.ratio_q:.3g}x / {row.ratio_v:.3g}x better -> {row.verdict}")
        print(f"  {'Euler step':<{width}}{rows[-1].one_step.angle_mse:>11.3e} {rows[-1].one_step.velocity_mse:>14.3e}"
              "  (q + dt v; 'v unchanged')")
        if self.floor and (self.floor["q"] > 0 or self.floor["v"] > 0):
            print(f"  {'noise floor':<{width}}{self.floor['q']:>11.3e} {self.floor['v']:>14.3e}  (the sensor's)")
        model = rows[0]
        if not model.verdict.startswith("learned"):
            print(f"stdm-drake train: warning: seed {seed}'s {self.name} has not learned the dynamics (validation "
                  f"one-step q {model.ratio_q:.3g}x better than the Euler step, v {model.ratio_v:.3g}x than 'v "
                  f"unchanged'; it needs {LEARNED_FACTOR:g}x in both"
                  + (f", or within {FLOOR_FACTOR:g}x of the noise floor" if self.floor and self.floor["v"] > 0 else "")
                  + f"); likely cause: {self.likely_cause(selection, rows)}", file=sys.stderr)
        return dict(transitions=model.one_step.transitions, trajectories=self.val_trajectories, noise_floor=self.floor,
                    models=[row.as_dict() for row in rows])

    def likely_cause(self, selection, rows) -> str:
        """The first of the usual reasons that fits this run."""
        from stdm_drake.learning.problem import PLAN_MISMATCH_LIMIT
        settings, chosen = self.settings, (selection.source if selection is not None else None) or self.sources
        targets_used = selection is None or selection.alpha > 0
        if settings.uses_derivative() and targets_used and chosen == "planned" and self.mismatch is not None and \
                self.mismatch["acceleration"] > PLAN_MISMATCH_LIMIT:
            return (f"the derivative targets: the plan's accelerations are {self.mismatch['acceleration']:.2f} "
                    "(relative RMS) from the recorded ones; leave out --derivative-source planned")
        if settings.uses_derivative() and selection is None:
            return (f"alpha {settings.alpha:g}, fixed: --alpha auto chooses it by validation, 0 (naive) included")
        if len(rows) > 2 and rows[1].verdict.startswith("learned"):
            return "the derivative loss: the naive member learned; train --model " + self.name[:-1]
        if self.training_transitions < 2000:
            return (f"the data size: {self.training_transitions} training transitions; collect more trajectories "
                    "(collect --count) or train on more of them (--train)")
        if not self.structure.grey_box and (self.structure.inputs == "raw" or self.structure.predicts == "state"):
            return ("the model structure: the paper's black box (--inputs raw, --predicts state) did not learn on "
                    "the shipped protocols (docs/learning.md); leave --inputs and --predicts at their defaults")
        return ("the data or the training budget: check the data with `stdm-drake inspect` and the learning curves "
                "(curves.csv); raise --epochs or --patience if the validation error was still falling")


def grey_box_physics(path, robot, settings, dataset, split) -> dict | None:
    """The structure's physics record of `--physics` (an identified robot of `robot`'s description), or None.
    An identified robot fitted on `dataset` must have been fitted and validated on plans this grey box
    trains or validates on (`split`), or its test plans would not be held out from the model as a whole."""
    if path is None:
        return None
    if settings.inputs != "plant_step":
        raise InputError("--physics is the grey box's plant: use it with --model G/GD (or --inputs plant_step)")
    from stdm_drake.identification.identified import load_identified
    identified = load_identified(path)
    identified.check_robot(robot)
    identified.check_fits(dataset)
    if identified.trained_on(dataset):
        fitted = set(identified.split_indices(dataset, "train")) | set(identified.split_indices(dataset, "val"))
        unseen = sorted(fitted - set(split.train.tolist()) - set(split.val.tolist()))
        if unseen:
            raise InputError(f"--physics {path} was identified on plans this grey box holds out for testing "
                             f"({', '.join(map(str, unseen[:5]))}{' ...' if len(unseen) > 5 else ''}); train with "
                             "the split options `identify` used")
    return dict(effects=identified.effects.record(), plant_time_step=identified.identification.plant_time_step,
                source=str(path))


def run(args: argparse.Namespace) -> int:
    from stdm_drake.data.dataset import load_dataset

    settings = training_settings(args)
    torch.set_num_threads(settings.threads)
    output = pathlib.Path(args.output)
    check_output_folder("-o/--output", output, inputs=[args.dataset, args.config, args.robot, args.physics],
                        force=args.force)
    if args.backend == "ray" and args.resume:
        raise InputError("--resume continues runs in a local folder; with --backend ray, train without it")
    existing = [seed for seed in settings.seeds if (output / f"seed{seed}" / "checkpoint.pt").exists()]
    if existing and not args.resume:
        raise InputError(f"{output / f'seed{existing[0]}' / 'checkpoint.pt'} exists; pass --resume "
                         "to continue it or choose another --output")
    dataset = load_dataset(args.dataset)
    robot = None   # (without a robot, train loads no Drake plant at all)
    if args.robot is not None or settings.structure().uses_nominal_model:
        robot = command_robot(args, dataset)
    if settings.uses_derivative() and robot is not None:
        warn_about_fast_damped_joints(robot, dataset.sample_period)
    split, per_group = dataset_split(dataset, settings)
    structure = settings.structure(grey_box_physics(args.physics, robot, settings, dataset, split))
    name = settings.model_name()
    sources, source_line, mismatch = derivative_sources(dataset, split, settings)
    problem = training_problem(dataset, split, model_type=name, activation=settings.activation,
                               hidden_width=settings.hidden_width, hidden_layers=settings.hidden_layers,
                               ensemble_size=settings.ensemble_size, delta=not settings.direct,
                               derivative_source=sources, action_rate=settings.action_rate,
                               structure=structure, robot=robot, split_seed=settings.split_seed, per_group=per_group,
                               threads=settings.threads)
    model_config = problem.model_config
    settings.training_config(settings.seeds[0])  # its checks, before the output folder is made
    grid = settings.alpha_choices()
    settings.check_memory(problem.transitions, max(model_config.ensemble_size, len(grid) if grid else 1))
    weights = network_weights(model_config.ensemble_size, model_config.hidden_layers, model_config.hidden_width)
    check_free_space(output / f"seed{settings.seeds[0]}" / "checkpoint.pt",   # weights, Adam's state (float32)
                     len(settings.seeds) * (16 * weights + CHECKPOINT_RESERVE_BYTES))
    verdict = ValidationVerdict(dataset, split, robot, structure, name, settings, problem.transitions, sources,
                                mismatch)
    runner = runner_config_from_args(args)  # joins the cluster now: an unreachable one stops before any work
    mark_output_folder(output)
    print(f"{name}: {model_config.hidden_layers}x{model_config.hidden_width} {model_config.activation}, "
          f"{model_config.ensemble_size} member(s), {'delta' if model_config.residual else 'direct'}, "
          f"{structure.label}; train {len(split.train)} / val {len(split.val)} / test {len(split.test)} trajectories "
          f"({problem.transitions} / {len(verdict.val.state)} transitions)")
    if source_line:
        print(source_line)
    if grid is not None:
        print(f"alpha chosen by validation from {', '.join(f'{a:g}' for a in grid)}"
              + (f" for each of the derivative sources {', '.join(sources)}" if isinstance(sources, tuple) else "")
              + ("; an alpha > 0 replaces naive training (0) only where its gain over it is above 0 at 95 % "
                 "confidence, paired over the validation trajectories" if 0.0 in grid else ""))
    fit_options = dict(alpha_grid=grid, checkpoint_every=settings.checkpoint_every, metadata=problem.metadata)
    entries = {}
    for seed, result, selection in fit_seeds(problem, settings, fit_options, runner, output, args.quiet):
        entries[seed] = write_seed_files(output / f"seed{seed}", name, seed, result, selection)
        entries[seed]["validation"] = verdict.report(seed, output / f"seed{seed}" / "checkpoint.pt", result.naive,
                                                     selection)
    summary = dict(written_by=written_by(), model_type=name, structure=structure.as_dict(), dataset=str(args.dataset),
                   dataset_sha256=dataset.sha256, derivative_sources=verdict.source_record(),
                   split={key: list(map(int, value)) for key, value in split.as_dict().items()},
                   seeds={str(seed): {k: v for k, v in entries[seed].items() if k != "alpha_selection"}
                          for seed in settings.seeds})
    selections = {str(seed): entries[seed]["alpha_selection"] for seed in settings.seeds
                  if "alpha_selection" in entries[seed]}
    if selections:
        summary["alpha_selection"] = selections
    write_text_atomic(output / "summary.json", json.dumps(summary, indent=2) + "\n")
    return 0
