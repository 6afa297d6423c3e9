"""The sine-sum study: data, run grid, and `stdm-drake sine-sum --quick` end to end."""
import csv
import dataclasses
import json

import numpy as np
import pytest

from stdm_drake.cli import main
from stdm_drake.errors import InputError
from stdm_drake.experiments.sine_sum import (FULL, PAPER_TABLE1, QUICK, StudyConfig, run_specs, run_study, sample,
                                             sine_sum, sine_sum_derivative)


def test_function_data_and_derivative():
    data = sample(100)
    assert data.inputs.shape == data.targets.shape == (100, 1)
    assert data.inputs[0, 0] == pytest.approx(-30 * np.pi) and data.inputs[-1, 0] == pytest.approx(30 * np.pi)
    assert np.allclose(np.diff(data.inputs[:, 0]), 60 * np.pi / 99)
    assert np.all(data.input_rates == 1.0)
    x = np.linspace(-90, 90, 301)
    numeric = (sine_sum(x + 1e-6) - sine_sum(x - 1e-6)) / 2e-6
    np.testing.assert_allclose(sine_sum_derivative(x), numeric, atol=1e-8)
    assert sine_sum(np.array([np.pi]))[0] == pytest.approx(np.sin(np.pi) + np.sin(0.5 * np.pi) + np.sin(0.1 * np.pi))


def test_run_grid_matches_the_paper_design():
    specs = run_specs(FULL)
    grid = [s for s in specs if s.loss == "mse"]
    assert len(grid) == 3 * 9 * 2
    assert {s.layers for s in grid} == {1, 3, 5} and len({s.activation for s in grid}) == 9
    assert all(s.members == (FULL.headline_seeds if (s.layers, s.activation) == (5, "swish") else FULL.seeds)
               for s in grid)
    assert FULL.headline_seeds == 5 and FULL.seeds == FULL.table_seeds == 3
    table = [s for s in specs if s.loss != "mse"]   # the MSE row of Table 1 reuses the Fig. 6 runs
    assert len(table) == 6 and all(s.derivative and s.layers == 5 and s.members == 3 for s in table)
    assert specs[0].layers == 5   # deepest first: the slowest runs start first
    assert FULL.width == 100 and FULL.alpha == "auto" and 0.0 in FULL.alpha_grid and 1e-3 in FULL.alpha_grid
    assert not FULL.standardize_inputs and FULL.lr_schedule == "cosine"
    assert (FULL.train_points, FULL.val_points, FULL.test_points) == (100, 1000, 4000)
    with pytest.raises(InputError, match="unknown activations"):
        StudyConfig(activations=("mish",))
    with pytest.raises(InputError, match="must be in the grid"):
        StudyConfig(layers=(1, 3))
    with pytest.raises(InputError, match="alpha must be a positive number or 'auto'"):
        StudyConfig(alpha="sometimes")


@pytest.mark.slow
def test_alpha_is_chosen_on_validation_before_any_derivative_run(tmp_path):
    """The sweep's choice is the alpha every derivative run used; naive runs use 0; the chosen alpha
    has the lowest validation MSE of the grid; results do not depend on the number of workers."""
    config = dataclasses.replace(QUICK, layers=(5,), activations=("tanh", "relu", "swish"), epochs=60, alpha="auto",
                                 alpha_grid=(0.0, 1e-2, 1.0), seeds=2, headline_seeds=2, table_seeds=2,
                                 table_activations=("tanh", "relu", "swish"), table_losses=("mae", "mse", "huber"))
    one, two = run_study(config, workers=1, progress=False), run_study(config, workers=2, progress=False)
    sweep = one["alpha_sweep"]
    assert sweep["chosen_alpha"] == sweep["alphas"][int(np.argmin(sweep["val_mse"]))]
    for run in one["runs"]:
        assert run["alpha"] == (sweep["chosen_alpha"] if run["spec"]["derivative"] else 0.0)
    assert [run["member_test_mse"] for run in one["runs"]] == [run["member_test_mse"] for run in two["runs"]]
    assert one["alpha_sweep"]["val_mse"] == two["alpha_sweep"]["val_mse"]
    fixed = run_study(dataclasses.replace(config, alpha=0.5), workers=1, progress=False)
    assert fixed["alpha_sweep"] is None and {run["alpha"] for run in fixed["runs"]} == {0.0, 0.5}


@pytest.mark.slow
def test_quick_study_end_to_end(tmp_path, capsys):
    """The quick profile's grid, files and summary (its full 6000 steps run in `reproduce --quick`'s test; here 300)."""
    output = tmp_path / "sine"
    assert main(["sine-sum", "--quick", "--epochs", "300", "-o", str(output), "--workers", "1", "--quiet"]) == 0
    assert "table 1" in capsys.readouterr().out
    for name in ("results.json", "summary.md", "fig6_mse_vs_activation.csv", "fig6_mse_vs_activation.png",
                 "fig7_predictions.png", "fig8_learning_curves.png", "fig8_learning_curves.csv", "table1.csv",
                 "table1.json", "table1.png"):
        assert (output / name).is_file(), name
    for png in output.glob("*.png"):
        content = png.read_bytes()
        assert content.startswith(b"\x89PNG") and len(content) > 10_000, png.name
    results = json.loads((output / "results.json").read_text())
    assert len(results["runs"]) == len(run_specs(QUICK))
    from stdm_drake.provenance import source_state   # (the code it ran: this checkout, named)
    assert results["provenance"]["command"] == "stdm-drake sine-sum --quick --epochs 300 -o DIR --workers 1 --quiet"
    assert results["provenance"]["commit"] == source_state()["commit"] and str(tmp_path) not in json.dumps(results)
    for run in results["runs"]:
        assert len(run["member_test_mse"]) == run["spec"]["members"]
        assert np.isfinite(run["member_test_mse"]).all() and run["seconds"] > 0
        assert len(run["best_prediction"]) == QUICK.test_points
        assert run["history"]["epoch"][-1] == 300 and run["alpha"] in (0.0, QUICK.alpha)
    with open(output / "fig6_mse_vs_activation.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(QUICK.layers) * len(QUICK.activations)
    assert all(np.isfinite(float(row[key])) for row in rows for key in row if key.endswith("mse"))
    with open(output / "table1.csv") as f:
        table = list(csv.DictReader(f))
    assert len(table) == len(QUICK.table_losses) * len(QUICK.table_activations) == 1
    for row in table:
        assert float(row["paper"]) == PAPER_TABLE1[(row["loss"], row["activation"])]
        assert np.isfinite(float(row["mean_test_mse"]))
    summary = (output / "summary.md").read_text()
    assert "quick profile, with overrides" in summary and "paper 0.0006" in summary and "s wall" in summary
    assert "95 % interval" in summary and not (output / "alpha_sweep.csv").exists()   # the full profile's alpha


def test_a_five_step_study_writes_every_report_file(tmp_path, capsys):
    """The command end to end in seconds (fast tier): a fixed alpha (no sweep, so no alpha_sweep files), 5
    full-batch steps; every figure, table and the summary are written, the headline printed."""
    output = tmp_path / "sine"
    assert main(["sine-sum", "--quick", "--epochs", "5", "--seeds", "2", "--alpha", "1e-3", "--workers", "1",
                 "--quiet", "-o", str(output)]) == 0
    printed = capsys.readouterr().out
    assert "alpha 0.001" in printed and printed.count("table 1") == len(QUICK.table_losses) * len(QUICK.table_activations)
    written = {path.name for path in output.iterdir()}
    assert {"results.json", "summary.md", "fig6_mse_vs_activation.csv", "fig6_mse_vs_activation.png",
            "fig7_predictions.png", "fig8_learning_curves.png", "fig8_learning_curves.csv", "table1.csv",
            "table1.json", "table1.png"} <= written and "alpha_sweep.csv" not in written
    curves = (output / "fig8_learning_curves.csv").read_text().splitlines()
    assert curves[0] == "mode,epoch,train_loss,val_loss,val_mse_standardized"
    assert {line.split(",")[0] for line in curves[1:]} == {"naive", "derivative"}
    assert all(line.split(",")[1] == "5" for line in curves[1:])   # validated at the last of the 5 steps
    # 5 steps learn nothing: the comparison is "uninformative", with the learning-free baseline, not "helps"/"hurts"
    assert "uninformative: neither mode learned, both within 2x of the test MSE of predicting the mean, 1.5" in printed
    assert "uninformative: neither mode learned" in (output / "summary.md").read_text()


def test_a_comparison_of_networks_that_learned_nothing_is_uninformative():
    """Newcomer pass 2: 20 full-batch steps printed "helps" for a ratio of 1.001 [1, 1.002] at a test MSE of 1.3,
    where predicting the mean scores 1.5. A mode that learned (below half the mean's MSE) makes the row a verdict."""
    from stdm_drake.experiments.sine_sum import fig6_rows, mean_baseline_mse
    config = dataclasses.asdict(dataclasses.replace(QUICK, layers=(5,), activations=("swish",)))
    baseline = mean_baseline_mse(config)
    assert baseline == pytest.approx(1.5, rel=1e-3)    # three sines of variance 1/2 each, nearly uncorrelated

    def study(naive, derivative):
        return dict(config=config, runs=[
            dict(spec=dict(layers=5, activation="swish", derivative=mode, loss="mse", members=len(mse)),
                 member_test_mse=mse, mean_test_mse=float(np.mean(mse)), best_test_mse=min(mse))
            for mode, mse in ((False, naive), (True, derivative))])
    members = QUICK.headline_seeds
    rng = np.random.default_rng(0)
    unlearned = [1.3 * (1 + 0.001 * k) for k in range(members)]
    assert fig6_rows(study(unlearned, [m / 1.001 for m in unlearned]))[0]["verdict"] == "uninformative"
    learned = list(1e-3 * np.exp(rng.normal(size=members)))
    assert fig6_rows(study(unlearned, learned))[0]["verdict"] == "helps"
    assert fig6_rows(study(learned, unlearned))[0]["verdict"] == "hurts"


@pytest.mark.slow
def test_flushing_subnormals_changes_speed_not_results():
    """Raw x in ±94 drives gelu's exp(-h²/2) into subnormals; flushing them to zero (the default) must
    leave the trained networks' test errors as they are, and switch flushing off again afterwards."""
    import torch
    from stdm_drake.experiments.sine_sum import RunSpec, train_run
    spec = RunSpec(layers=3, activation="gelu", derivative=True, loss="mse", members=2)
    config = dataclasses.replace(QUICK, epochs=60, validation_interval=20, layers=(3, 5),
                                 activations=("gelu", "swish"))
    flushed = train_run(spec, config, 1.0)
    plain = train_run(spec, dataclasses.replace(config, flush_subnormals=False), 1.0)
    np.testing.assert_allclose(flushed["member_test_mse"], plain["member_test_mse"], rtol=1e-5)
    assert torch.tensor(1e-40, dtype=torch.float32).item() != 0.0  # flushing is off outside the study
