"""The sample-efficiency study (docs/sample_efficiency.md): its nested per-pose split, DD as the validation-best
positive alpha, the grid-edge mark, both claim rules with every outcome, and its pipeline end to end."""
import dataclasses
import json

import pytest

from tools_import import sample_efficiency as se, study


def test_the_split_is_per_pose_nested_and_shares_validation_and_test():
    groups = [pose for pose in range(4) for _ in range(25)]
    splits = {size: se.split_of(groups, se.FULL, size) for size in se.FULL.sizes}
    for size, split in splits.items():
        assert len(split["train"]) == size and len(split["val"]) == 20 and len(split["test"]) == 40
        assert all(sum(groups[i] == pose for i in split["train"]) == size // 4 for pose in range(4))
        assert not set(split["train"]) & (set(split["val"]) | set(split["test"]))
        assert split["val"] == splits[4]["val"] and split["test"] == splits[4]["test"]
    assert set(splits[4]["train"]) < set(splits[12]["train"]) < set(splits[20]["train"]) < set(splits[40]["train"])
    with pytest.raises(ValueError):
        se.split_of(groups, se.FULL, 6)      # (not a multiple of the 4 poses)


def member(cell, seed, init, alpha, value, val_mse=1.0):
    return dict(cell=cell, data_seed=seed, init=init, alpha=alpha, val_mse=val_mse, one_step_q=value,
                one_step_v=value, open_loop_q=value, ratio_to_euler_q=10.0, ratio_to_unchanged_v=10.0,
                verdict="learned")


def test_dd_is_the_validation_best_positive_alpha_and_an_edge_choice_is_marked():
    profile = dataclasses.replace(se.FULL, kinds=("tracked",), sizes=(4,), activations=("swish",))
    cell = se.cells(profile)[0]
    rows, rules = [], {}
    for seed in profile.data_seeds:
        for init in profile.inits:
            rows += [member(cell.name, seed, init, 0.0, 2.0), member(cell.name, seed, init, 1e-4, 4.0, val_mse=0.5),
                     member(cell.name, seed, init, 1e-1, 1.0, val_mse=0.4 if seed < 202 else 0.6)]
            rules[(cell.name, seed, init)] = 0.0
    summary = se.summarize([cell], rows, rules, profile)[0]
    assert summary["chosen_alphas"] == {"0.0001": 4, "0.1": 4}
    assert summary["alpha_at_grid_edge"]                       # 1e-1 in 4 of 8 pairs: more than a third
    assert summary["train_rule"]["kept_naive"] == 8
    assert summary["per_alpha"]["0.1"]["one-step q"]["ratio"] == pytest.approx(2.0)


def cell_summary(kind, size, activation, verdict, q_ratio=1.0, q_p=1.0, gated=True):
    return dict(kind=kind, size=size, activation=activation, verdict=verdict, gated=gated,
                DD={"one-step q": dict(ratio=q_ratio, p_holm=q_p)})


@pytest.mark.parametrize("verdicts, claim", [
    (("helps", "the paper reproduces", "helps"), "supported"),
    (("helps", "no help", "inconclusive"), "partly supported"),
    (("hurts", "no help", "inconclusive"), "contradicted"),
    (("helps", "hurts", "no help"), "mixed"),
    (("helps", "mixed", "no help"), "mixed"),
    (("no help", "inconclusive", "uninformative (naive has not learned)"), "not shown"),
])
def test_every_outcome_of_the_sample_efficiency_rule(verdicts, claim):
    profile = dataclasses.replace(se.FULL, kinds=("tracked",), activations=("swish",))
    summary = [cell_summary("tracked", size, "swish", verdict) for size, verdict in zip(se.PAPER_SIZES, verdicts)]
    summary.append(cell_summary("tracked", 40, "swish", "hurts"))     # (N = 40 is beside the claim, not in it)
    assert se.claims(summary, profile)["sample_efficiency"]["tracked"]["claim"] == claim


@pytest.mark.parametrize("tanh_q, swish_q, gated, finding", [
    ((0.5, 0.01), (1.0, 1.0), True, "reproduces"),
    ((0.5, 0.01), (2.0, 0.01), True, "reproduces"),
    ((2.0, 0.01), (1.0, 1.0), True, "does not reproduce"),
    ((1.0, 1.0), (0.5, 0.01), True, "does not reproduce"),
    ((1.0, 1.0), (1.0, 1.0), True, "not shown"),
    ((0.5, 0.01), (1.0, 1.0), False, "uninformative"),
])
def test_every_outcome_of_the_activation_rule(tanh_q, swish_q, gated, finding):
    profile = dataclasses.replace(se.FULL, kinds=("tracked",), sizes=(20,))
    summary = [cell_summary("tracked", 20, "tanh", "x", *tanh_q, gated=gated),
               cell_summary("tracked", 20, "swish", "x", *swish_q)]
    assert se.claims(summary, profile)["activation"]["tracked N20"]["finding"] == finding


@pytest.mark.slow
def test_quick_profile_runs_end_to_end_and_a_rerun_reads_its_pairs_back(tmp_path):
    output, data = tmp_path / "out", tmp_path / "data"
    assert study.main(["sample-efficiency", "--allow-dirty", "--quick", "-o", str(output), "--data", str(data)]) == 0
    results = json.loads((output / "results.json").read_text())
    assert results["design"] == "docs/sample_efficiency.md" and results["quick"] is True
    pairs = len(se.QUICK.data_seeds) * len(se.QUICK.inits)
    assert len(results["summary"]) == len(se.QUICK.sizes) and len(results["train_rule"]) == 2 * pairs
    for cell in results["summary"]:
        assert sum(cell["chosen_alphas"].values()) == pairs
        assert all(0 <= cell["DD"][label]["p_holm"] <= 1 for _, label in se.ENDPOINTS)
    assert {row["kind"] for row in results["plant"]} == {"tracked"}
    assert all(row["plant"]["one_step_q"] < row["Euler step"]["one_step_q"] for row in results["plant"])
    runs = (output / "runs.csv").read_text()
    assert runs.count("\n") == 1 + 2 * pairs * len(se.GRID)
    assert study.main(["sample-efficiency", "--allow-dirty", "--quick", "-o", str(output), "--data", str(data)]) == 0
    assert json.loads((output / "results.json").read_text())["summary"] == results["summary"]
