"""One MPC study, the library's `stdm-drake mpc`: prediction models compared in closed loop under the same MPC
on held-out plans of a dataset (the plant of the dataset's robot, every model on the same plans), optionally
each model's setting tuned first on other plans; its table printed and written with the runs, a plot and
what it ran on (mpc.md, mpc.csv, mpc.json, mpc.png).

    study = MpcStudy(dataset=pathlib.Path("data.h5"), models=[("DD", pathlib.Path("runs/dd/seed0/checkpoint.pt"))],
                     optimizer=Ilqr(max_iterations=3), output=pathlib.Path("out/mpc-ilqr"))
    result = run_mpc_study(study)     # every closed loop, the summary rows, result.record: what mpc.json holds
"""
import collections
import dataclasses
import pathlib
import re
import sys

from stdm_drake.closed_loop.comparison import (ClosedLoopResult, closed_loop_failures, compare_controllers,
                                               constraint_lines,
                                               draw_results, held_out_references, real_time_lines, summarize,
                                               summary_table)
from stdm_drake.closed_loop.failure_causes import loop_causes
from stdm_drake.closed_loop.optimizer import OptimizerSettings
from stdm_drake.errors import InputError
from stdm_drake.files import line_text, atomic_paths, escaped_names
from stdm_drake.closed_loop.mpc import mpc_config_for, mpc_settings_file
from stdm_drake.data.compatibility import resolve_robot
from stdm_drake.outputs import check_output_file, check_output_folder, fresh_default_folder, mark_output_folder
from stdm_drake.config import file_keys
from stdm_drake.robots.plant import Dynamics, joint_limits
from stdm_drake.robots.station import gravity_beyond_effort, loop_effects
from stdm_drake.robots.plant_effects_check import plant_effects_for
from stdm_drake.dynamics.model_files import kind_of, load_model
from stdm_drake.dynamics.physics import PlantModel
from stdm_drake.closed_loop.comparison import tuning_references
from stdm_drake.closed_loop.tuning import tune, with_setting
from stdm_drake.provenance import results_header

DEFAULT_OUTPUT = pathlib.Path("out/mpc")   # without an output folder: this one, or out/mpc-2, -3, ... (a fresh one)
MODEL_NAME = re.compile(r"[A-Za-z0-9_.+-]{1,40}")   # a model's name: a column of mpc.csv and mpc.md
PLANT_NAMES = ("plant", "true-plant")   # the plant models' rows (in any case: no model may take them)
# Models one study compares: each is a closed loop per plan (seconds each) and a column of the tables, which 100
# already make hard to read; 1,000 ran for about 70 minutes, 10,000 loaded for minutes without a line
MAX_MODELS = 100


@dataclasses.dataclass
class MpcStudy:
    """What one MPC study needs.

    dataset: the .h5 file whose held-out plans are the references; models: (name, model file) pairs, each file a
    checkpoint `train` wrote or an identified robot `identify` wrote; plant: the plant-as-model rows too (the
    robot's description, "plant", and on an affected plant the affected plant itself, "true-plant");
    plans: held-out plans to track; tune: plans to choose each model's MPC setting on first (0: off;
    `tuning`); settings: the MPC settings YAML (None: the robot's, `mpc.mpc_config_for`); optimizer: the
    optimizer's settings (`rti.Rti`, `ilqr.Ilqr`, any `OptimizerSettings`) in place of the file's; robot: its
    config YAML (None: the shipped preset the dataset was collected with, else the UR-10's; must be the
    dataset's robot); plant_effects: the effects YAML of the plant the loops run on (None: those the dataset
    records, if any); excitation_references: track the recorded trajectories of a dataset without plans;
    output: the folder for mpc.md, mpc.csv, mpc.json and mpc.png (None: `DEFAULT_OUTPUT`, or the first of
    out/mpc-2, -3, ... that holds no results); html: a Meshcat recording of every loop (plant beside the
    reference) with Drake's VisualizationConfig YAML `visualization`; progress: a progress bar; force: replace
    outputs stdm-drake did not write."""
    dataset: pathlib.Path
    models: list = dataclasses.field(default_factory=list)
    plant: bool = True
    plans: int = 3
    tune: int = 0
    settings: pathlib.Path | None = None
    optimizer: OptimizerSettings | None = None
    robot: pathlib.Path | None = None
    plant_effects: pathlib.Path | None = None
    excitation_references: bool = False
    output: pathlib.Path | None = None
    html: pathlib.Path | None = None
    visualization: pathlib.Path | None = None
    progress: bool = True
    force: bool = False

    def validate(self) -> None:
        """InputError (one line) for a request no study can run, before any file is read: no plan to track, a
        negative tuning count, a model name that is not a table column, names given twice or a plant's name,
        an optimizer that is none or whose settings it refuses."""
        if self.plans < 1:
            raise InputError(f"--plans must be >= 1, got {self.plans}")
        if self.tune < 0:
            raise InputError(f"--tune must be >= 0 (0: off), got {self.tune}")
        if len(self.models) > MAX_MODELS:
            raise InputError(f"{len(self.models):,} --model arguments; one study compares at most {MAX_MODELS:,} (each "
                             "is a closed loop per plan): split them over several runs")
        names = [name for name, _ in self.models]
        for name in names:
            if not MODEL_NAME.fullmatch(name):
                shown = repr(name) if len(name) <= 48 else repr(name[:40]) + f"... ({len(name)} characters)"
                raise InputError(f"--model name {shown}: letters, digits, '_', '-', '.' and '+' only (it heads a column "
                                 "of mpc.csv and mpc.md), at most 40 characters")
        repeated = sorted(name for name, times in collections.Counter(names).items() if times > 1)
        if repeated:
            raise InputError(f"--model names must differ; {', '.join(repeated)} given more than once")
        reserved = sorted(name for name in names if name.lower() in PLANT_NAMES)
        if reserved:
            raise InputError(f"--model name {reserved[0]!r} is the plant model's; name the learned model otherwise")
        if self.optimizer is not None:
            if not isinstance(self.optimizer, OptimizerSettings):
                raise InputError(f"the optimizer must be an OptimizerSettings (e.g. Rti(), Ilqr()), got {self.optimizer!r}")
            self.optimizer.validate()

    def inputs(self) -> list:
        """The files the study reads (no output may be one of them)."""
        return [self.dataset, self.settings, self.robot, self.visualization, self.plant_effects,
                *(path for _, path in self.models)]


@dataclasses.dataclass
class MpcStudyResult:
    """A study's outcome: every closed loop (`ClosedLoopResult`), one summary row per model (`summarize`), the
    table mpc.md holds, the lines naming the models whose loops are no result (`closed_loop_failures`), the
    folder written and `record`, what mpc.json holds (inputs, settings, summary, runs, tuning)."""
    results: list
    summary: list
    table: str
    failures: list
    folder: pathlib.Path
    record: dict


def run_mpc_study(study: MpcStudy) -> MpcStudyResult:
    """Run `study`: every check first (the request, the output folder and HTML file, Meshcat allowed, the
    visualization, the dataset and its robot, the references it offers, the MPC settings, the plant effects,
    the models fitting the dataset, enough held-out plans), then the tuning if asked, the closed loops, the
    table printed and the outputs written. InputError (one line) for a bad input."""
    import torch

    from stdm_drake.data.dataset import load_dataset   # lazy: h5py
    from stdm_drake.robots.recorder import check_meshcat_allowed, recording_visualization   # lazy: matplotlib
    study.validate()
    output = pathlib.Path(study.output) if study.output is not None else fresh_default_folder(DEFAULT_OUTPUT, "mpc")
    check_output_folder("-o/--output", output, inputs=study.inputs(), force=study.force)
    check_output_file("--html", study.html, kind="html", inputs=study.inputs(), force=study.force)
    if study.html:
        check_meshcat_allowed("--html")
    visualization = recording_visualization(study.visualization, bool(study.html), "--html FILE")
    dataset = load_dataset(study.dataset)
    robot = resolve_robot(study.robot, dataset)
    robot.check_fully_actuated("MPC")
    check_references(dataset, study.excitation_references)
    config = mpc_config_for(robot, study.settings)
    if study.optimizer is not None:
        config = dataclasses.replace(config, optimizer=study.optimizer)
    if study.tune:
        if "disturbance_gain" in file_keys(study.settings):
            raise InputError(f"--tune chooses the observer gain (0, 0.3 or 1 per model), so the disturbance_gain of "
                             f"{study.settings} would be ignored; leave it out of the file, or leave out --tune")
    plant_config, effects_record = study_plant(study, dataset, robot)
    plants, learned, model_records = study_models(study, dataset, robot, plant_config)
    models = plants + learned
    limits = joint_limits(Dynamics(robot).plant)
    for model in models:   # (settings a model cannot be solved with, e.g. a PyTorch device for the plant: refused now)
        config.solver(model, limits, robot.joint_names)
    check_particles_used(config.optimizer, models)
    references = held_out_references(dataset, [model.checkpoint for model in learned], study.plans)
    if len(references) < study.plans:
        raise InputError(f"--plans {study.plans}: {study.dataset} has only {len(references)} held-out plans")
    recorder = None
    if study.html:
        from stdm_drake.robots.recorder import TrajectoryRecorder   # lazy: matplotlib
        recorder = TrajectoryRecorder(dataset.sample_period, ghost=True, robot=robot, visualization=visualization)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # the solver makes many small calls; threads only add overhead
    try:
        tuning, groups = tuned_settings(study, dataset, models, learned, references, config, plant_config, robot)
        results = [result for group, group_config in groups
                   for result in compare_controllers(group, references, group_config, plant_config,
                                                     progress=study.progress, recorder=recorder, robot=robot,
                                                     announce=say)]
    finally:
        torch.set_num_threads(threads)
    inputs = dict(dataset=dict(path=str(dataset.path), sha256=dataset.sha256),
                  robot=robot.record(),
                  plant_effects=effects_record, models=model_records,
                  mpc_settings=dict(file=_text(mpc_settings_file(robot, study.settings)),
                                    optimizer_given=study.optimizer is not None, settings=config.record()))
    failed = any(result.limit_violations for result in results)
    gravity = "" if plant_config.effects is None or not failed else gravity_beyond_effort(   # (a plant no torque holds)
        Dynamics(robot, plant_config.effects), limits.effort, [q for _, reference in references for q in reference.q],
        [robot.joint_names[index] for index in robot.actuated_indices], where="on the plans")
    # (held-out run 37: loops on elastic transmissions failed with no cause named, where `collect` names the springs)
    shaping = loop_effects(plant_config.effects, list(robot.joint_names)) if failed and not gravity else []
    effects = f"the loops ran with {', '.join(shaping)}" if shaping else ""
    result = finish(study, output, results, dataset.sample_period, inputs, tuning, recorder, config)
    causes = loop_causes(results, inputs["models"], references, config, plant_config, robot, dataset.sample_period,
                         gravity=gravity, effects=effects, say=say if study.progress else None, learned_models=learned)
    result.failures = closed_loop_failures(results, note=causes.note, model_notes=causes.model_notes)
    return result


def check_particles_used(optimizer, models) -> None:
    """InputError where a sampling optimizer's propagation over particles (`tsinf`, `ts1`) has no model of the run
    to act on: each has one deterministic member (the plant, D, DD), so every one would run as mean. (With one
    ensemble among them the others run as mean, said on their real-time line.)"""
    propagation = getattr(optimizer, "propagation", "mean")
    if propagation == "mean" or any(int(getattr(model, "ensemble_size", 1)) > 1 or getattr(model, "probabilistic", False)
                                    for model in models):
        return
    names = ", ".join(getattr(model, "name", "?") for model in models)
    raise InputError(f"{optimizer.tag()} propagation {propagation} with {optimizer.particles} particles samples an "
                     f"ensemble's members, and every model of this run ({names}) has one deterministic member; use "
                     "propagation: mean")


def say(line: str) -> None:
    """A line for the person running the study, on stderr at once."""
    print(line, file=sys.stderr, flush=True)


def _text(path) -> str | None:
    return None if path is None else str(path)


def check_references(dataset, excitation_references: bool) -> None:
    """InputError unless the dataset offers what the study tracks: its plans, or with `excitation_references`
    the recorded trajectories of a dataset without plans."""
    if not dataset.has_plan and not excitation_references:
        raise InputError(f"{dataset.path} is {'an excitation dataset' if dataset.is_simulated else 'a log without the plan'}"
                         ": it has no plans to track; give a dataset with plans, or --excitation-references to track "
                         "its recorded trajectories")
    if dataset.has_plan and excitation_references:
        raise InputError(f"--excitation-references tracks the recorded trajectories of a dataset without plans; "
                         f"{dataset.path} has plans, which mpc tracks, so it would be ignored")


def study_plant(study: MpcStudy, dataset, robot):
    """(The PlantConfig the loops run on: the plant the dataset records (its plant step, self-contact and contact
    settings) with the study's plant effects, else those the dataset records; what mpc.json records of the
    effects, None without)."""
    config = dataset.metadata.plant_config(effects=False)   # the data's plant, simulated as they were
    time_step = config.time_step
    given = study.plant_effects is not None
    effects = plant_effects_for(study.plant_effects if given else dataset.metadata.plant_effects, robot, time_step,
                                dataset.sample_period)
    if effects is None:
        return config, None
    line = (f"plant effects: {study.plant_effects if given else 'as recorded in ' + str(study.dataset)}: "
            f"{effects.summary()}" + ("; torque noise seeded by plan index: every model meets the same draws on a "
                                      "plan" if effects.has_torque_noise() else ""))
    if study.progress:   # (quiet: the line is in the table, so that a failure of the loops is the only line)
        say(line)
    config.effects = effects
    return (config,
            dict(file=str(study.plant_effects) if given else None, recorded_in_dataset=not given,
                 summary=effects.summary(), line=line))


def study_models(study: MpcStudy, dataset, robot, plant_config) -> tuple[list, list, list]:
    """(The plant models unless left out, the models of the study's model files, each checked against the
    dataset; one record per model, in that order, for mpc.json: name, kind, file, its sha256 and what it is)."""
    from stdm_drake.data.dataset import file_sha256   # lazy: h5py
    models, learned, records = [], [], []
    if study.plant:
        models.append(PlantModel(dataset.sample_period, robot=robot, integrator="rk4"))
        records.append(dict(name=models[-1].name, kind="plant", file=str(robot.model_path), sha256=robot.model_sha256(),
                            description=models[-1].describe()))
        if plant_config.effects is not None and not plant_config.effects.beyond_rigid_bodies():   # (lag, delay,
            models.append(PlantModel(dataset.sample_period, plant_config, robot=robot, integrator="rk4"))  # elasticity,
            # Stribeck friction, ripple: the RK4 model holds none)
            records.append(dict(name=models[-1].name, kind="plant with effects",
                                file=_text(study.plant_effects), sha256=None, description=models[-1].describe()))
    for name, path in study.models:
        model = load_model(path, robot, name=name, for_control=True)
        model.checkpoint.check_fits(dataset)
        learned.append(model)
        records.append(dict(name=name, kind=kind_of(path).name, file=str(path), sha256=file_sha256(path),
                            description=model.describe()))
    if not models + learned:
        raise InputError("nothing to compare: give --model NAME=FILE or keep the plant model")
    return models, learned, records


def tuned_settings(study: MpcStudy, dataset, models, learned, references, config, plant_config, robot):
    """(The tuning record, None without; the groups of models that share MPC settings, as (models, settings):
    all with `config`, or with `study.tune` each with the setting chosen for it on tuning plans, `tuning.tune`)."""
    if not study.tune:
        return None, [(models, config)]
    plans = tuning_references(dataset, [model.checkpoint for model in learned], study.tune,
                              [index for index, _ in references])
    chosen, tried = tune(models, plans, config, plant_config, robot=robot, progress=study.progress)
    for name, setting in chosen.items() if study.progress else ():   # (quiet: in the table)
        say(f"MPC setting of {name} (chosen on {len(plans)} tuning plans): effort weights x {setting[0]:g}, "
            f"observer gain {setting[1]:g}")
    configs = [with_setting(config, chosen[model.name]) for model in models]
    tuning = dict(plans=[index for index, _ in plans], chosen=chosen,
                  settings={model.name: model_config.record() for model, model_config in zip(models, configs)},
                  runs=[dict(dataclasses.asdict(result), effort_scale=setting[0], observer_gain=setting[1])
                        for setting, result in tried])
    return tuning, [([model], model_config) for model, model_config in zip(models, configs)]


def finish(study: MpcStudy, output: pathlib.Path, results: list, sample_period: float, inputs: dict,
           tuning: dict | None, recorder, config) -> MpcStudyResult:
    """The table printed (with the constraint summary of `config`'s constraints), mpc.md, mpc.json, mpc.csv and
    mpc.png written to `output`, the recording to the HTML file; the result, its failure lines left to the caller
    (`failure_causes.loop_causes` may run checks to name their causes)."""
    import json

    rows = summarize(results, sample_period)
    table = summary_table(rows)
    if tuning is not None:
        table += ("\n\nMPC settings chosen on the tuning plans (indices " + ", ".join(map(str, tuning["plans"])) + "): "
                  + "; ".join(f"{name} effort x {setting[0]:g}, observer gain {setting[1]:g}"
                              for name, setting in tuning["chosen"].items()))
    table += "\n\n" + "\n".join(f"- {line}" for line in real_time_lines(rows, sample_period))
    table += "\n\n" + "\n".join(f"- {line}" for line in constraint_lines(rows, config.constraints))
    if inputs.get("plant_effects"):
        table += f"\n- {inputs['plant_effects']['line']}"
    print(table)
    record = dict(**results_header(), inputs=inputs, summary=rows,
                  runs=[dataclasses.asdict(result) for result in results], tuning=tuning)
    mark_output_folder(output)
    columns = [field.name for field in dataclasses.fields(ClosedLoopResult) if field.name != "q_error"]
    names = ("mpc.md", "mpc.json", "mpc.csv", "mpc.png")   # (one set: a signal replaces none of them)
    with atomic_paths([output / name for name in names]) as (markdown, data, table_file, figure):
        markdown.write_text(table + "\n")
        data.write_text(json.dumps(escaped_names(record), indent=1))   # (file names as `ls -b`)
        table_file.write_text("\n".join([",".join(columns)] + [
            ",".join(str(getattr(result, column)) for column in columns) for result in results]) + "\n")
        draw_results(results, sample_period, figure)
    print(f"wrote {line_text(output)}: mpc.md, mpc.csv, mpc.json, mpc.png")
    if recorder is not None:
        recorder.finish(study.html, what="robot: plant under MPC; translucent orange: the reference")
    return MpcStudyResult(results=results, summary=rows, table=table, failures=[], folder=output, record=record)
