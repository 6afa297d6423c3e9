"""The model-based RL loop on the affected UR-10 against open-loop data of the same budget (docs/sampling_mpc.md, Part B).

    python tools/study.py mbrl-loop [--quick] [--workers 2] [-o docs/results/mbrl_loop] [--data out/mbrl_loop_data]

Five loops (`experiments.mbrl_loop.run_loop`, training seeds 0-4) from the same 8 initial plans, each refitting
D on its own closed loops for 5 rounds (the iLQR with the reality gap's tuned setting), evaluated every round on
Part A's 8 test plans, with the same plans tracked by the dithered PID beside them (open-loop data, same
budget). Per loop: round 0's q MSE / round 5's, and the open-loop model's / round 5's, with Student-t
intervals over the loops and the design's verdicts. Loops resume from --data.
"""
import argparse
import math
import pathlib
import time

import numpy as np

FULL = dict(loops=5, rounds=5, initial_plans=8, plans_per_round=8, epochs=300, reference_steps=None)
QUICK = dict(loops=2, rounds=1, initial_plans=8, plans_per_round=4, epochs=3, reference_steps=6)


def test_references(robot, effects, data_folder: pathlib.Path, steps, workers: int) -> list:
    """Part A's test plans: the first 2 of each start pose's test plans of the reality gap's closed-loop dataset
    (seed 0, split 18 / 2 / 5 per pose, split seed 0), as (index, Reference)."""
    from stdm_drake.closed_loop.comparison import reference_of
    from stdm_drake.closed_loop.mpc import Reference
    from stdm_drake.data.dataset import split_trajectories
    from studies.reality_gap import dataset, start_poses
    data = dataset(data_folder, "closed_loop", effects, start_poses(robot) * 25, 0, robot, workers)
    test = split_trajectories(data.groups, 18, 2, 5, 0, per_group=True).test
    chosen, seen = [], {}
    end = None if steps is None else steps + 1
    for index in test:
        group = int(data.groups[index])
        if seen.get(group, 0) < 2:
            seen[group] = seen.get(group, 0) + 1
            reference = reference_of(data, int(index))
            chosen.append((int(index), Reference(q=reference.q[:end], v=reference.v[:end])))
    return chosen


def one_loop(design: dict, seed: int, folder: str, robot_path: str, effects, references: list) -> dict:
    """One loop of training seed `seed` in `folder` (a pool job)."""
    import dataclasses
    import torch
    torch.set_num_threads(1)
    from stdm_drake.closed_loop.ilqr import Ilqr
    from stdm_drake.closed_loop.mpc import mpc_config_for
    from stdm_drake.closed_loop.tuning import with_setting
    from stdm_drake.experiments.mbrl_loop import LoopConfig, run_loop
    from stdm_drake.robots.robot import load_robot
    from studies.sampling_mpc import SETTING
    robot = load_robot(robot_path)
    mpc = dataclasses.replace(with_setting(mpc_config_for(robot), SETTING), optimizer=Ilqr(max_iterations=1))
    config = LoopConfig(output=pathlib.Path(folder), robot=robot, mpc=mpc, plant_effects=effects, model="D",
                        train=dict(epochs=design["epochs"]), rounds=design["rounds"],
                        initial_plans=design["initial_plans"], plans_per_round=design["plans_per_round"], seed=seed,
                        open_loop=True)
    return run_loop(config, references, say=lambda line: print(f"loop {seed}: {line}", flush=True))


def interval(logs: list) -> dict:
    from studies.reality_gap import seed_interval
    return seed_interval(logs)


def verdicts(summaries: list) -> dict:
    """The design's two endpoints over the loops."""
    falls = [math.log(s["rounds"][0]["q_mse_geometric_mean"] / s["rounds"][-1]["q_mse_geometric_mean"])
             for s in summaries]
    versus = [math.log(s["rounds"][-1]["open_loop"]["q_mse_geometric_mean"] / s["rounds"][-1]["q_mse_geometric_mean"])
              for s in summaries]
    fall, against = interval(falls), interval(versus)
    left = sum(s["rounds"][-1]["steps_outside_limits"] for s in summaries)
    if fall.get("low") is None:
        fall_text = "one loop: no interval"
    elif left:
        fall_text = f"not met: the last round's evaluations left the limits on {left} steps"
    elif fall["low"] >= 3:
        fall_text = "met"
    elif fall["low"] > 1:
        fall_text = "falls but less than 3x shown"
    elif fall["high"] < 1:
        fall_text = "rises"
    else:
        fall_text = "does not fall"
    if against.get("low") is None:
        against_text = "one loop: no interval"
    elif against["low"] > 1:
        against_text = "the loop's data beat open-loop data"
    elif against["high"] < 1:
        against_text = "open-loop data beat the loop's"
    else:
        against_text = "inconclusive"
    return dict(round0_over_last=dict(fall, verdict=fall_text), open_loop_over_last=dict(against, verdict=against_text),
                last_round_steps_outside_limits=left)


def per_round(summaries: list) -> list:
    """Per round: geometric mean over the loops of the loop's and the open-loop model's q MSE, limits, cuts."""
    rows = []
    for index in range(len(summaries[0]["rounds"])):
        loop = [s["rounds"][index] for s in summaries]
        row = dict(round=index, trajectories=[r["trajectories"] for r in loop],
                   q_mse=float(np.exp(np.mean([math.log(r["q_mse_geometric_mean"]) for r in loop]))),
                   steps_outside_limits=int(sum(r["steps_outside_limits"] for r in loop)),
                   learned=sum(r["learned"].get("verdict", "").startswith("learned") for r in loop),
                   safety_stops=int(sum(r.get("collection", {}).get("safety_stops", 0) for r in loop)))
        if all("open_loop" in r for r in loop):
            row.update(open_loop_q_mse=float(np.exp(np.mean([math.log(r["open_loop"]["q_mse_geometric_mean"])
                                                             for r in loop]))),
                       open_loop_steps_outside_limits=int(sum(r["open_loop"]["steps_outside_limits"] for r in loop)),
                       open_loop_learned=sum(r["open_loop"]["learned"].get("verdict", "").startswith("learned")
                                             for r in loop))
        rows.append(row)
    return rows


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from studies.affected_plant import add_affected_plant_arguments
    add_affected_plant_arguments(parser, "mbrl_loop", quick_minutes=2)
    parser.add_argument("--reference-data", type=pathlib.Path,
                        default=pathlib.Path(__file__).resolve().parents[2] / "out" / "sampling_mpc_data",
                        help="Part A's data folder (its closed-loop dataset holds the test plans)")


def run(args: argparse.Namespace) -> int:
    import json
    from stdm_drake.cluster import RunnerConfig, job_pool
    from stdm_drake.files import write_text_atomic
    from studies.affected_plant import quick_folders, robot_and_effects
    quick_folders(args, "mbrl_loop")
    robot, effects = robot_and_effects(args)
    design = QUICK if args.quick else FULL
    started = time.perf_counter()
    references = test_references(robot, effects, args.reference_data, design["reference_steps"], args.workers)
    with job_pool(RunnerConfig(workers=args.workers)) as pool:
        futures = [pool.submit(one_loop, design, seed, str(args.data / f"seed{seed}"), str(robot.config_path), effects,
                               references) for seed in range(design["loops"])]
        summaries = [future.result() for future in futures]
    results = dict(written_by="tools/study.py mbrl-loop", provenance=args.provenance, quick=args.quick, design=design,
                   evaluation_plans=[index for index, _ in references], verdicts=verdicts(summaries),
                   rounds=per_round(summaries), loops=summaries, seconds=round(time.perf_counter() - started, 1))
    args.output.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.output / "results.json", json.dumps(results, indent=1))
    header = "round,loop_q_mse,open_loop_q_mse,steps_outside_limits,open_loop_steps_outside_limits,safety_stops\n"
    write_text_atomic(args.output / "rounds.csv", header + "".join(
        f"{r['round']},{r['q_mse']:.6g},{r.get('open_loop_q_mse', '')},{r['steps_outside_limits']},"
        f"{r.get('open_loop_steps_outside_limits', '')},{r['safety_stops']}\n" for r in results["rounds"]))
    for row in results["rounds"]:
        print(f"round {row['round']}: loop q MSE {row['q_mse']:.3g} rad²"
              + (f", open-loop data {row['open_loop_q_mse']:.3g}" if "open_loop_q_mse" in row else "")
              + f", steps outside the limits {row['steps_outside_limits']}, safety stops {row['safety_stops']}")
    for name, value in results["verdicts"].items():
        if isinstance(value, dict):
            print(f"{name}: {value['ratio']:.3g}x" + (f" [{value['low']:.3g}, {value['high']:.3g}]" if value.get("low")
                                                      else "") + f": {value['verdict']}")
    print(f"-> {args.output} in {results['seconds']:.0f} s")
    return 0
