"""The settling experiment (docs/settling.md): its statistics (two-level intervals, Holm), its verdict rule with
every outcome, its grid-extension rule, its pipeline end to end, and the reality gap's plan-level re-reading."""
import dataclasses
import json
import math

import numpy as np
import pytest

from tools_import import reality_gap_plans, settling, study


def member(data_seed, init, alpha, value, scale="raw", val_mse=1.0):
    return settling.Member(cell="c", data_seed=data_seed, init=init, scale=scale, alpha=alpha, val_mse=val_mse,
                           best_epoch=1, epochs=1, one_step_q=value, one_step_v=value, open_loop_q=value,
                           ratio_to_euler_q=10.0, ratio_to_unchanged_v=10.0, verdict="learned")


def test_two_level_interval_is_over_data_seeds_with_its_p_value():
    """A 2x gain in every pair: 2x, zero-width; data seeds that disagree widen the interval whatever the inits do."""
    base = {(s, i): member(s, i, 0.0, 2.0) for s in range(4) for i in range(3)}
    method = {(s, i): member(s, i, 1e-3, 1.0) for s in range(4) for i in range(3)}
    same = settling.two_level(base, method, "one_step_q")
    assert same["ratio"] == pytest.approx(2.0) and same["low"] == pytest.approx(2.0) and same["data_seeds"] == 4
    spread = {(s, i): member(s, i, 0.0, [8.0, 0.5, 4.0, 1.0][s]) for s in range(4) for i in range(3)}
    wide = settling.two_level(spread, method, "one_step_q")
    assert wide["low"] < 1.0 < wide["high"] and 0.05 < wide["p"] < 1


def test_holm_adjusts_step_down_and_stays_monotone():
    assert settling.holm([0.01, 0.04, 0.03, 0.5]) == pytest.approx([0.04, 0.09, 0.09, 0.5])
    assert settling.holm([0.2]) == [0.2]


@pytest.mark.parametrize("q, v, expected", [
    ((4.0, 2.5, 6.0, 0.001), (3.5, 2.1, 5.0, 0.001), "the paper reproduces"),
    ((1.5, 1.2, 1.9, 0.01), (1.1, 0.9, 1.3, 0.5), "helps"),
    ((0.5, 0.4, 0.6, 0.001), (0.9, 0.7, 1.1, 0.4), "hurts"),
    ((1.5, 1.2, 1.9, 0.01), (0.6, 0.5, 0.7, 0.01), "mixed"),
    ((1.0, 0.9, 1.1, 0.9), (1.02, 0.85, 1.2, 0.8), "no help"),
    ((1.0, 0.6, 1.7, 0.9), (1.0, 0.9, 1.1, 0.9), "inconclusive"),
])
def test_every_outcome_of_the_verdict_rule(q, v, expected):
    ratio = lambda r, low, high, p: dict(ratio=r, low=low, high=high, p_holm=p)   # noqa: E731
    assert settling.verdict(True, ratio(*q), ratio(*v)) == expected
    assert settling.verdict(False, ratio(*q), ratio(*v)) == "uninformative (naive has not learned)"


def test_dd_is_the_validation_best_positive_alpha_and_the_extension_rule():
    profile = dataclasses.replace(settling.QUICK, data_seeds=(0, 1, 2), inits=(0,))
    cell = settling.CELLS[0]
    largest = max(settling.RAW_GRID)
    rows = [dataclasses.replace(member(s, 0, 0.0, 1.0), cell=cell.name) for s in range(3)]
    for s in range(3):   # the largest alpha wins validation on 2 of 3 grids (more than a third: extend)
        rows.append(dataclasses.replace(member(s, 0, 1e-4, 1.0, val_mse=0.5), cell=cell.name))
        rows.append(dataclasses.replace(member(s, 0, largest, 1.0, val_mse=0.4 if s < 2 else 0.6), cell=cell.name))
    picked = settling.chosen(rows, cell.name, "raw", profile.data_seeds, profile.inits, False)
    assert [picked[(s, 0)].alpha for s in range(3)] == [largest, largest, 1e-4]
    assert settling.needs_extension(rows, cell, "raw", profile)
    assert not settling.needs_extension(rows[:3] + rows[3::2], cell, "raw", profile)


@pytest.mark.slow
def test_quick_profile_runs_end_to_end(tmp_path, monkeypatch):
    """Datasets, the chain-rule check, both grids per pair with train's rule beside, the grid extension (forced
    here for one cell), the summary and its files; a rerun reads every pair back from its cache."""
    output = tmp_path / "out"
    monkeypatch.setattr(settling, "needs_extension", lambda rows, cell, scale, profile: cell.name == "literal-current")
    assert study.main(["settling", "--allow-dirty", "--quick", "-o", str(output), "--data", str(tmp_path / "data")]) == 0
    assert any(run["extension"] for run in json.loads((output / "results.json").read_text())["runs"])
    first = (output / "results.json").read_text()
    assert study.main(["settling", "--allow-dirty", "--quick", "-o", str(output), "--data", str(tmp_path / "data")]) == 0
    again = json.loads((output / "results.json").read_text())
    assert again["runs"] == json.loads(first)["runs"] and again["summary"] == json.loads(first)["summary"]
    results = json.loads((output / "results.json").read_text())
    assert results["design"] == "docs/settling.md" and results["quick"] is True
    check = results["chain_rule"]
    assert set(check) == {"forward_difference", "zero_order_hold", "transitions"}
    assert all(0 <= value < 0.5 for scheme in ("forward_difference", "zero_order_hold")
               for value in check[scheme].values())
    pairs = len(settling.QUICK.data_seeds) * len(settling.QUICK.inits)
    assert len(results["summary"]) == 2 and len(results["train_rule"]["raw"]) == 2 * pairs
    for cell in results["summary"]:
        for scale in settling.SCALES:
            values = cell["scales"][scale]
            assert values["verdict"] in {"the paper reproduces", "helps", "hurts", "mixed", "no help", "inconclusive",
                                         "uninformative (naive has not learned)"}
            assert sum(values["chosen_alphas"].values()) == pairs
            assert all(0 <= values["DD"][label]["p_holm"] <= 1 for _, label in settling.ENDPOINTS)
    runs = results["runs"]
    naive = [run for run in runs if run["alpha"] == 0]
    assert len(naive) == 2 * pairs and all(run["scale"] == "raw" for run in naive)
    assert {run["alpha"] for run in runs if run["scale"] == "relative"} >= set(settling.RELATIVE_GRID)
    assert (output / "cells.csv").read_text().count("\n") == 1 + 2 * len(settling.SCALES)
    assert {row["data"] for row in results["plant"]} == {"literal", "identification"}


def test_reality_gap_plan_level_intervals_are_wider_than_over_seeds():
    """Plans as the unit: per plan the geometric mean over seeds, t over plans; RMS is the MSE ratio's root."""
    rng = np.random.default_rng(0)
    values = rng.normal(3.0, 1.0, size=(1, 12)) + rng.normal(0.0, 0.05, size=(5, 12))   # plans vary, seeds agree
    found = reality_gap_plans.intervals(values)
    over_plans, over_seeds = found["mse_over_plans"], found["mse_over_seeds"]
    assert over_plans[0] == pytest.approx(math.exp(values.mean())) == pytest.approx(over_seeds[0])
    assert math.log(over_plans[2] / over_plans[1]) > 5 * math.log(over_seeds[2] / over_seeds[1])
    assert found["rms_over_plans"] == pytest.approx([value ** 0.5 for value in over_plans])
