"""`stdm-drake train`: split a dataset, train one model per seed, and write checkpoints, learning curves
and the alpha selection (the job: `learning.train_job`)."""
from __future__ import annotations

import argparse
import dataclasses
import pathlib

from stdm_drake.cluster import add_runner_arguments, runner_config_from_args
from stdm_drake.commands.arguments import add_robot_argument, parse_alpha
from stdm_drake.learning.activations import ACTIVATION_NAMES
from stdm_drake.learning.models import DEFAULT_ENSEMBLE_SIZE, GREY_BOX_TYPES, MODEL_TYPES
from stdm_drake.learning.settings import (ALPHA_SCALES, DEFAULT_ALPHA_SCALE, DEFAULT_MODEL_TYPE, LOSS_KINDS,
                                         LR_SCHEDULES, RELATIVE_ALPHA_GRID, TRAIN_ALPHA_GRID, TrainSettings)
from stdm_drake.learning.structure import INPUT_SETS, PREDICTS
from stdm_drake.learning.trainable import NETWORK_KINDS
from stdm_drake.outputs import add_force_argument


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dataset", type=pathlib.Path, help="dataset file written by `stdm-drake collect` (.h5)")
    parser.add_argument("--output", "-o", type=pathlib.Path, required=True,
                        help="output folder: seed<N>/checkpoint.pt, seed<N>/curves.csv, summary.json")
    add_robot_argument(parser, "the nominal model of nominal-acceleration inputs; a dataset collected with "
                               "another robot is refused")
    parser.add_argument("--config", type=pathlib.Path,
                        help="training settings YAML (TrainSettings: keys as the flags below with '_' for '-'); "
                             "flags given on the command line override it")
    parser.add_argument("--model", default=DEFAULT_MODEL_TYPE, type=str.upper,
                        choices=tuple(MODEL_TYPES) + tuple(GREY_BOX_TYPES),
                        help="model type: D/P/DE/PE naive, DD/PD/DED/PED with the derivative loss (alpha and derivative "
                             f"targets chosen by validation, naive among them); default {DEFAULT_MODEL_TYPE}: derivative "
                             "learning helped in no cell of the settling experiment (docs/settling.md); G/GD the grey "
                             "box: a D/DD whose delta adds to the plant model's next state (--inputs plant_step; the "
                             "plant: the robot's description, or --physics)")
    parser.add_argument("--physics", type=pathlib.Path, metavar="IDENTIFIED",
                        help="the grey box's plant: an identified robot (`stdm-drake identify`'s .yaml) instead of the "
                             "robot's description; recorded in the checkpoint")
    parser.add_argument("--derivative", choices=("on", "off"),
                        help="override the derivative loss the model type implies")
    parser.add_argument("--alpha", type=parse_alpha, default="auto",
                        help="derivative loss weight as in the paper's eq. 9 (e.g. 1e-3, the paper's number), or "
                             "'auto' (default): chosen by validation state MSE from --alpha-grid, 0 (naive training) "
                             "included, so the model is at worst naive on validation")
    parser.add_argument("--alpha-grid", type=float, nargs="+",
                        help="alphas tried by --alpha auto (default: 0 and, for the raw scale, "
                             f"{', '.join(f'{a:g}' for a in TRAIN_ALPHA_GRID[1:])} (docs/settling.md); for the relative scale "
                             f"{RELATIVE_ALPHA_GRID[1]:g} ... {RELATIVE_ALPHA_GRID[-1]:g})")
    parser.add_argument("--alpha-scale", choices=ALPHA_SCALES, default=DEFAULT_ALPHA_SCALE,
                        help="raw: alpha as in the paper's eq. 9; relative: each output's derivative residual over its "
                             "own target's spread, so alpha 1 weighs the derivative and state terms of every joint alike "
                             f"(default {DEFAULT_ALPHA_SCALE}: docs/settling.md)")
    parser.add_argument("--network", choices=tuple(NETWORK_KINDS), default="ensemble_mlp",
                        help="network kind (default ensemble_mlp: the paper's MLPs; a registered kind, "
                             "stdm_drake.learning.trainable)")
    parser.add_argument("--activation", choices=ACTIVATION_NAMES, default="swish",
                        help="hidden activation (default swish); tanh or relu for a model Drake's MultilayerPerceptron "
                             "can hold (`export --target drake`); `export` to ONNX takes every one")
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


def training_settings(args: argparse.Namespace) -> tuple[TrainSettings, set]:
    """The settings file (`--config`, else the defaults) with every flag given on the command line applied over
    it, and the keys the user set (flags and the file's keys; validated by the job)."""
    from stdm_drake.config import file_keys, load_yaml_config
    settings = (load_yaml_config(args.config, TrainSettings, what="training settings", validate=False) if args.config
                else TrainSettings())   # (a file's value that a flag overrides is not checked: it is not used)
    flags = {field.name: getattr(args, field.name) for field in dataclasses.fields(TrainSettings)
             if hasattr(args, field.name)}
    return dataclasses.replace(settings, **flags), set(flags) | file_keys(args.config)


def run(args: argparse.Namespace) -> int:
    from stdm_drake.learning.train_job import TrainJob, train_job
    settings, given = training_settings(args)
    settings.validate(given=given)   # (before the runner: a bad flag is reported first)
    train_job(TrainJob(dataset=args.dataset, output=args.output, settings=settings, robot=args.robot,
                       physics=args.physics, resume=args.resume, force=args.force, progress=not args.quiet,
                       runner=runner_config_from_args(args, connect_now=False), inputs=(args.config,),
                       given=frozenset(given)))
    return 0
