"""Benchmark: 100-step open-loop rollout, batch 1, of a single model and a 5-member ensemble.

Models: 3 hidden layers x 100, swish, state 12, action 6, delta parameterization, normalizers
fitted to synthetic robot-like data (so rollouts stay bounded). Timed in the same run, interleaved
(median over rounds):
  fast       stdm_drake.learning.predict.rollout on a prebuilt InferenceModel (numpy float32, the whole call)
  baseline   a plain PyTorch loop calling the nn.Module under torch.no_grad() (ensemble: mean of members)
Goals: single model <= 1 ms, 5-member ensemble <= 1.5 ms. Also shown, not part of the goals: a
probabilistic ensemble with TS-inf propagation over 20 particles.

    python tools/bench_rollout.py [--threads 1] [--rounds 15] [--write]
"""
from __future__ import annotations

import argparse
import pathlib
import statistics
import sys
import time

import numpy as np
import torch

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from benchmark_report import machine_description, write_benchmark_section  # noqa: E402
from stdm_drake.learning.regression import RegressionData  # noqa: E402
from stdm_drake.learning.trainer import build_model  # noqa: E402
from stdm_drake.learning.models import dynamics_config  # noqa: E402
from stdm_drake.learning.predict import InferenceModel, rollout  # noqa: E402

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


def measure(rounds: int, repeats: int) -> tuple[dict, dict]:
    rng = np.random.default_rng(1)
    x0, actions = rng.standard_normal(12), 5.0 * rng.standard_normal((HORIZON, 6))
    single, ensemble, probabilistic = make_model(1), make_model(5), make_model(5, probabilistic=True)
    fast_single, fast_ensemble, fast_probabilistic = (InferenceModel(m) for m in (single, ensemble, probabilistic))
    cases = {
        "single model (D), fast": lambda: rollout(fast_single, x0, actions),
        "single model (D), PyTorch module loop": lambda: torch_loop(single, x0, actions),
        "5-member ensemble (DE), fast": lambda: rollout(fast_ensemble, x0, actions),
        "5-member ensemble (DE), PyTorch module loop": lambda: torch_loop(ensemble, x0, actions),
        "5-member PE, TS-inf 20 particles, fast": lambda: rollout(fast_probabilistic, x0, actions,
                                                                  propagation="tsinf", particles=20),
    }
    agreement = {
        "single": float(np.abs(rollout(fast_single, x0, actions).mean - torch_loop(single, x0, actions)).max()),
        "ensemble": float(np.abs(rollout(fast_ensemble, x0, actions).mean
                                 - torch_loop(ensemble, x0, actions)).max()),
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


def report(medians: dict, agreement: dict, threads: int) -> str:
    goals = {"single model (D), fast": 1.0, "5-member ensemble (DE), fast": 1.5}
    lines = [f"Machine: {machine_description(threads)}.", "",
             f"Open-loop rollout, {HORIZON} steps, batch 1, 3x100 swish, state 12, action 6; median ms per "
             "rollout, cases interleaved in one run.", "",
             "| case | ms / rollout | goal |", "|---|---|---|"]
    for name, value in medians.items():
        goal = goals.get(name)
        lines.append(f"| {name} | {value:.3f} | {f'<= {goal:g} ms' if goal else ''} |")
    single = medians["single model (D), PyTorch module loop"] / medians["single model (D), fast"]
    ensemble = medians["5-member ensemble (DE), PyTorch module loop"] / medians["5-member ensemble (DE), fast"]
    lines += ["", f"Speed-up over the module loop: single {single:.1f}x, ensemble {ensemble:.1f}x. "
              f"Largest difference between the fast path (float32 numpy) and the module loop over the "
              f"{HORIZON} steps: {agreement['single']:.1e} (single), {agreement['ensemble']:.1e} (ensemble)."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads for the baseline (default 1)")
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--repeats", type=int, default=20, help="rollouts per case per round")
    parser.add_argument("--write", action="store_true", help="update BENCHMARKS.md")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    medians, agreement = measure(args.rounds, args.repeats)
    text = report(medians, agreement, args.threads)
    print(text)
    if args.write:
        write_benchmark_section("Learning library", "Open-loop rollout (tools/bench_rollout.py)", text)
        print("updated BENCHMARKS.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
