"""The reality gap's closed-loop headline read again from its committed runs: plan-level intervals and RMS ratios.

Run 2 of docs/reality_gap.md reported the tuned learned MPC's joint-angle MSE ratio to the nominal MPC with a
95 % interval over the 5 seeds only (each seed's ratio a geometric mean over the same 20 test plans), which
treats the plans as fixed. This re-reading, from the runs in `docs/results/reality_gap/results.json` (no new
run), gives per model type the same ratio with plans as the unit (per plan the geometric mean over seeds, a
Student-t interval over the 20 plans), a bootstrap over plans and seeds together, and the ratio of RMS errors
(the square root of the MSE ratio: the same comparison in radians).

    python tools/study.py reality-gap-plans [--results docs/results/reality_gap/results.json]
        [-o docs/results/reality_gap/plan_level.json]
"""
from __future__ import annotations

import argparse
import json
import math
import pathlib

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]


def log_ratios(runs: list[dict], model_type: str) -> tuple[np.ndarray, list]:
    """log(nominal MSE / model MSE) per (seed, plan), (S, P), on the tuned test runs; the plans' indices."""
    test = [run for run in runs if run["split"] == "test" and run.get("setting") == "tuned"]
    plans = sorted({run["trajectory"] for run in test})
    nominal = {run["trajectory"]: run["q_mse_rad2"] for run in test if run["model"] == "plant"}
    models = sorted({run["model"] for run in test if run["model"] == model_type
                     or run["model"].startswith(model_type + " seed ")})
    mse = {(run["model"], run["trajectory"]): run["q_mse_rad2"] for run in test}
    return np.array([[math.log(nominal[plan] / mse[(model, plan)]) for plan in plans] for model in models]), plans


def intervals(values: np.ndarray, seed: int = 0, draws: int = 4000) -> dict:
    """MSE and RMS ratios (nominal / model) with 95 % intervals: over plans (t), over seeds (t, as run 2
    reported) and a bootstrap over plans and seeds together. values: (S, P) log MSE ratios."""
    from scipy import stats

    def t_interval(samples: np.ndarray) -> list:
        mean = samples.mean()
        if len(samples) < 2:
            return [math.exp(mean), 0.0, math.inf]
        half = stats.t.ppf(0.975, len(samples) - 1) * samples.std(ddof=1) / math.sqrt(len(samples))
        return [math.exp(mean), math.exp(mean - half), math.exp(mean + half)]

    rng = np.random.default_rng(seed)
    seeds, plans = values.shape
    boot = [values[np.ix_(rng.integers(0, seeds, seeds), rng.integers(0, plans, plans))].mean() for _ in range(draws)]
    low, high = np.percentile(boot, [2.5, 97.5])
    over_plans = t_interval(values.mean(axis=0))
    return dict(seeds=seeds, plans=plans, mse_over_plans=over_plans, mse_over_seeds=t_interval(values.mean(axis=1)),
                mse_bootstrap_plans_and_seeds=[math.exp(values.mean()), math.exp(low), math.exp(high)],
                rms_over_plans=[value ** 0.5 for value in over_plans])


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--results", type=pathlib.Path, default=ROOT / "docs" / "results" / "reality_gap" / "results.json")
    parser.add_argument("-o", "--output", type=pathlib.Path,
                        default=ROOT / "docs" / "results" / "reality_gap" / "plan_level.json")


def run(args: argparse.Namespace) -> int:
    from stdm_drake.files import write_text_atomic
    runs = json.loads(args.results.read_text())["runs"]
    found = {}
    for model_type in ("D", "DD", "true-plant"):
        values, plans = log_ratios(runs, model_type)
        found[model_type] = intervals(values)
    nominal = [run["q_mse_rad2"] for run in runs if run["split"] == "test" and run.get("setting") == "tuned"
               and run["model"] == "plant"]
    result = dict(written_by="tools/study.py reality-gap-plans", provenance=args.provenance, source=str(args.results.relative_to(ROOT)
                                                                           if args.results.is_relative_to(ROOT)
                                                                           else args.results),
                  test_plans=plans, nominal_q_rms_rad=math.exp(np.mean(np.log(nominal)) / 2), models=found)
    write_text_atomic(args.output, json.dumps(result, indent=2) + "\n")
    for model_type, values in found.items():
        mse, rms = values["mse_over_plans"], values["rms_over_plans"]
        print(f"{model_type}: nominal / model q MSE {mse[0]:.3g}x [{mse[1]:.3g}, {mse[2]:.3g}] over {values['plans']} "
              f"plans (over seeds: [{values['mse_over_seeds'][1]:.3g}, {values['mse_over_seeds'][2]:.3g}]); RMS "
              f"{rms[0]:.3g}x [{rms[1]:.3g}, {rms[2]:.3g}]")
    print(f"-> {args.output}")
    return 0
