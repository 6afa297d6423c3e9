"""`stdm-drake mpc`: closed-loop MPC of the robot's plant with the plant model and learned models as
predictors. On an affected plant (`--plant-effects`, or the effects the dataset records) the plant model
is the robot's description (the nominal model a user has, "plant"), beside the affected plant itself
("true-plant", an oracle)."""
import dataclasses
import re
import sys

from stdm_drake.closed_loop.comparison import (
    ClosedLoopResult, closed_loop_failures, compare_controllers, held_out_references, plot_results, real_time_lines,
    summarize, summary_table
)
from stdm_drake.closed_loop.mpc import mpc_config_for
from stdm_drake.closed_loop.tuning import with_setting
from stdm_drake.commands.arguments import (add_plant_effects_argument, add_robot_argument, add_visualization_argument,
                                           check_meshcat_allowed, command_robot, command_visualization)
from stdm_drake.errors import InputError
from stdm_drake.learning.physics import PlantModel
from stdm_drake.robots.plant import DEFAULT_PLANT_TIME_STEP, PlantConfig, plant_effects_for
from stdm_drake.outputs import (add_force_argument, check_output_file, check_output_folder, mark_output_folder,
                                written_by)


MODEL_NAME = re.compile(r"[A-Za-z0-9_.+-]{1,40}")   # a --model name: a column of mpc.csv and mpc.md


def add_arguments(parser) -> None:
    import pathlib
    parser.add_argument("dataset", type=pathlib.Path, help="tracking dataset whose held-out plans are the references")
    parser.add_argument("--model", action="append", default=[], metavar="NAME=FILE",
                        help="a model to compare (repeatable): a checkpoint, e.g. DD=runs/dd/seed0/checkpoint.pt, or an "
                             "identified robot, e.g. identified=identified.yaml")
    parser.add_argument("--no-plant", action="store_true",
                        help="leave out the plant-as-model reference MPCs (nominal and, on an affected plant, true)")
    parser.add_argument("--excitation-references", action="store_true",
                        help="with an excitation dataset (no plans): track its recorded trajectories instead, e.g. "
                             "for an arm too small for task-space plans")
    parser.add_argument("--plans", type=int, default=3, help="held-out plans to track (default 3)")
    parser.add_argument("--tune", type=int, default=0, metavar="N",
                        help="first choose each model's MPC setting (effort-weight scale 1, 1e-2, 1e-4 x observer gain "
                             "0, 0.3, 1) on N tuning plans: the models' validation plans, then any plan neither "
                             "tracked nor trained on (9 closed loops per plan and model; README, 'Plant effects'); the gain replaces "
                             "the settings' disturbance_gain, so a --config file that sets it is refused")
    parser.add_argument("--config", type=pathlib.Path,
                        help="MPC settings YAML (default: controllers/mpc.yaml; for another robot, its effort "
                             "weights derived from the robot's inertia, see README)")
    add_robot_argument(parser, "must be the dataset's robot")
    add_plant_effects_argument(parser, "the closed loops run on the affected plant (default: the effects the dataset "
                                       "records, if any)")
    parser.add_argument("--output", "-o", type=pathlib.Path, default=pathlib.Path("out/mpc"),
                        help="folder for mpc.md, mpc.csv, mpc.json and mpc.png")
    parser.add_argument("--html", type=pathlib.Path, help="Meshcat recording: plant (robot) vs reference (ghost)")
    add_visualization_argument(parser)
    parser.add_argument("--quiet", action="store_true")
    add_force_argument(parser)


def run(args) -> int:
    import json

    import torch

    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.files import write_text_atomic
    from stdm_drake.commands.arguments import command_model
    torch.set_num_threads(1)  # the solver makes many small calls; threads only add overhead
    if args.plans < 1:
        raise InputError(f"--plans must be >= 1, got {args.plans}")
    if args.tune < 0:
        raise InputError(f"--tune must be >= 0 (0: off), got {args.tune}")
    for entry in args.model:
        name, separator, path = entry.partition("=")
        if not separator or not name or not path:
            raise InputError(f"--model takes NAME=FILE, got {entry!r}")
        if not MODEL_NAME.fullmatch(name):
            shown = repr(name) if len(name) <= 48 else repr(name[:40]) + f"... ({len(name)} characters)"
            raise InputError(f"--model name {shown}: letters, digits, '_', '-', '.' and '+' only (it heads a column of "
                             "mpc.csv and mpc.md), at most 40 characters")
    checkpoints = [entry.partition("=")[2] for entry in args.model]
    names = [entry.partition("=")[0] for entry in args.model]
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise InputError(f"--model names must differ; {', '.join(repeated)} given more than once")
    reserved = sorted(name for name in names if name.lower() in ("plant", "true-plant"))   # (in any case: beside
    if reserved:                                                                            # the plant's own rows)
        raise InputError(f"--model name {reserved[0]!r} is the plant model's; name the learned model otherwise")
    inputs = [args.dataset, args.config, args.robot, args.visualization, args.plant_effects, *checkpoints]
    check_output_folder("-o/--output", args.output, inputs=inputs, force=args.force)
    check_output_file("--html", args.html, kind="html", inputs=inputs, force=args.force)
    if args.html:
        check_meshcat_allowed("--html")
    visualization = command_visualization(args)
    dataset = load_dataset(args.dataset)
    robot = command_robot(args, dataset)
    robot.check_fully_actuated("MPC")
    if not dataset.has_plan and not args.excitation_references:
        raise InputError(f"{args.dataset} is {'an excitation dataset' if dataset.is_simulated else 'a log without the plan'}"
                         ": it has no plans to track; give a dataset with plans, or --excitation-references to track "
                         "its recorded trajectories")
    if dataset.has_plan and args.excitation_references:
        raise InputError(f"--excitation-references tracks the recorded trajectories of a dataset without plans; "
                         f"{args.dataset} has plans, which mpc tracks, so it would be ignored")
    config = mpc_config_for(robot, args.config)
    if args.tune:
        from stdm_drake.config import file_keys
        if "disturbance_gain" in file_keys(args.config):
            raise InputError(f"--tune chooses the observer gain (0, 0.3 or 1 per model), so the disturbance_gain of "
                             f"{args.config} would be ignored; leave it out of the file, or leave out --tune")
    time_step = dataset.metadata.plant_time_step or DEFAULT_PLANT_TIME_STEP   # the data's plant step
    effects = plant_effects_for(args.plant_effects if args.plant_effects is not None else
                                dataset.metadata.plant_effects, robot, time_step)
    plant_config = PlantConfig.discrete(time_step, effects=effects)
    if effects is not None:
        print(f"plant effects: {args.plant_effects or 'as recorded in ' + str(args.dataset)}: {effects.summary()}"
              + ("; torque noise seeded by plan index: every model meets the same draws on a plan"
                 if effects.has_torque_noise() else ""),
              file=sys.stderr)
    learned = [command_model(path, robot, name=name) for name, path in zip(names, checkpoints)]
    for model in learned:
        model.checkpoint.check_fits(dataset)
    learned = [model.for_control() if isinstance(model, PlantModel) else model for model in learned]   # (identified)
    plants = [PlantModel(dataset.sample_period, robot=robot, integrator="rk4")]
    if effects is not None:
        plants.append(PlantModel(dataset.sample_period, plant_config, robot=robot, integrator="rk4"))
    models = ([] if args.no_plant else plants) + learned
    if not models:
        raise InputError("nothing to compare: give --model NAME=FILE or keep the plant model")
    references = held_out_references(dataset, [model.checkpoint for model in learned], args.plans)
    if len(references) < args.plans:
        raise InputError(f"--plans {args.plans}: {args.dataset} has only {len(references)} held-out plans")
    recorder = None
    if args.html:
        from stdm_drake.robots.recorder import TrajectoryRecorder
        recorder = TrajectoryRecorder(dataset.sample_period, ghost=True, robot=robot, visualization=visualization)
    announce = lambda line: print(line, file=sys.stderr, flush=True)  # noqa: E731
    tuning = None
    if args.tune:
        from stdm_drake.closed_loop.comparison import tuning_references
        from stdm_drake.closed_loop.tuning import tune
        plans = tuning_references(dataset, [model.checkpoint for model in learned], args.tune,
                                  [index for index, _ in references])
        chosen, tried = tune(models, plans, config, plant_config, robot=robot, progress=not args.quiet)
        tuning = dict(plans=[index for index, _ in plans], chosen=chosen,
                      runs=[dict(dataclasses.asdict(result), effort_scale=setting[0], observer_gain=setting[1])
                            for setting, result in tried])
        for name, setting in chosen.items():
            print(f"MPC setting of {name} (chosen on {len(plans)} tuning plans): effort weights x {setting[0]:g}, "
                  f"observer gain {setting[1]:g}", file=sys.stderr)
    runs = [(models, config)] if tuning is None else [([model], with_setting(config, chosen[model.name]))
                                                      for model in models]   # tuned: each with its own, in order
    results = [result for group, group_config in runs
               for result in compare_controllers(group, references, group_config, plant_config, progress=not args.quiet,
                                                 recorder=recorder, robot=robot, announce=announce)]
    rows = summarize(results, dataset.sample_period)
    table = summary_table(rows)
    if tuning is not None:
        table += "\n\nMPC settings chosen on the tuning plans (indices " + ", ".join(map(str, tuning["plans"])) + "): " + "; ".join(
            f"{name} effort x {setting[0]:g}, observer gain {setting[1]:g}" for name, setting in chosen.items())
    timing = real_time_lines(rows, dataset.sample_period)
    table += "\n\n" + "\n".join(f"- {line}" for line in timing)
    print(table)
    out = args.output
    mark_output_folder(out)
    write_text_atomic(out / "mpc.md", table + "\n")
    write_text_atomic(out / "mpc.json", json.dumps(dict(written_by=written_by(), summary=rows, runs=[dataclasses.asdict(r) for r in results],
                                                        tuning=tuning), indent=1))
    columns = [field.name for field in dataclasses.fields(ClosedLoopResult) if field.name != "q_error"]
    write_text_atomic(out / "mpc.csv", "\n".join([",".join(columns)] + [
        ",".join(str(getattr(result, column)) for column in columns) for result in results]) + "\n")
    plot_results(results, dataset.sample_period, out / "mpc.png")
    print(f"wrote {out}/mpc.md, mpc.csv, mpc.json, mpc.png")
    if recorder is not None:
        recorder.finish(args.html, what="robot: plant under MPC; translucent orange: the reference")
    failures = closed_loop_failures(results)
    for failure in failures:
        print(f"stdm-drake mpc: error: {failure}", file=sys.stderr)
    return 2 if failures else 0
