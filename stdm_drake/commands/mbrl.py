"""`stdm-drake mbrl`: the model-based RL loop: act with the model's MPC, collect the closed loop's data on the
(affected) plant, refit, for N rounds from a small dataset (`stdm_drake.experiments.mbrl_loop`)."""
import argparse
import pathlib

from stdm_drake.commands.arguments import add_plant_effects_argument
from stdm_drake.outputs import add_force_argument


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--output", "-o", type=pathlib.Path, default=pathlib.Path("out/mbrl"),
                        help="folder of the rounds (default out/mbrl); a rerun into the same folder resumes the loop")
    parser.add_argument("--robot", type=pathlib.Path, help="robot config YAML (default: the UR-10's, models/ur10.yaml)")
    add_plant_effects_argument(parser, "the plant the loop acts on and collects from")
    parser.add_argument("--config", type=pathlib.Path,
                        help="MPC settings YAML, any optimizer (default: the robot's; shipped: "
                             "stdm-drake:controllers/mpc_ilqr_tuned.yaml, mpc_icem.yaml, mpc_mppi.yaml, mpc_cem.yaml)")
    parser.add_argument("--model", default="D", type=str.upper, help="`train`'s model type (default D)")
    parser.add_argument("--epochs", type=int, default=300, help="training epochs per round at most (default 300)")
    parser.add_argument("--rounds", type=int, default=5, help="refits after the first model (default 5)")
    parser.add_argument("--initial-plans", type=int, default=8,
                        help="plans of the initial dataset, at least 2 per start pose: training validates on one "
                             "per pose (default 8, for the shipped plans' 4 start poses)")
    parser.add_argument("--plans-per-round", type=int, default=8, help="plans the MPC tracks each round (default 8)")
    parser.add_argument("--evaluation-plans", type=int, default=8, help="plans every round is evaluated on (default 8)")
    parser.add_argument("--seed", type=int, default=0, help="the models' training seed (default 0)")
    parser.add_argument("--open-loop", action="store_true",
                        help="also train on the same plans tracked by the collection controller (the same data "
                             "budget collected open loop) and evaluate it beside every round")
    parser.add_argument("--quiet", action="store_true", help="no progress bar and no line per round")
    add_force_argument(parser)


def run(args: argparse.Namespace) -> int:
    from stdm_drake.closed_loop.mpc import mpc_config_for
    from stdm_drake.data.compatibility import resolve_robot
    from stdm_drake.experiments.mbrl_loop import LoopConfig, check_loop_folder, run_loop
    from stdm_drake.outputs import check_output_folder, mark_output_folder
    from stdm_drake.robots.plant_effects_check import plant_effects_for
    robot = resolve_robot(args.robot)
    config = LoopConfig(output=args.output, robot=robot, mpc=mpc_config_for(robot, args.config),
                        plant_effects=plant_effects_for(args.plant_effects, robot, 0.001), model=args.model,
                        train=dict(epochs=args.epochs), rounds=args.rounds, initial_plans=args.initial_plans,
                        plans_per_round=args.plans_per_round, evaluation_plans=args.evaluation_plans, seed=args.seed,
                        open_loop=args.open_loop)
    config.validate()
    check_loop_folder(args.output, args.rounds)   # (with --force too: another loop's rounds are never changed)
    check_output_folder("-o/--output", args.output, inputs=(args.robot, args.config, args.plant_effects),
                        force=args.force)
    mark_output_folder(args.output)
    summary = run_loop(config, say=(lambda line: None) if args.quiet else print, progress=not args.quiet)
    last = summary["rounds"][-1]
    first = summary["rounds"][0]
    from stdm_drake.files import line_text
    from stdm_drake.learning.evaluate import times_better
    print(f"round 0 -> {last['round']}: closed-loop q MSE {first['q_mse_geometric_mean']:.3g} -> "
          f"{last['q_mse_geometric_mean']:.3g} rad² "
          f"({times_better(first['q_mse_geometric_mean'] / last['q_mse_geometric_mean'])}); "
          f"{line_text(args.output / 'summary.json')}")
    if last["steps_outside_limits"]:
        from stdm_drake.experiments.mbrl_causes import failure_line
        print(f"stdm-drake mbrl: error: {failure_line(last)}", file=__import__("sys").stderr)
        return 2   # (as `mpc` and `reproduce` where a closed loop leaves the limits)
    return 0
