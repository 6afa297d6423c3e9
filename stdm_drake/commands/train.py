"""`stdm-drake train`: split a dataset, train one model per seed, and write checkpoints, learning curves
and the alpha selection (the job: `learning.train_job`)."""
from __future__ import annotations

import argparse
import dataclasses
import pathlib

from stdm_drake.cluster import add_runner_arguments, runner_config_from_args
from stdm_drake.commands.arguments import add_robot_argument, add_settings_flags
from stdm_drake.learning.settings import TrainSettings
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
    parser.add_argument("--physics", type=pathlib.Path, metavar="IDENTIFIED",
                        help="the grey box's plant: an identified robot (`stdm-drake identify`'s .yaml) instead of the "
                             "robot's description; recorded in the checkpoint")
    add_settings_flags(parser, TrainSettings)   # (--model ... --threads: the settings' fields)
    parser.add_argument("--resume", action="store_true",
                        help="continue interrupted runs in the output folder (a seed with nothing written yet starts "
                             "from scratch, so a killed run can always be rerun with --resume)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    add_force_argument(parser)
    add_runner_arguments(parser)


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
