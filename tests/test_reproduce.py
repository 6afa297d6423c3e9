"""`stdm-drake reproduce`: the quick profile end to end, the paper's split sizes, report verdicts."""
import dataclasses
import json
import math
import pathlib
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from presets import UR10
from stdm_drake.cli import main
from stdm_drake.data.dataset import load_dataset
from stdm_drake.learning.settings import DEFAULT_ALPHA, DEFAULT_ALPHA_GRID
from stdm_drake.experiments.jobs import FULL, QUICK, TrainJob, cached_rows, plan_jobs, run_job
from stdm_drake.experiments.results import TrainingResult
from stdm_drake.learning.models import MODEL_TYPES
from stdm_drake.experiments.reproduce_report import improvement_percent, verdict
from stdm_drake.stats import paired_ratio


ROOT = pathlib.Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_a_regular_install_imports_itself_and_its_files_from_the_package(regular_install, quick_report):
    env, work, target = regular_install
    where = subprocess.run([sys.executable, "-S", "-c", "import stdm_drake, stdm_drake.paths as p; "
                            "print(stdm_drake.__file__); print(p.MODELS_DIR)"],
                           cwd=work, env=env, capture_output=True, text=True, check=True, timeout=120).stdout.split()
    assert all(pathlib.Path(line).is_relative_to(target) for line in where), where
    assert (quick_report / "report.html").is_file()


@pytest.mark.slow
def test_quick_profile_writes_a_complete_report(quick_report):
    assert (quick_report / "data" / f"identification_n{QUICK.identification_count}_seed0.h5").exists()
    for name in ("report.md", "report.html", "results.json", "sim_activations.csv", "real_sizes.csv",
                 "figures/fig11_activations_sim.png", "figures/fig12_sizes_sim.png", "figures/fig13_learning_curves.png",
                 "figures/fig16_activations_real.png", "figures/fig17_sizes_real.png", "figures/fig18_multistep.png",
                 "figures/fig19_multistep_20.png", "mpc/mpc.png", "sine_sum/summary.md"):
        assert (quick_report / name).stat().st_size > 200, name
    results = json.loads((quick_report / "results.json").read_text())
    tables = results["tables"]
    origin = results["provenance"]   # (a regular install: no checkout to name, so the version and "not clean")
    assert origin["command"] == "stdm-drake reproduce --quick -o DIR --quiet" and origin["stdm_drake"]
    assert origin["commit"] is None and origin["clean"] is False and "cores" in origin["machine"]
    assert [row["activation"] for row in tables["sim_activations"]] == list(QUICK.activations)
    assert [row["activation"] for row in tables["real_activations"]] == list(QUICK.activations)
    assert [row["train_trajectories"] for row in tables["sim_sizes"]] == list(QUICK.sim_train_sizes)
    assert [row["train_trajectories"] for row in tables["real_sizes"]] == list(QUICK.real_train_sizes)
    assert [row["model_type"] for row in tables["multistep"]] == list(MODEL_TYPES)
    assert [row["model"] for row in tables["mpc"]] == ["plant", "D", "DD", "PE", "PED"]
    for row in tables["mpc"][1:]:
        assert row["seeds"] == QUICK.control_seeds and row["plans"] == QUICK.mpc_plans
        assert row["plant_over_model"]["pairs"] == QUICK.mpc_plans and len(row["seed_ratios"]) == QUICK.control_seeds
    assert "naive_over_derivative" in tables["mpc"][2] and "naive_over_derivative" in tables["mpc"][4]
    assert len(tables["mpc_runs"]) == 1 + 4 * QUICK.control_seeds
    for name in ("sim_activations", "sim_sizes", "real_activations", "real_sizes", "multistep"):
        for row in tables[name]:
            numbers = [value for value in row.values() if isinstance(value, float) and not math.isinf(value)]
            assert numbers and all(math.isfinite(value) for value in numbers), (name, row)
    for row in tables["multistep"]:
        assert len(row["multistep_q"]) == QUICK.horizon and row["rollout_ms"] > 0
    text = (quick_report / "report.md").read_text()
    assert "paper" in text and "Fig. 11" in text and "Fig. 19" in text and "Sine-sum" in text
    # the report opens with what the run shows: the default model (trained and gated like any learned model) and
    # the sine-sum, each with its paired interval, before the paper's sections
    assert text.index("## Summary: what this run shows") < text.index("## Data") < text.index("Fig. 11")
    summary = text[text.index("## Summary"):text.index("## Data")]
    assert "The toolbox's default model" in summary and "Sine-sum" in summary and "need the full profile" in summary
    (default,) = tables["default_model"]
    assert default["seeds"] == QUICK.default_model_seeds and default["learned"], default["D_vs_baseline"]
    assert all(alpha > 0 for alpha in default["alphas"]) and "[" in summary.split("Derivative learning on it")[1]
    # every verdict points to the settled answer: the default model's to the settling experiment, the sine-sum's to
    # the full profile's committed headline
    assert "docs/settling.md" in summary.split("Derivative learning on it")[1].split("Sine-sum")[0]
    assert "The settled answer: derivative learning helps on the sine-sum, 39.2x [26.4, 58.2]" in summary


def test_the_summarys_settled_sine_sum_answer_is_the_committed_full_profile_headline():
    """The numbers the summary quotes as the settled sine-sum answer are those of the committed full-profile file,
    to the digits printed."""
    import csv
    from stdm_drake.experiments.reproduce_summary import SETTLED_SINE_SUM, sine_sum_text
    with open(ROOT / SETTLED_SINE_SUM["source"], newline="") as handle:
        (row,) = [row for row in csv.DictReader(handle) if (row["layers"], row["activation"]) == ("5", "swish")]
    assert row["verdict"] == SETTLED_SINE_SUM["verdict"] and int(row["networks"]) == SETTLED_SINE_SUM["networks"]
    for key, column in (("ratio", "ratio"), ("low", "ratio_low"), ("high", "ratio_high")):
        assert f"{float(row[column]):.3g}" == f"{SETTLED_SINE_SUM[key]:g}", key
    top = dict(networks=3, ratio=7.99, ratio_low=0.89, ratio_high=71.7, verdict="no clear difference",
               paper_derivative=6e-4)
    text = sine_sum_text(top, quick=True)
    from stdm_drake.experiments.reproduce_summary import QUICK_SINE_SUM
    from stdm_drake.experiments.sine_sum import QUICK
    measured = json.loads((ROOT / QUICK_SINE_SUM["source"]).read_text())["summary"][str(QUICK.headline_seeds)]
    assert (QUICK_SINE_SUM["networks"], QUICK_SINE_SUM["helps"], QUICK_SINE_SUM["seeds"]) == \
        (QUICK.headline_seeds, measured["helps"], measured["seeds"])
    assert "the quick stage's interval lay above 1 on 10 of 10 seeds" in text
    assert "quick stage" not in sine_sum_text(top, quick=False)
    assert text.startswith("Sine-sum (section III.B, 5 layers, swish, 3 networks): naive / derivative test MSE 7.99x "
                           "[0.89, 71.7] (no clear difference;") and "39.2x [26.4, 58.2] over 5 networks" in text


@pytest.mark.slow
def test_rerun_reuses_datasets_and_checkpoints(quick_report):
    before = {path: path.stat().st_mtime_ns for path in (quick_report / "cache").glob("*.pt")}
    data = {path: path.stat().st_mtime_ns for path in (quick_report / "data").glob("*.h5")}
    data[quick_report / "sine_sum" / "results.json"] = (quick_report / "sine_sum" / "results.json").stat().st_mtime_ns
    assert before and data
    assert main(["reproduce", "--quick", "-o", str(quick_report), "--quiet"]) == 0
    assert {path: path.stat().st_mtime_ns for path in (quick_report / "cache").glob("*.pt")} == before
    assert {path: path.stat().st_mtime_ns for path in data} == data
    runs = json.loads((quick_report / "results.json").read_text())["runs"]
    assert runs and all(run["reused"] for run in runs)


def test_full_profile_uses_the_papers_splits():
    """Split sizes of every job of the full profile on stand-in datasets of the paper's sizes."""
    class Stub:
        def __init__(self, groups, name):
            self.groups, self.path, self.sha256 = np.asarray(groups), name, name

        def trajectory(self, index):
            return SimpleNamespace(tau=np.zeros((50, 6)))

    excitation, tracking = Stub(np.zeros(200, int), "ex"), Stub(np.repeat(np.arange(4), 25), "tr")
    local = Stub(np.zeros(200, int), "lo")
    identification = Stub(np.repeat(np.arange(4), FULL.identification_count // 4), "id")
    jobs = plan_jobs(FULL, excitation, local, tracking, identification)
    sim = [job for job in jobs if job.experiment == "sim"]
    assert {(len(job.train), len(job.val), len(job.test)) for job in sim} == {(10, 40, 120), (20, 40, 120), (40, 40, 120)}
    real = [job for job in jobs if job.experiment == "real"]
    assert {(len(job.train), len(job.val), len(job.test)) for job in real} == {(4, 20, 60), (12, 20, 60), (20, 20, 60)}
    for job in real:  # per initial pose: train / 5 validation / 15 test from each of the 4 poses
        groups = tracking.groups
        assert set(np.bincount(groups[list(job.train)], minlength=4)) == {job.train_size}
        assert set(np.bincount(groups[list(job.val)], minlength=4)) == {5}
        assert set(np.bincount(groups[list(job.test)], minlength=4)) == {15}
        assert not set(job.train) & set(job.test) and not set(job.val) & set(job.test)
    multistep = [job for job in jobs if job.experiment == "multistep"]
    assert sorted(job.model_type for job in multistep) == sorted(MODEL_TYPES)
    assert {(len(job.train), len(job.val), len(job.test)) for job in multistep} == {(20, 20, 60)}
    control = [job for job in jobs if job.experiment == "control"]
    assert [(job.model_type, job.seed) for job in control] == [
        (model_type, seed) for model_type in ("D", "DD", "PE", "PED") for seed in range(3)]
    assert {(len(job.train), len(job.val), len(job.test), job.derivative_source) for job in control} == {
        (72, 8, 20, "true")}
    assert FULL.mpc_plans == 20
    assert all(job.dataset == "id" for job in control)
    assert len({job.key() for job in jobs}) == len(jobs)
    activations_at_40 = {job.activation for job in sim if len(job.train) == 40}
    assert len(activations_at_40) == 9 and {job.seed for job in sim} == set(range(5))
    # naive/derivative pairs are alpha grids: the full grid (alpha by validation) for swish, else naive + paper
    for job in sim + real:
        expected = DEFAULT_ALPHA_GRID if job.activation == "swish" else (0.0, DEFAULT_ALPHA)
        assert job.alphas == expected and job.model_type == "D"
    local_jobs = [job for job in jobs if job.experiment == "sim_local"]
    assert {(len(job.train), len(job.val), len(job.test), job.activation, job.multistep, job.dataset)
            for job in local_jobs} == {(40, 40, 120, "swish", True, "lo")}
    assert {job.seed for job in local_jobs} == set(range(5))
    assert all(job.alpha_mode == "auto" for job in multistep)
    assert all(job.alpha_mode == "fixed" and job.max_epochs == FULL.control_max_epochs
               and job.action_rate == "zero_order_hold" for job in control)
    assert all(job.action_rate == "forward_difference" for job in jobs if job.experiment != "control")


@pytest.mark.slow
def test_multistep_rollout_equals_repeated_one_step_prediction(quick_report):
    from stdm_drake.learning.checkpoint import load_checkpoint
    from stdm_drake.learning.predict import predict, rollout
    runs = json.loads((quick_report / "results.json").read_text())["runs"]
    run = next(r for r in runs if r["experiment"] == "multistep" and r["model_type"] == "PED")
    model = load_checkpoint(quick_report / "cache" / f"{run['key']}.pt").model
    dataset = load_dataset(next((quick_report / "data").glob("tracking*.h5")))
    traj = dataset.trajectory(0)
    x = np.concatenate([traj.q[0], traj.v[0]])
    path = rollout(model, x, traj.tau[:30]).mean
    for k in range(30):
        x = predict(model, x, traj.tau[k]).mean
        np.testing.assert_array_equal(path[k], x)


def test_verdicts_follow_from_the_intervals():
    assert improvement_percent(naive=3.0, derivative=1.0) == pytest.approx(200.0)
    helps = paired_ratio([3.0, 3.3, 2.9, 3.1], [1.0, 1.0, 1.0, 1.0]).as_dict()
    assert helps["verdict"] == "helps" and helps["low"] > 1
    # consistent: the whole interval above 1 + half the paper's gain (150 %: 1.75)
    assert verdict(helps, 150) == "consistent with the paper"
    assert verdict(helps, 1000) == "inconsistent with the paper"          # the interval lies below 6
    unclear = paired_ratio([3.0, 0.5, 2.0], [1.0, 1.0, 1.0]).as_dict()
    assert unclear["verdict"] == "no clear difference" and verdict(unclear, 60) == "inconclusive"
    worse = paired_ratio([1.0, 1.0, 1.0], [2.0, 2.1, 1.9]).as_dict()
    assert worse["verdict"] == "hurts" and verdict(worse, 60) == "inconsistent with the paper"
    assert verdict(paired_ratio([3.0], [1.0]).as_dict(), 60) == "inconclusive (1 pair)"
    assert verdict(helps, 150, learned=False) == "uninformative (not learned)"
    assert verdict(helps, None) == ""
    assert paired_ratio([2.0], [1.0]).verdict == "no clear difference"   # one pair: no interval


def test_mpc_statistics_pair_by_plan_and_average_seeds():
    """Plan-level pairs: each type's q MSE on a plan is the geometric mean over its seeds."""
    from types import SimpleNamespace

    from stdm_drake.experiments.reproduce_report import mpc_statistics

    def run(model, plan, q):
        return SimpleNamespace(model=model, trajectory=plan, q_mse_rad2=q, solve_ms_mean=1.0, solve_ms_p95=2.0,
                               limit_violations=0, fallbacks=0)
    runs = [run("plant", p, 1.0) for p in range(4)]
    runs += [run(f"D seed {s}", p, 2.0 * (1 + s)) for s in range(2) for p in range(4)]        # gm over seeds: 2 sqrt 2
    runs += [run(f"DD seed {s}", p, [1.0, 1.1, 0.9, 1.0][p]) for s in range(2) for p in range(4)]
    rows = {row["model"]: row for row in mpc_statistics(runs)}
    assert rows["D"]["plant_over_model"]["ratio"] == pytest.approx(1 / (2 * 2 ** 0.5))
    assert rows["D"]["plant_over_model"]["verdict"] == "hurts" and rows["D"]["plant_over_model"]["pairs"] == 4
    assert rows["D"]["seed_ratios"] == pytest.approx([0.5, 0.25])
    assert rows["D"]["q_mse_rad2"] == pytest.approx(3.0)
    assert rows["DD"]["naive_over_derivative"]["verdict"] == "helps"
    assert "plant_over_model" not in rows["plant"] and "naive_over_derivative" not in rows["D"]


@pytest.mark.slow
def test_grid_variants_are_paired_members_of_one_grid(quick_report):
    """D, DD and DD-auto of one seed come from one alpha grid: the D row is the alpha-0 member, DD the
    paper's alpha, DD-auto the member with the lowest validation MSE (never above naive's)."""
    runs = json.loads((quick_report / "results.json").read_text())["runs"]
    grid = [r for r in runs if r["experiment"] == "sim" and r["activation"] == "swish" and r["seed"] == 0
            and r["train_size"] == max(QUICK.sim_train_sizes)]
    by_type = {r["model_type"]: r for r in grid}
    assert set(by_type) == {"D", "DD", "DD-auto"} and len({r["key"] for r in grid}) == 1
    assert by_type["D"]["alpha"] == 0 and by_type["DD"]["alpha"] == DEFAULT_ALPHA
    selection = by_type["DD-auto"]["alpha_selection"]
    assert by_type["DD-auto"]["alpha"] == selection["chosen_alpha"]
    assert by_type["DD-auto"]["val_mse"] == min(selection["val_mse"]) <= by_type["D"]["val_mse"]
    assert len(by_type["D"]["multistep_q"]) == 50    # open-loop over the whole excitation trajectory
    coverage = json.loads((quick_report / "results.json").read_text())["tables"]["coverage"]
    assert [row["regime"] for row in coverage] == ["global", "local"]


@pytest.mark.slow
def test_datasets_are_reused_only_when_collected_with_the_same_settings(tmp_path):
    from stdm_drake.experiments.jobs import ensure_dataset
    first = ensure_dataset("tracking", 4, 1, tmp_path, False, name="plans", robot=UR10)
    stamp = first.path.stat().st_mtime_ns
    assert ensure_dataset("tracking", 4, 1, tmp_path, False, name="plans", robot=UR10).path.stat().st_mtime_ns == stamp
    other = ensure_dataset("tracking", 4, 1, tmp_path, False, name="plans", robot=UR10,
                           controller="controllers/pid.yaml")
    assert other.path == first.path and other.path.stat().st_mtime_ns != stamp
    assert other.metadata.record["controller"]["kind"] == "pid"


def test_reproduce_exits_2_when_an_mpc_run_left_the_limits(tmp_path, monkeypatch, capsys):
    """The report is written and each failed closed loop named in one line; the exit status says the
    run is not a clean result."""
    from stdm_drake.commands import reproduce as command
    report = tmp_path / "out" / "report.html"
    monkeypatch.setattr(command, "reproduce", lambda *args, **kwargs: (
        report, ["model DD seed 1 left the robot's joint limits on 7 of 2000 steps (1 of 20 plans)"]))
    assert main(["reproduce", "--quick", "-o", str(tmp_path / "out"), "--quiet"]) == 2
    assert "stdm-drake reproduce: error: MPC stage: model DD seed 1 left the robot's joint limits on 7 of 2000" in \
        capsys.readouterr().err


@pytest.mark.slow
def test_training_results_are_typed_cached_and_retrained_when_stale(excitation_dataset, tmp_path):
    """A grid job yields one TrainingResult per variant with the physics baselines beside the model; the
    cache returns the same results marked reused; a cached row of another schema is trained again."""
    dataset = load_dataset(excitation_dataset)
    job = TrainJob("sim", str(excitation_dataset), dataset.sha256, (0, 1), (2,), (3,), "D", "tanh", 0,
                   ensemble_size=1, max_epochs=2, patience=2, horizon=10, multistep=True, train_size=2,
                   alphas=(0.0, DEFAULT_ALPHA))
    rows = run_job(job, tmp_path)
    assert [row.model_type for row in rows] == ["D", "DD"] and all(isinstance(row, TrainingResult) for row in rows)
    for row in rows:
        assert (row.experiment, row.train_size, row.reused) == ("sim", 2, False)
        assert row.q_mse > 0 and row.euler_q_mse > 0 and row.unchanged_v_mse > 0
        assert len(row.multistep_q) == len(row.stays_put_multistep_q) == 10 and row.rollout_ms > 0
    again = cached_rows(job, tmp_path)
    assert again == [dataclasses.replace(row, reused=True) for row in rows]
    stored = tmp_path / f"{job.key()}.json"
    stored.write_text(json.dumps([dict(row.stored(), old_field=1) for row in rows]))
    assert cached_rows(job, tmp_path) is None
