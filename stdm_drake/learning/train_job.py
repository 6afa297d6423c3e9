"""One training job, the library's `train`: split a dataset, train one model per seed, and write checkpoints,
learning curves, the alpha selection and summary.json; what `stdm-drake train` and every study run.

    job = TrainJob(dataset=pathlib.Path("data.h5"), output=pathlib.Path("runs/dd"),
                   settings=TrainSettings(model="DD", seeds=[0, 1]))
    summary = train_job(job)          # the summary.json record; checkpoints at runs/dd/seed<N>/checkpoint.pt
"""
from __future__ import annotations

import dataclasses
import functools
import json
import pathlib
import sys

import numpy as np

from stdm_drake.cluster import RunnerConfig, connect
from stdm_drake.devices import compute_threads
from stdm_drake.errors import InputError
from stdm_drake.files import check_free_space, write_text_atomic
from stdm_drake.learning.problem import training_problem, PLAN_MISMATCH_LIMIT, candidate_sources
from stdm_drake.data.dataset import dataset_split, load_dataset
from stdm_drake.learning.seeds import fit_seeds
from stdm_drake.learning.settings import TrainSettings
from stdm_drake.learning.trainable import network_class
from stdm_drake.learning.train_outputs import write_seed_files
from stdm_drake.outputs import check_output_folder, mark_output_folder, running_command, running_options, written_by
from stdm_drake.robots.plant import Dynamics
from stdm_drake.data.inspect import noise_floor
from stdm_drake.learning.evaluate import compare_with_baselines, times_better
from stdm_drake.learning.learned_model import LearnedModel
from stdm_drake.dynamics.physics import ConstantVelocity
from stdm_drake.dynamics.verdict import FLOOR_FACTOR, LEARNED_FACTOR, floor_not_held_note
from stdm_drake.dynamics.model_files import kind_of, load_model_file
from stdm_drake.data.compatibility import resolve_robot

CHECKPOINT_RESERVE_BYTES = 1 << 20   # a checkpoint's history, metadata and the seed's curves, beyond its weights


@dataclasses.dataclass
class TrainJob:
    """What one training job needs.

    dataset: the .h5 file `collect` or `import` wrote; output: the folder for seed<N>/checkpoint.pt,
    seed<N>/curves.csv and summary.json (checked and locked before any work: `outputs.check_output_folder`);
    settings: the model, its training and the split (`TrainSettings`, validated by the caller or here);
    robot: the robot config YAML (None: the shipped preset the dataset was collected with, else the UR-10's;
    loaded only where the model's structure needs the robot's nominal model or a robot is given);
    physics: the grey box's plant, an identified robot (.yaml); resume: continue interrupted seeds in
    `output`; force: write into a folder stdm-drake did not write; runner: where the seeds train (this
    process, or Ray); progress: epoch bars; inputs: further files the output must not overwrite (e.g. the
    settings file); given: the settings the user set (`TrainSettings.validate`'s given; None: those that
    differ from the defaults)."""
    dataset: pathlib.Path
    output: pathlib.Path
    settings: TrainSettings = dataclasses.field(default_factory=TrainSettings)
    robot: pathlib.Path | None = None
    physics: pathlib.Path | None = None
    resume: bool = False
    force: bool = False
    runner: RunnerConfig = dataclasses.field(default_factory=RunnerConfig)
    progress: bool = True
    inputs: tuple = ()
    given: frozenset | None = None


def warn_about_fast_damped_joints(robot, sample_period: float) -> None:
    """One warning line when derivative learning is asked for a robot with joints whose description's
    damping stops them faster than the sample period (`Dynamics.damping_time_constants` at home): on
    such an arm the derivative targets are the fast decay itself, and a DD trained on the ABB IRB 1200's
    identification data did not learn (docs/published_arms.md)."""
    constants = Dynamics(robot).damping_time_constants()
    fast = [(name, value) for name, value in zip(robot.joint_names, constants) if value < sample_period]
    if fast:
        listed = ", ".join(f"{name} {1e3 * value:.2g} ms" for name, value in fast)
        print(f"stdm-drake train: warning: robot {robot.name}: the damping of {listed} stops these joints faster than "
              f"the {1e3 * sample_period:g} ms period; derivative learning failed on such an arm (docs/published_arms.md), "
              "train --model D for it", file=sys.stderr)


def derivative_sources(dataset, split, settings: TrainSettings) -> tuple:
    """(derivative_source for `training_problem`, the line that states the choice or None, the plan's measured
    mismatch `data.inspect.plan_mismatch` or None). Given by the user,
    the source is used as it is (a plan far from the recorded motion gets one warning line with the measured
    mismatch); else `learning.problem.candidate_sources` on the training and validation trajectories: all of
    them (a tuple, chosen by validation) with alpha "auto", their first with a fixed alpha. A model without the
    derivative loss uses none (None, None, the mismatch)."""
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


SLOW_LR_FACTOR = 100   # a learning rate this far below the default's is named as the cause before the budget
BUDGET_END_FRACTION = 0.9   # a kept epoch past this fraction of a run that ran out its epochs: still improving


class LearningVerdict:
    """What `train` ends with, per seed: the verdict of `physics.learning_verdict` on the **test split**, the one
    `evaluate` reads by default, so that both commands say the same of one checkpoint: the model's one-step MSE
    beside the Euler step (q) and "v unchanged" (v), the alpha grid's naive member where it trained one and the
    sensor's noise floor, and one warning line naming the likely cause when the model has not learned. Nothing
    of the run reads the test split before this (early stopping and alpha are chosen on validation). The same
    comparison on the validation split is kept in summary.json (`validation`), unprinted, for what chooses by it
    (the studies). Where the split leaves no test trajectory the verdict is the validation split's, and says so."""

    def __init__(self, dataset, split, robot, structure, name: str, settings: TrainSettings, transitions: int,
                 sources, mismatch: dict | None):
        self.dataset, self.robot, self.structure, self.name, self.settings = dataset, robot, structure, name, settings
        self.training_transitions, self.sources, self.mismatch = transitions, sources, mismatch
        self.val = dataset.transitions(split.val)
        self.val_trajectories = len(split.val)
        self.val_floor = noise_floor(dataset, split.val)
        tested = len(split.test) > 0
        self.split_name = "test" if tested else "validation"
        self.judged = dataset.transitions(split.test) if tested else self.val
        self.judged_trajectories = len(split.test) if tested else len(split.val)
        self.floor = noise_floor(dataset, split.test) if tested else self.val_floor

    def source_record(self) -> dict:
        """The derivative sources tried and the plan's measured mismatch, for summary.json."""
        tried = list(self.sources) if isinstance(self.sources, tuple) else [self.sources] if self.sources else []
        return dict(tried=tried, plan_mismatch=self.mismatch)

    def report(self, seed: int, checkpoint: pathlib.Path, result, selection) -> dict:
        """Print seed `seed`'s verdict (its checkpoint; result: its `trainer.TrainResult`, whose naive member is the
        grid's alpha = 0 network or None) and return its summary entries: {"validation": ..., "test": ...} (no "test"
        without a test split)."""
        naive = result.naive
        kept_naive = selection is not None and selection.alpha == 0
        label = self.name + ("" if selection is None else " (alpha 0: naive training)" if kept_naive
                             else f" ({selection.label(selection.index)})")
        models = [LearnedModel(checkpoint, name=label, robot=self.robot, check_robot=self.robot is not None)]
        if naive is not None and selection is not None and selection.alpha > 0:
            single = "" if models[0].ensemble_size == 1 else ", one network"
            models.append(LearnedModel(naive, name=f"{self.name[0]} (alpha 0{single})", robot=self.robot,
                                       structure=self.structure, sample_period=self.dataset.sample_period))
        euler = ConstantVelocity(models[0].state_dim, models[0].action_dim, self.dataset.sample_period)
        validation = compare_with_baselines(models + [euler], self.val, None, noise_floor=self.val_floor)
        rows = validation if self.split_name == "validation" else \
            compare_with_baselines(models + [euler], self.judged, None, noise_floor=self.floor)
        width = max([len(row.name) for row in rows] + [len("noise floor")]) + 2
        held_out = ("held out from training, early stopping and the choice of alpha; `evaluate` reads it too"
                    if self.split_name == "test" else "no trajectory left for a test split: the split early stopping read")
        print(f"seed {seed} on the {self.split_name} split ({self.judged_trajectories} trajectories, "
              f"{rows[0].one_step.transitions} transitions; {held_out}), one-step MSE:")
        print(f"  {'':<{width}}{'q [rad^2]':>11} {'v [(rad/s)^2]':>14}  against the Euler step (q) / 'v unchanged' (v)")
        for row in rows[:-1]:
            print(f"  {row.name:<{width}}{row.one_step.angle_mse:>11.3e} {row.one_step.velocity_mse:>14.3e}  "
                  f"{times_better(row.ratio_q)} / {times_better(row.ratio_v)} -> {row.verdict}")
        print(f"  {'Euler step':<{width}}{rows[-1].one_step.angle_mse:>11.3e} {rows[-1].one_step.velocity_mse:>14.3e}"
              "  (q + dt v; 'v unchanged')")
        alone = self.plant_alone
        if alone is not None:
            print(f"  {'plant alone':<{width}}{alone.one_step.angle_mse:>11.3e} {alone.one_step.velocity_mse:>14.3e}  "
                  f"(the grey box's physics without its network: {self.plant_source})")
        if self.floor and (self.floor["q"] > 0 or self.floor["v"] > 0):
            print(f"  {'noise floor':<{width}}{self.floor['q']:>11.3e} {self.floor['v']:>14.3e}  (the sensor's)")
            note = floor_not_held_note(rows[0].ratio_q, rows[0].ratio_v, rows[0].floor_ratio_q, rows[0].floor_ratio_v)
            if note:
                print(f"  {note}")
        if kept_naive and self.settings.uses_derivative():
            print(f"  (the alpha grid kept naive training: this {self.name} checkpoint is a naive "
                  f"{self.name[:-1]}, trained without the derivative loss)")
        model = rows[0]
        if not model.verdict.startswith("learned"):
            print(f"stdm-drake train: warning: seed {seed}'s {self.name} has not learned the dynamics ({self.split_name} "
                  f"split: one-step q {times_better(model.ratio_q)} than the Euler step, v "
                  f"{times_better(model.ratio_v)} than 'v unchanged'; it needs {LEARNED_FACTOR:g}x better in both"
                  + (f", or within {FLOOR_FACTOR:g}x of the noise floor" if self.floor and self.floor["v"] > 0 else "")
                  + f"); likely cause: {self.likely_cause(selection, rows, result)}", file=sys.stderr)

        worse = [] if alone is None else self.worse_than_plant(model, alone)
        if worse:
            print(f"stdm-drake train: warning: seed {seed}'s {self.name} predicts {' and '.join(worse)} than its plant "
                  f"alone ({self.plant_source}) on the {self.split_name} split: the network's correction costs "
                  "accuracy on these data, so the plant alone is the better model here (`stdm-drake compare` weighs "
                  "both); " + self.plant_alone_advice(result), file=sys.stderr)

        def entry(found, trajectories, floor):
            return dict(transitions=found[0].one_step.transitions, trajectories=trajectories, noise_floor=floor,
                        models=[row.as_dict() for row in found])
        entries = dict(validation=entry(validation, self.val_trajectories, self.val_floor))
        if self.split_name == "test":
            entries["test"] = entry(rows, self.judged_trajectories, self.floor)
        if alone is not None:
            entries[self.split_name]["plant_alone"] = dict(alone.as_dict(), source=self.plant_source)
        return entries

    def worse_than_plant(self, model, alone) -> list[str]:
        """Where a grey box (`model`, a `compare_with_baselines` row) predicts worse than its plant alone (`alone`):
        "q 1.5x worse (... against ... rad^2)", per quantity. A quantity where both sit within FLOOR_FACTOR of the
        sensor's noise floor has no difference to name (held-out run 43: "1x worse" at the floor, and the advice, more
        data or epochs, changed nothing)."""
        floor = self.floor or {}
        at_floor = lambda name, *errors: floor.get(name, 0) > 0 and max(errors) <= FLOOR_FACTOR * floor[name]  # noqa: E731
        return [f"{name} {f'{model_mse / plant_mse:.3g}x ' if plant_mse > 0 else ''}worse ({model_mse:.3g} against "
                f"{plant_mse:.3g} {unit})"
                for name, model_mse, plant_mse, unit in (
                    ("q", model.one_step.angle_mse, alone.one_step.angle_mse, "rad^2"),
                    ("v", model.one_step.velocity_mse, alone.one_step.velocity_mse, "(rad/s)^2"))
                if model_mse > plant_mse and not at_floor(name, model_mse, plant_mse)]

    @staticmethod
    def plant_alone_advice(result) -> str:
        """How a grey box worse than its plant alone may still add to it: more data or epochs, unless training never
        did better than after its first epoch (`trainer.TrainResult`'s best epochs), where the network has found
        nothing in these data to add (held-out run 44: on data the plant itself made, 3x the data and 300 epochs
        kept it 1.23x worse, best at epoch 1)."""
        if max(result.best_epochs) <= 1:
            return ("its validation error was lowest after the first epoch, so the network found nothing to add to the "
                    "plant on these data: use the plant alone")
        return "more data or epochs may let the network add what the plant lacks"

    @property
    def plant_source(self) -> str:
        return "the identified robot" if self.structure.physics else "the robot's description"

    @functools.cached_property
    def plant_alone(self):
        """For a grey box (plant-step inputs): the one-step errors (`ModelErrors`) of its plant model alone, the
        physics its network corrects, on the judged split; None for another structure or without a robot. Computed
        once: the report's row and the description's cause line read the same errors."""
        if not self.structure.grey_box or self.robot is None:
            return None
        plant = self.structure.nominal_features(self.robot, self.dataset.sample_period).model
        return compare_with_baselines([plant], self.judged, None)[0]

    def description_error(self, rows) -> str | None:
        """For a grey box on the robot's description (no identified robot as --physics): the cause line when its
        plant alone (the `plant alone` row: the description's step the network corrects) predicts these data worse
        than the Euler step one step ahead (q; rows[-1]), as a description missing the motors' rotor inertia does;
        None otherwise (or without a robot)."""
        if not self.structure.grey_box or self.structure.physics or self.robot is None:
            return None
        plant, euler = self.plant_alone, rows[-1]
        ratio = plant.one_step.angle_mse / max(euler.one_step.angle_mse, 1e-300)
        if ratio <= 1.0:
            return None
        return (f"the robot's description: the plant it describes (the plant alone row) predicts q {ratio:.3g}x worse "
                f"than the Euler step one step ahead on these data ({plant.one_step.angle_mse:.3g} against "
                f"{euler.one_step.angle_mse:.3g} rad^2), so the grey box starts from physics that mislead it; "
                f"identify the robot from the data (`stdm-drake identify`) and train on it ({train_option('--physics')})")

    def likely_cause(self, selection, rows, result) -> str:
        """The first of the usual reasons that fits this run (result: its `trainer.TrainResult`)."""
        settings, chosen = self.settings, (selection.source if selection is not None else None) or self.sources
        targets_used = selection is None or selection.alpha > 0
        if settings.uses_derivative() and targets_used and chosen == "planned" and self.mismatch is not None and \
                self.mismatch["acceleration"] > PLAN_MISMATCH_LIMIT:
            return (f"the derivative targets: the plan's accelerations are {self.mismatch['acceleration']:.2f} "
                    f"(relative RMS) from the recorded ones; leave out {train_option('--derivative-source')} planned")
        if settings.uses_derivative() and selection is None:
            return (f"alpha {settings.alpha:g}, fixed: {train_option('--alpha')} auto chooses it by validation, 0 (naive) "
                    "included")
        if len(rows) > 2 and rows[1].verdict.startswith("learned"):
            return "the derivative loss: the naive member learned; train --model " + self.name[:-1]
        description = self.description_error(rows)
        if description is not None:
            return description
        if not self.structure.grey_box and (self.structure.inputs == "raw" or self.structure.predicts == "state"):
            inputs, predicts = train_option("--inputs"), train_option("--predicts")
            return (f"the model structure: the paper's black box ({inputs} raw, {predicts} state) did not learn on "
                    f"the shipped protocols (docs/learning.md); leave {inputs} and {predicts} at their defaults")
        default_lr = TrainSettings().lr
        if settings.lr <= default_lr / SLOW_LR_FACTOR:
            return (f"the learning rate: {settings.lr:g}, {default_lr / settings.lr:,.0f}x below the default {default_lr:g} "
                    f"(Adam moves each weight by about that much per step); raise {train_option('--lr')} or leave it out")
        best = int(selection.best_epochs[selection.index] if selection is not None else max(result.best_epochs))
        if not result.stopped_early and best > BUDGET_END_FRACTION * result.epochs_run:
            return (f"the training budget: training ended at its {result.epochs_run} epochs with the validation error "
                    f"still falling (its best at epoch {best}); raise {train_option('--epochs')}")
        if self.training_transitions < 2000:
            if running_command() == "mbrl":   # (the loop's data and split are its own: its rounds and plans)
                return (f"the data size: {self.training_transitions} training transitions; more rounds or plans "
                        "(--rounds, --initial-plans, --plans-per-round)")
            more = ("collect more trajectories (collect --count)" if self.dataset.is_simulated else
                    "record and import a longer log of the robot")
            return (f"the data size: {self.training_transitions} training transitions; {more} or train on more of "
                    f"them ({train_option('--train')})")
        return ("the data or the training budget: check the data with `stdm-drake inspect` and the learning curves "
                f"(curves.csv); raise {train_option('--epochs')} or {train_option('--patience')} if the validation "
                "error was still falling")


def train_option(flag: str) -> str:
    """`flag`, an option of `stdm-drake train`, as advice names it under the running command: as it is where that
    command takes it (train, mbrl's --epochs; the library), else as `stdm-drake train FLAG` (held-out run 40:
    compare's training warning advised --train, which compare refuses)."""
    options = running_options()
    return flag if options is None or flag in options else f"`stdm-drake train {flag}`"


def grey_box_physics(path, robot, settings, dataset, split) -> dict | None:
    """The structure's physics record of `--physics` (an identified robot of `robot`'s description), or None.
    An identified robot fitted on `dataset` must have been fitted and validated on plans this grey box
    trains or validates on (`split`), or its test plans would not be held out from the model as a whole."""
    if path is None:
        return None
    if settings.inputs != "plant_step":
        raise InputError("--physics is the grey box's plant: use it with --model G/GD (or --inputs plant_step)")
    if kind_of(path).name != "identified robot":
        raise InputError(f"--physics {path}: not an identified robot (`stdm-drake identify`'s .yaml)")
    identified = load_model_file(path)
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


def train_job(job: TrainJob) -> dict:
    """Run `job`: every check first (output folder, settings, dataset, robot, memory, disk), then one model per
    seed, each seed's verdict against the physics baselines on the validation split printed, and the summary
    written to `job.output / "summary.json"`; returns that summary (dataset, split, per seed its checkpoint,
    epochs, alpha selection and validation rows)."""

    settings, output = job.settings, pathlib.Path(job.output)
    settings.validate(given=job.given)
    settings.check_alpha(job.given)
    compute_threads(settings.threads)
    check_output_folder("-o/--output", output, inputs=[job.dataset, job.robot, job.physics, *job.inputs],
                        force=job.force)
    if job.runner.backend == "ray" and job.resume:
        raise InputError("--resume continues runs in a local folder; with --backend ray, train without it")
    existing = [seed for seed in settings.seeds if (output / f"seed{seed}" / "checkpoint.pt").exists()]
    if existing and not job.resume:
        raise InputError(f"{output / f'seed{existing[0]}' / 'checkpoint.pt'} exists; pass --resume "
                         "to continue it or choose another --output")
    dataset = load_dataset(job.dataset)
    robot = None   # (without a robot, train loads no Drake plant at all)
    if job.robot is not None or settings.structure().uses_nominal_model:
        robot = resolve_robot(job.robot, dataset)
    if settings.uses_derivative() and robot is not None:
        warn_about_fast_damped_joints(robot, dataset.sample_period)
    split, per_group = dataset_split(dataset, settings)
    structure = settings.structure(grey_box_physics(job.physics, robot, settings, dataset, split))
    name = settings.model_name()
    sources, source_line, mismatch = derivative_sources(dataset, split, settings)
    problem = training_problem(dataset, split, model_type=name, activation=settings.activation,
                               hidden_width=settings.hidden_width, hidden_layers=settings.hidden_layers,
                               ensemble_size=settings.ensemble_size, delta=not settings.direct,
                               derivative_source=sources, action_rate=settings.action_rate,
                               structure=structure, robot=robot, split_seed=settings.split_seed, per_group=per_group,
                               threads=settings.threads, network=settings.network)
    model_config = problem.model_config
    settings.training_config(settings.seeds[0])  # its checks, before the output folder is made
    grid = settings.alpha_choices()
    settings.check_memory(problem.transitions, max(model_config.ensemble_size, len(grid) if grid else 1))
    network = network_class(settings.network)
    weights = network.weight_count(model_config)
    check_free_space(output / f"seed{settings.seeds[0]}" / "checkpoint.pt",   # weights, Adam's state (float32)
                     len(settings.seeds) * (16 * weights + CHECKPOINT_RESERVE_BYTES))
    verdict = LearningVerdict(dataset, split, robot, structure, name, settings, problem.transitions, sources,
                              mismatch)
    job.runner.validate()
    if job.runner.backend == "ray":
        connect(job.runner)   # joins the cluster now: an unreachable one stops before any work
    mark_output_folder(output)
    print(f"{name}: {network.describe_config(model_config)}, "
          f"{model_config.ensemble_size} member(s), {'delta' if model_config.residual else 'direct'}, "
          f"{structure.label}; train {len(split.train)} / val {len(split.val)} / test {len(split.test)} trajectories "
          f"({problem.transitions} / {len(verdict.val.state)} transitions)")
    if source_line:
        print(source_line)
    if grid is not None:
        print(f"{'relative ' if settings.alpha_scale == 'relative' else ''}alpha chosen by validation from "
              f"{', '.join(f'{a:g}' for a in grid)}"
              + (f" for each of the derivative sources {', '.join(sources)}" if isinstance(sources, tuple) else "")
              + ("; an alpha > 0 replaces naive training (0) only where its gain over it is above 0 at 95 % "
                 "confidence, paired over the validation trajectories" if 0.0 in grid else ""))
    fit_options = dict(alpha_grid=grid, checkpoint_every=settings.checkpoint_every, metadata=problem.metadata)
    entries = {}
    for seed, result, selection in fit_seeds(problem, settings, fit_options, job.runner, output, not job.progress):
        entries[seed] = write_seed_files(output / f"seed{seed}", name, seed, result, selection)
        entries[seed].update(verdict.report(seed, output / f"seed{seed}" / "checkpoint.pt", result, selection))
    summary = dict(written_by=written_by(), model_type=name, structure=structure.as_dict(), dataset=str(job.dataset),
                   dataset_sha256=dataset.sha256, robot=None if robot is None else robot.record(),
                   physics=None if job.physics is None else str(job.physics), network=settings.network,
                   settings=dataclasses.asdict(settings), settings_files=[str(path) for path in job.inputs if path],
                   derivative_sources=verdict.source_record(),
                   split={key: list(map(int, value)) for key, value in split.as_dict().items()},
                   seeds={str(seed): {k: v for k, v in entries[seed].items() if k != "alpha_selection"}
                          for seed in settings.seeds})
    selections = {str(seed): entries[seed]["alpha_selection"] for seed in settings.seeds
                  if "alpha_selection" in entries[seed]}
    if selections:
        summary["alpha_selection"] = selections
    write_text_atomic(output / "summary.json", json.dumps(summary, indent=2) + "\n")
    return summary
