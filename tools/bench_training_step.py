"""Benchmark: one training step with the derivative loss vs the plain MSE step.

Model: 3 hidden layers x 100, swish, 18 inputs (x 12 + a 6), 12 outputs, batch 256, Adam.
Variants, all timed in the same run and interleaved (median over rounds):
  plain        stdm_drake.learning.trainer.training_step with alpha = 0 (the MSE step)
  derivative   the same step with alpha = 1e-3: hand-written forward-mode JVP (models.py)
  func.jvp     baseline: the tangent from torch.func.jvp of the network
  vmap(jacrev) baseline: full per-sample Jacobians (torch.func.vmap(torch.func.jacrev)), then J ż
The goal is derivative <= 1.5 x plain.

    python tools/bench_training_step.py [--threads 1] [--rounds 15] [--write]

--write replaces this benchmark's subsection of BENCHMARKS.md (under "## Learning library").
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

from benchmark_report import BENCHMARKS_FILE, machine_description, start_benchmark, write_benchmark_section  # noqa: E402
from stdm_drake.learning.regression import RegressionData  # noqa: E402
from stdm_drake.learning.settings import TrainingConfig  # noqa: E402
from stdm_drake.learning.trainer import build_model, training_step  # noqa: E402
from stdm_drake.learning.models import dynamics_config  # noqa: E402

SECTION = "Learning library"
BATCH = 256


def synthetic_data(count: int = 4096, seed: int = 0) -> RegressionData:
    rng = np.random.default_rng(seed)
    inputs = rng.standard_normal((count, 18))
    return RegressionData(inputs=inputs, targets=inputs[:, :12] + 0.01 * rng.standard_normal((count, 12)),
                          input_rates=rng.standard_normal((count, 18)), target_rates=rng.standard_normal((count, 12)))


def make_steps(seed: int = 0):
    """name -> zero-argument callable doing one Adam step of that variant (own model each)."""
    data = synthetic_data(seed=seed)
    config = dynamics_config(state_dim=12, action_dim=6, delta=True)
    rows = torch.arange(BATCH)[None]
    steps = {}

    def setup(alpha):
        model = build_model(config, seed)
        model.fit_normalizers(data)
        tensors = model.standardize(data)
        optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
        return model, tensors, optimizer, TrainingConfig(alpha=alpha)

    for name, alpha in (("plain (MSE only)", 0.0), ("derivative (hand-written JVP)", 1e-3)):
        model, tensors, optimizer, training = setup(alpha)
        steps[name] = (lambda m=model, o=optimizer, t=training, d=tensors: training_step(m, o, t, d, rows))

    def baseline(tangent_of):
        model, tensors, optimizer, training = setup(1e-3)
        batch = [value[rows] for value in (tensors.inputs, tensors.targets, tensors.input_rates, tensors.target_rates)]

        def step():
            outputs, tangents = tangent_of(model, batch[0], batch[2])
            total = model.losses_from_outputs(training, outputs, tangents, batch[1], batch[3]).objective
            optimizer.zero_grad(set_to_none=True)
            total.backward()
            optimizer.step()
        return step

    def func_jvp(model, inputs, rates):
        outputs, tangents = torch.func.jvp(model.normalized_outputs, (inputs,), (rates,))
        return outputs, tangents[..., :model.config.output_dim]

    def jacobian(model, inputs, rates):
        def single(z):   # one sample (in,) -> (E, out), member by member with 2-D matmuls: under vmap
            members = []  # the backward of batched (E, 1, ·) matmuls is an order of magnitude slower
            for member in range(model.config.ensemble_size):
                h = z
                for weight, bias in zip(model.weights[:-1], model.biases[:-1]):
                    h = model.activation.function(h @ weight[member] + bias[member, 0])
                members.append(h @ model.weights[-1][member] + model.biases[-1][member, 0])
            out = torch.stack(members)
            return out, out
        jac, outputs = torch.func.vmap(torch.func.jacrev(single, has_aux=True))(inputs[0])   # (B, E, out, in)
        tangents = torch.einsum("beoi,bi->ebo", jac, rates[0])
        return outputs.transpose(0, 1), tangents[..., :model.config.output_dim]

    steps["torch.func.jvp (baseline)"] = baseline(func_jvp)
    steps["vmap(jacrev) full Jacobian (baseline)"] = baseline(jacobian)
    return steps


def measure(rounds: int, steps_per_round: int, seed: int = 0) -> dict:
    """Median ms per step of every variant, rounds interleaved so drift hits all alike."""
    steps = make_steps(seed)
    for step in steps.values():
        for _ in range(10):
            step()
    times = {name: [] for name in steps}
    for _ in range(rounds):
        for name, step in steps.items():
            started = time.perf_counter()
            for _ in range(steps_per_round):
                step()
            times[name].append((time.perf_counter() - started) / steps_per_round * 1e3)
    return {name: statistics.median(values) for name, values in times.items()}


def report(medians: dict, threads: int) -> str:
    plain = next(iter(medians.values()))
    lines = [f"Machine: {machine_description(threads)}.", "",
             f"Training step, batch {BATCH}, 3x100 swish, 18 in / 12 out, Adam; median ms per step, "
             "variants interleaved in one run. Goal: derivative <= 1.5 x plain.", "",
             "| variant | ms / step | x plain |", "|---|---|---|"]
    for name, value in medians.items():
        lines.append(f"| {name} | {value:.3f} | {value / plain:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1, as `stdm-drake train`)")
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--steps", type=int, default=20, help="steps per variant per round")
    parser.add_argument("--write", action="store_true", help="update BENCHMARKS.md")
    args, origin = start_benchmark(parser, argv)
    torch.set_num_threads(args.threads)
    text = report(measure(args.rounds, args.steps), args.threads)
    print(text)
    if args.write:
        threads = f"{args.threads} thread" + ("s" if args.threads > 1 else "")
        title = f"Training step with the derivative loss (tools/bench_training_step.py, {threads})"
        write_benchmark_section(SECTION, title, text, origin, name=f"bench_training_step_{args.threads}_thread")
        print(f"updated {BENCHMARKS_FILE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
