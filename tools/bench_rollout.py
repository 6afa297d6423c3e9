"""Benchmark: 100-step open-loop rollout, batch 1, of a single model and a 5-member ensemble.

Models: 3 hidden layers x 100, swish, state 12, action 6, delta parameterization, normalizers
fitted to synthetic robot-like data (so rollouts stay bounded); and the default structure's network of the UR-10
(the next velocity from the state, the torque and the nominal acceleration of the robot's rigid-body model). Timed
in the same run, interleaved (median over rounds):
  compiled   `LearnedModel.rollout` in the compiled core (C++, `dynamics.compiled_core`; the whole call)
  fast       stdm_drake.learning.predict.rollout on a prebuilt InferenceModel (numpy float32, the whole call)
  numpy      `LearnedModel.rollout(implementation="numpy")` (the default structure's step-by-step reference)
  baseline   a plain PyTorch loop calling the nn.Module under torch.no_grad() (ensemble: mean of members)
Goals: the compiled core (issue 54) a single model <= 0.1 ms, a 5-member ensemble <= 0.3 ms; the numpy fast path
(issue 23) a single model <= 1 ms, a 5-member ensemble <= 1.5 ms. Also shown, not part of the goals: a
probabilistic ensemble with TS-inf propagation over 20 particles, and the default structure's network.
With --write: BENCHMARKS.md's section and docs/results/compiled_step/bench_rollout.json (the medians, the
agreement between the codes and the commit the run's code is).

    python tools/bench_rollout.py [--threads 1] [--rounds 15] [--write]
"""
from __future__ import annotations

import argparse
import json
import pathlib
import statistics
import sys
import time

import numpy as np
import torch

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from benchmark_report import machine_description, start_benchmark, write_benchmark_section  # noqa: E402
from stdm_drake.files import write_text_atomic  # noqa: E402
from stdm_drake.learning.regression import RegressionData  # noqa: E402
from stdm_drake.learning.trainer import build_model  # noqa: E402
from stdm_drake.learning.models import dynamics_config  # noqa: E402
from stdm_drake.learning.predict import InferenceModel, rollout  # noqa: E402
from stdm_drake.learning.learned_model import LearnedModel  # noqa: E402
from stdm_drake.learning.structure import DEFAULT  # noqa: E402

HORIZON = 100


def robot_like_data(count: int = 2000, seed: int = 0) -> RegressionData:
    """States ~ N(0, 1), torques ~ N(0, 5), next states = x + 0.01-scale deltas."""
    rng = np.random.default_rng(seed)
    states = rng.standard_normal((count, 12))
    actions = 5.0 * rng.standard_normal((count, 6))
    return RegressionData(inputs=np.hstack([states, actions]),
                          targets=states + 0.01 * rng.standard_normal((count, 12)))


def make_model(ensemble_size: int, probabilistic: bool = False):
    model = build_model(dynamics_config(state_dim=12, action_dim=6, ensemble_size=ensemble_size,
                                        probabilistic=probabilistic), seed=0)
    model.fit_normalizers(robot_like_data())
    return model.eval()


def torch_loop(model, x0: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """The baseline: nn.Module calls in a Python loop, ensemble mean as the next state."""
    with torch.no_grad():
        state = torch.as_tensor(x0, dtype=torch.float32)[None]
        sequence = torch.as_tensor(actions, dtype=torch.float32)
        states = []
        for step in range(len(sequence)):
            mean, _ = model(torch.cat([state, sequence[step:step + 1]], dim=1))
            state = mean.mean(dim=0)
            states.append(state)
        return torch.cat(states).numpy()


def default_structure_model():
    """(the UR-10, the default structure's network as its model, 100 torques (100, 6) N m): 3 x 100 swish, the
    next velocity from [v, q, tau, nominal acceleration], input normalizers fitted to the UR-10's states near
    home, torques about gravity's and the nominal accelerations they give, outputs scaled so that the rollout
    stays bounded (a rollout's time does not depend on the weights)."""
    from stdm_drake.learning.models import ModelConfig
    from stdm_drake.robots.robot import UR10_CONFIG, load_robot
    robot = load_robot(UR10_CONFIG)
    rng = np.random.default_rng(2)
    q, v = robot.home + 0.3 * rng.standard_normal((2000, 6)), 0.5 * rng.standard_normal((2000, 6))
    features = DEFAULT.nominal_features(robot, 0.01)
    from stdm_drake.robots.plant import Dynamics
    torque = Dynamics(robot).gravity_torque(robot.home) + 5.0 * rng.standard_normal((2000, 6))
    x = np.hstack([q, v])
    phi = features.values(q, v, torque)
    state, rest = DEFAULT.split(x, torque, phi)
    inputs = np.hstack([state, rest])
    network = build_model(ModelConfig(input_dim=inputs.shape[1], output_dim=6, residual=True), seed=0)
    network.fit_normalizers(RegressionData(inputs=inputs, targets=v + 0.01 * phi))
    with torch.no_grad():    # (velocity changes of 1e-3 rad/s per step: an untrained network's rollout stays bounded)
        network.output_normalizer.mean.zero_()
        network.output_normalizer.std.fill_(1e-3)
    model = LearnedModel(network.eval(), robot=robot, structure=DEFAULT, sample_period=0.01)
    return robot, model, torque[:HORIZON]


def measure(rounds: int, repeats: int) -> tuple[dict, dict]:
    rng = np.random.default_rng(1)
    x0, actions = rng.standard_normal(12), 5.0 * rng.standard_normal((HORIZON, 6))
    single, ensemble, probabilistic = make_model(1), make_model(5), make_model(5, probabilistic=True)
    fast_single, fast_ensemble, fast_probabilistic = (InferenceModel(m) for m in (single, ensemble, probabilistic))
    learned_single, learned_ensemble = LearnedModel(single), LearnedModel(ensemble)
    assert learned_single.rollout_implementation == learned_ensemble.rollout_implementation == "compiled"
    robot, structured, torques = default_structure_model()
    start = np.concatenate([robot.home, np.zeros(6)])[None]
    structured_actions = torques[None]
    cases = {
        "single model (D), compiled": lambda: learned_single.rollout(x0[None], actions[None]),
        "single model (D), fast": lambda: rollout(fast_single, x0, actions),
        "single model (D), PyTorch module loop": lambda: torch_loop(single, x0, actions),
        "5-member ensemble (DE), compiled": lambda: learned_ensemble.rollout(x0[None], actions[None]),
        "5-member ensemble (DE), fast": lambda: rollout(fast_ensemble, x0, actions),
        "5-member ensemble (DE), PyTorch module loop": lambda: torch_loop(ensemble, x0, actions),
        "5-member PE, TS-inf 20 particles, fast": lambda: rollout(fast_probabilistic, x0, actions,
                                                                  propagation="tsinf", particles=20),
        "default structure (D, nominal acceleration), compiled": lambda: structured.rollout(start, structured_actions),
        "default structure (D, nominal acceleration), numpy": lambda: structured.rollout(
            start, structured_actions, implementation="numpy"),
    }
    def largest(first, second):
        return float(np.abs(first - second).max())
    agreement = {
        "single": largest(rollout(fast_single, x0, actions).mean, torch_loop(single, x0, actions)),
        "ensemble": largest(rollout(fast_ensemble, x0, actions).mean, torch_loop(ensemble, x0, actions)),
        "single compiled": largest(learned_single.rollout(x0[None], actions[None]).mean[0],
                                   rollout(fast_single, x0, actions).mean),
        "ensemble compiled": largest(learned_ensemble.rollout(x0[None], actions[None]).mean[0],
                                     rollout(fast_ensemble, x0, actions).mean),
        "default structure compiled": largest(structured.rollout(start, structured_actions).mean,
                                              structured.rollout(start, structured_actions,
                                                                 implementation="numpy").mean),
    }
    for case in cases.values():
        for _ in range(3):
            case()
    times = {name: [] for name in cases}
    for _ in range(rounds):
        for name, case in cases.items():
            started = time.perf_counter()
            for _ in range(repeats):
                case()
            times[name].append((time.perf_counter() - started) / repeats * 1e3)
    return {name: statistics.median(values) for name, values in times.items()}, agreement


GOALS = {"single model (D), compiled": 0.1, "5-member ensemble (DE), compiled": 0.3,   # issue 54
         "single model (D), fast": 1.0, "5-member ensemble (DE), fast": 1.5}                # issue 23


def report(medians: dict, agreement: dict, threads: int) -> str:
    lines = [f"Machine: {machine_description(threads)}.", "",
             f"Open-loop rollout, {HORIZON} steps, batch 1, 3x100 swish, state 12, action 6 (the default structure: "
             "the UR-10's next velocity from 24 inputs); median ms per rollout, cases interleaved in one run. A goal "
             "is met when the median is within it.", "",
             "| case | ms / rollout | goal | met |", "|---|---|---|---|"]
    for name, value in medians.items():
        goal = GOALS.get(name)
        lines.append(f"| {name} | {value:.3f} | {f'<= {goal:g} ms' if goal else ''} | "
                     f"{('yes' if value <= goal else 'no') if goal else ''} |")
    def ratio(slow, fast):
        return medians[slow] / medians[fast]
    lines += ["", "Speed-up of the compiled core over the numpy code in the same run: single "
              f"{ratio('single model (D), fast', 'single model (D), compiled'):.1f}x, ensemble "
              f"{ratio('5-member ensemble (DE), fast', '5-member ensemble (DE), compiled'):.1f}x, default structure "
              f"{ratio('default structure (D, nominal acceleration), numpy', 'default structure (D, nominal acceleration), compiled'):.1f}x; "
              "of the numpy fast path over the module loop: single "
              f"{ratio('single model (D), PyTorch module loop', 'single model (D), fast'):.1f}x, ensemble "
              f"{ratio('5-member ensemble (DE), PyTorch module loop', '5-member ensemble (DE), fast'):.1f}x.",
              f"Largest difference over the {HORIZON} steps: compiled against numpy {agreement['single compiled']:.1e} "
              f"(single), {agreement['ensemble compiled']:.1e} (ensemble), {agreement['default structure compiled']:.1e} "
              f"(default structure; the numpy paper's path carries the state in float32, the core in float64); the "
              f"fast path against the module loop {agreement['single']:.1e} (single), {agreement['ensemble']:.1e} "
              "(ensemble)."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads for the baseline (default 1)")
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--repeats", type=int, default=20, help="rollouts per case per round")
    parser.add_argument("--write", action="store_true",
                        help="update BENCHMARKS.md and docs/results/compiled_step/bench_rollout.json")
    args, origin = start_benchmark(parser, argv)   # (at the start: the code this run imports)
    torch.set_num_threads(args.threads)
    medians, agreement = measure(args.rounds, args.repeats)
    text = report(medians, agreement, args.threads)
    print(text)
    if args.write:
        write_benchmark_section("Learning library", "Open-loop rollout (tools/bench_rollout.py)", text, origin,
                                record=False)   # (its own results file below)
        folder = ROOT / "docs" / "results" / "compiled_step"
        folder.mkdir(parents=True, exist_ok=True)
        write_text_atomic(folder / "bench_rollout.json", json.dumps(dict(
            provenance=origin, threads=args.threads, horizon=HORIZON,
            rounds=args.rounds, repeats=args.repeats, median_ms=medians, goals_ms=GOALS,
            met={name: medians[name] <= goal for name, goal in GOALS.items()}, largest_difference=agreement),
            indent=1) + "\n")
        print("updated BENCHMARKS.md and docs/results/compiled_step/bench_rollout.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
