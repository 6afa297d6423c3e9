"""`stdm-drake mpc`: closed-loop MPC of the robot's plant with the plant model and learned models as
predictors. On an affected plant (`--plant-effects`, or the effects the dataset records) the plant model
is the robot's description (the nominal model a user has, "plant"), beside the affected plant itself
("true-plant", an oracle). The study itself: `stdm_drake.closed_loop.study.run_mpc_study`."""
import sys

from stdm_drake.closed_loop.study import MpcStudy, run_mpc_study
from stdm_drake.commands.arguments import add_plant_effects_argument, add_robot_argument, add_visualization_argument
from stdm_drake.errors import InputError
from stdm_drake.outputs import add_force_argument


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
                             "tracked nor trained on (9 closed loops per plan and model; docs/guides/robots.md, 'Plant effects'); the gain replaces "
                             "the settings' disturbance_gain, so a --config file that sets it is refused")
    parser.add_argument("--config", type=pathlib.Path,
                        help="MPC settings YAML: the optimizer as a tagged value (`optimizer: !Rti {...}`, !Ilqr, "
                             "!Icem, !Mppi, !Cem), and how it keeps the robot's limits (`constraints: {mode: soft}`: "
                             "torque box hard, position and velocity limits soft, the default; hard; off: clip) "
                             "(default: controllers/mpc.yaml; for another robot, its effort weights derived from the "
                             "robot's inertia, see docs/guides/robots.md)")
    add_robot_argument(parser, "must be the dataset's robot")
    add_plant_effects_argument(parser, "the closed loops run on the affected plant (default: the effects the dataset "
                                       "records, if any)")
    parser.add_argument("--output", "-o", type=pathlib.Path,
                        help="folder for mpc.md, mpc.csv, mpc.json and mpc.png (default: out/mpc, or the first of "
                             "out/mpc-2, out/mpc-3, ... that holds no results: a second run keeps the first's)")
    parser.add_argument("--html", type=pathlib.Path, help="Meshcat recording: plant (robot) vs reference (ghost)")
    add_visualization_argument(parser)
    parser.add_argument("--quiet", action="store_true")
    add_force_argument(parser)


def model_files(entries: list[str]) -> list[tuple]:
    """The (name, file) pairs of the --model NAME=FILE arguments."""
    import pathlib
    pairs = []
    for entry in entries:
        name, separator, path = entry.partition("=")
        if not separator or not name or not path:
            raise InputError(f"--model takes NAME=FILE, got {entry!r}")
        pairs.append((name, pathlib.Path(path)))
    return pairs


def run(args) -> int:
    result = run_mpc_study(MpcStudy(
        dataset=args.dataset, models=model_files(args.model), plant=not args.no_plant, plans=args.plans,
        tune=args.tune, settings=args.config, robot=args.robot, plant_effects=args.plant_effects,
        excitation_references=args.excitation_references, output=args.output, html=args.html,
        visualization=args.visualization, progress=not args.quiet, force=args.force))
    for failure in result.failures:
        print(f"stdm-drake mpc: error: {failure}", file=sys.stderr)
    return 2 if result.failures else 0
