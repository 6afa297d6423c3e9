"""The decisive experiment's statistics and verdict rules, its limit-free robot, and its pipeline."""
import math
from types import SimpleNamespace

import numpy as np
import pytest

from presets import UR10
from tools_import import decisive, study


def rows(values, model):
    return [SimpleNamespace(data_seed=seed, init=init, model=model, one_step_q=value)
            for seed, per_seed in enumerate(values) for init, value in enumerate(per_seed)]


@pytest.mark.slow
def test_two_level_interval_is_over_data_seeds():
    """Ratios 4x in every pair: 4x with a zero-width interval; data seeds that disagree widen it even when
    the initializations within each agree perfectly (inits are not independent evidence)."""
    same = decisive.two_level_ratio(rows([[4.0] * 5] * 3, "D"), rows([[1.0] * 5] * 3, "DD"), "one_step_q")
    assert same["ratio"] == pytest.approx(4.0) and same["low"] == pytest.approx(4.0) and same["pairs"] == 15
    spread = decisive.two_level_ratio(rows([[8.0] * 5, [4.0] * 5, [2.0] * 5], "D"), rows([[1.0] * 5] * 3, "DD"),
                                        "one_step_q")
    assert spread["ratio"] == pytest.approx(4.0) and spread["low"] < 1.0 < 4.0 < spread["high"]
    single = decisive.two_level_ratio(rows([[3.0] * 5], "D"), rows([[1.0] * 5], "DD"), "one_step_q")
    assert single["low"] == 0.0 and math.isinf(single["high"])


def test_cell_verdicts_follow_the_design():
    ratio = lambda r, low, high: dict(ratio=r, low=low, high=high)   # noqa: E731
    reproduces = {"one-step q": ratio(4, 2.5, 6), "one-step v": ratio(3.5, 2.1, 5), "q at step 20": ratio(1, 0.5, 2)}
    assert decisive.cell_verdict(True, reproduces) == "the paper reproduces"
    assert decisive.cell_verdict(False, reproduces) == "uninformative (naive has not learned)"
    no_help = {key: ratio(1.0, 0.9, 1.1) for key in reproduces}
    assert decisive.cell_verdict(True, no_help) == "no help"
    wide = dict(no_help, **{"one-step v": ratio(1.0, 0.7, 1.4)})
    assert decisive.cell_verdict(True, wide) == "inconclusive"


def test_the_limit_free_ur10_has_no_position_limits_and_the_ur10s_inertia():
    from stdm_drake.robots.plant import Dynamics, robot_joint_limits
    from stdm_drake.robots.robot import load_robot
    free = load_robot(decisive.ROOT / "models" / "ur10_limit_free.yaml")
    limits = robot_joint_limits(free)
    assert np.all(np.isinf(limits.position_lower)) and np.all(np.isinf(limits.position_upper))
    np.testing.assert_array_equal(limits.effort, robot_joint_limits(UR10).effort)
    q = np.array(decisive.HOME)
    np.testing.assert_allclose(Dynamics(free).mass_matrix(q), Dynamics(UR10).mass_matrix(q), rtol=1e-12)


@pytest.mark.slow
def test_quick_profile_runs_end_to_end(tmp_path):
    assert study.main(["decisive", "--allow-dirty", "--quick", "-o", str(tmp_path / "out"), "--data", str(tmp_path / "data")]) == 0
    import json
    results = json.loads((tmp_path / "out" / "results.json").read_text())
    assert [cell["cell"] for cell in results["summary"]] == ["literal-10ms", "learned-structure"]
    assert len(results["runs"]) == 2 * 2 * 2 * 4 and results["reused_rows"] == 0
    assert all(cell["verdict"] and "D-half_over_DD" in cell for cell in results["summary"])
    half = [run for run in results["runs"] if run["model"] == "D-half"]
    assert {run["train_sample_period"] for run in half} == {0.005}
    # the learned-structure cell trains on the literal cell's data: one full and one half-period file per seed
    assert sorted(path.name for path in (tmp_path / "data").iterdir()) == sorted(
        f"literal-10ms{half}_seed{seed}_n50.h5" for half in ("", "_half") for seed in (0, 1))
    # --resume keeps every row of the same design and trains nothing
    assert study.main(["decisive", "--allow-dirty", "--quick", "--resume", "-o", str(tmp_path / "out"), "--data", str(tmp_path / "data")]) == 0
    again = json.loads((tmp_path / "out" / "results.json").read_text())
    assert again["reused_rows"] == len(results["runs"]) and again["runs"] == results["runs"]
    assert study.main(["decisive", "--allow-dirty", "--resume", "-o", str(tmp_path / "out"), "--data", str(tmp_path / "data")]) == 2


@pytest.mark.slow
def test_closed_loop_study_quick_profile(tmp_path):
    """The seed-level closed-loop study end to end at pipeline size: every model trained and gated, the
    plant and every model driven over the same plans, a seed-level ratio with its interval. The results
    are written either way; the exit status is 2 exactly when a closed loop left the limits (at this
    pipeline size, 20 epochs, one of the naive models does)."""
    import json

    code = study.main(["closed-loop", "--allow-dirty", "--quick", "-o", str(tmp_path / "out"), "--data", str(tmp_path / "data")])
    results = json.loads((tmp_path / "out" / "results.json").read_text())
    assert code == (2 if any(run["limit_violations"] for run in results["runs"]) else 0)
    summary = results["summary"]
    assert summary["seeds"] == 2 and summary["D_over_DD"]["pairs"] == 2
    assert {run["model"] for run in results["runs"]} == {"plant", "D seed 0", "D seed 1", "DD seed 0", "DD seed 1"}
    assert len(results["runs"]) == 5 * summary["plans"]
