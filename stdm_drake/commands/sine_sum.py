"""`stdm-drake sine-sum`: the paper's sine-sum activation study (Fig. 6-8, Table 1) and its reports."""
from __future__ import annotations

import argparse
import dataclasses
import os
import pathlib

from stdm_drake.learning.settings import parse_alpha
from stdm_drake.errors import InputError
from stdm_drake.experiments.sine_sum import (FULL, QUICK, headline, run_specs, run_study, table1_rows, verdict_text,
                                             write_reports)
from stdm_drake.learning.activations import ACTIVATION_NAMES
from stdm_drake.learning.settings import UPPER_BOUNDS as TRAIN_BOUNDS
from stdm_drake.outputs import fresh_default_folder, add_force_argument, check_output_folder, mark_output_folder
from stdm_drake.stats import ratio_interval_text


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--output", "-o", type=pathlib.Path,
                        help="output folder (default runs/sine-sum, or runs/sine-sum-2, -3, ... where an earlier run's "
                             "results are)")
    parser.add_argument("--quick", action="store_true",
                        help="quick profile: the headline configuration only (5 layers, swish, MSE), 10 paired networks, "
                             "6000 steps at alpha 1 (the full profile's choice), about 110 s on 2 cores")
    parser.add_argument("--alpha", type=parse_alpha,
                        help="derivative-loss weight as in eq. 9, or 'auto' (default: chosen by validation)")
    parser.add_argument("--epochs", type=int, help="override the profile's epochs (full-batch steps)")
    parser.add_argument("--seeds", type=int,
                        help="override the profile's networks per configuration (5-layer swish included)")
    parser.add_argument("--layers", type=int, nargs="+", help="override the hidden-layer counts (must include 5)")
    parser.add_argument("--activations", nargs="+", choices=ACTIVATION_NAMES,
                        help="override the activations (must include tanh, relu, swish)")
    parser.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                        help="processes, one torch thread each (default min(2, cores)); results do not depend on it")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    add_force_argument(parser)
    from stdm_drake.cluster import add_runner_arguments
    add_runner_arguments(parser)


# Beyond these the study would not fit in memory or never end (train's own bounds: learning.settings, whose
# hidden-layer bound --layers shares).
UPPER_BOUNDS = {"--epochs": 1_000_000, "--seeds": 1000}
# and their product with the grid: full-batch network steps of the whole study, at most 10x the full profile's
# (184 networks x 10,000 epochs: the full `reproduce` run took 46.5 minutes, docs/guides/reproduce.md)
MAX_NETWORK_STEPS = 10 * FULL.epochs * sum(spec.members for spec in run_specs(FULL))


def run(args: argparse.Namespace) -> int:
    config = QUICK if args.quick else FULL
    for option, value in (("--epochs", args.epochs), ("--seeds", args.seeds)):
        if value is not None and not 1 <= value <= UPPER_BOUNDS[option]:
            raise InputError(f"{option} must be in 1..{UPPER_BOUNDS[option]}, got {value}")
    layers_bound = TRAIN_BOUNDS["hidden_layers"]
    if args.layers is not None and not all(1 <= layers <= layers_bound for layers in args.layers):
        raise InputError(f"--layers must each be in 1..{layers_bound}, got {' '.join(map(str, args.layers))}")
    overrides = {key: (tuple(value) if isinstance(value, list) else value)
                 for key, value in (("epochs", args.epochs), ("seeds", args.seeds), ("headline_seeds", args.seeds),
                                    ("layers", args.layers), ("activations", args.activations),
                                    ("alpha", args.alpha)) if value is not None}
    if args.seeds is not None:
        overrides["table_seeds"] = min(config.table_seeds, args.seeds)
    if overrides.get("alpha") == 0:
        raise InputError("--alpha 0 is naive learning, which the study runs anyway; give a positive alpha or auto")
    if overrides:
        config = dataclasses.replace(config, **overrides)
    if (steps := config.epochs * sum(spec.members for spec in run_specs(config))) > MAX_NETWORK_STEPS:
        raise InputError(f"--epochs and --seeds: the study would take {steps:.3g} network steps (epochs x networks), "
                         f"more than {MAX_NETWORK_STEPS:.3g}, 10x the full profile's; lower one of them")
    from stdm_drake.cluster import check_workers, runner_config_from_args
    check_workers(args.workers)
    args.output = args.output or fresh_default_folder("runs/sine-sum", "sine-sum")
    check_output_folder("-o/--output", args.output, force=args.force)
    runner = runner_config_from_args(args)
    study = run_study(config, workers=args.workers, progress=not args.quiet, runner=runner)
    mark_output_folder(args.output)
    written = write_reports(study, args.output, quick=args.quick, partial=bool(overrides))
    print(f"{len(study['runs'])} runs in {study['wall_seconds']:.1f} s; wrote {len(written)} files to {args.output}")
    top = headline(study)
    print(f"  {top['layers']} layers swish (alpha {top['alpha']:g}): test MSE derivative "
          f"{top['derivative_mean_test_mse']:.3g}, naive {top['naive_mean_test_mse']:.3g} (paired ratio "
          f"{ratio_interval_text(top['ratio'], top['ratio_low'], top['ratio_high'])}, {verdict_text(top)}; paper "
          f"{top['paper_derivative']:g})")
    for row in table1_rows(study):
        print(f"  table 1  {row['loss']:>5} {row['activation']:>6}: test MSE {row['mean_test_mse']:.4g} "
              f"(paper {row['paper']:.4g})")
    return 0
