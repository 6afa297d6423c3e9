"""`stdm-drake train` / `evaluate` on a tiny dataset file written by the dataset module; benchmark report writer."""
import json

import numpy as np
import pytest

from stdm_drake.cli import main
from stdm_drake.data.dataset import Trajectory, load_dataset
from stdm_drake.data.writer import write_dataset
from stdm_drake.learning.evaluate import multi_step_errors, one_step_errors, trajectory_rollout_data
from stdm_drake.learning.trainer import build_model
from stdm_drake.learning.checkpoint import load_model, save_checkpoint
from stdm_drake.learning.models import dynamics_config



def synthetic_trajectory(rng, steps=30, dt=0.01):
    """Six decoupled damped pendulums under smooth torques: arrays named as the dataset module expects."""
    q, v = np.zeros((steps + 1, 6)), np.zeros((steps + 1, 6))
    tau = 0.5 * np.sin(0.3 * np.arange(steps)[:, None] + rng.uniform(0, 6, 6)) + rng.uniform(-0.5, 0.5, 6)
    tau_next = 0.5 * np.sin(0.3 * steps + rng.uniform(0, 6, 6))
    q[0], v[0] = rng.uniform(-1, 1, 6), rng.uniform(-0.5, 0.5, 6)

    def acceleration(q, v, u):
        return -2.0 * np.sin(q) - 0.3 * v + u

    qdd, qdd_end = np.zeros((steps + 1, 6)), np.zeros((steps, 6))
    for k in range(steps):
        qdd[k] = acceleration(q[k], v[k], tau[k])
        v[k + 1] = v[k] + dt * qdd[k]
        q[k + 1] = q[k] + dt * v[k + 1]
        qdd_end[k] = acceleration(q[k + 1], v[k + 1], tau[k])
    qdd[steps] = acceleration(q[steps], v[steps], tau_next)
    return Trajectory(q=q, v=v, tau=tau, tau_next=tau_next, q_true=q.copy(), v_true=v.copy(), qdd=qdd,
                      qdd_end=qdd_end)


def write_tiny_dataset(path, count, seed):
    rng = np.random.default_rng(seed)
    trajectories = [synthetic_trajectory(rng) for _ in range(count)]
    return write_dataset(path, trajectories, np.zeros(count, dtype=int),
                         {"protocol": "excitation", "sample_period": 0.01})


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    folder = tmp_path_factory.mktemp("learn_cli")
    dataset = write_tiny_dataset(folder / "tiny.h5", 10, seed=0)
    output = folder / "run"
    code = main(["train", str(dataset), "--predicts", "state", "--inputs", "raw", "-o", str(output), "--model", "DED", "--ensemble-size", "2",
                 "--alpha", "1e-3", "--hidden-width", "16", "--hidden-layers", "2", "--epochs", "4", "--seeds", "0", "1",
                 "--train", "6", "--val", "2", "--quiet"])
    assert code == 0
    return dataset, output


def test_train_writes_checkpoints_curves_and_summary(tiny):
    dataset, output = tiny
    summary = json.loads((output / "summary.json").read_text())
    assert summary["model_type"] == "DED" and set(summary["seeds"]) == {"0", "1"}
    split = summary["split"]
    assert len(split["train"]) == 6 and len(split["val"]) == 2 and len(split["test"]) == 2
    assert not set(split["train"]) & set(split["val"]) and not set(split["test"]) & set(split["train"])
    for seed in (0, 1):
        checkpoint = load_model(output / f"seed{seed}" / "checkpoint.pt", state_dim=12, action_dim=6)
        assert checkpoint.model_config.ensemble_size == 2 and checkpoint.model_config.residual
        assert checkpoint.training_config.alpha == pytest.approx(1e-3) and checkpoint.training_config.seed == seed
        assert checkpoint.metadata.dataset_sha256 == load_dataset(dataset).sha256
        assert checkpoint.metadata.sample_period == 0.01 and checkpoint.metadata.split == split
        lines = (output / f"seed{seed}" / "curves.csv").read_text().splitlines()
        assert lines[0].startswith("epoch,train_loss") and len(lines) == 5
        assert all(np.isfinite([float(v) for v in line.split(",")]).all() for line in lines[1:])


def test_train_refuses_to_overwrite_and_resumes(tiny, capsys):
    dataset, output = tiny
    arguments = ["train", str(dataset), "--predicts", "state", "--inputs", "raw", "-o", str(output), "--model", "DED", "--ensemble-size", "2",
                 "--alpha", "1e-3", "--hidden-width", "16", "--hidden-layers", "2", "--epochs", "4", "--seeds", "0", "1",
                 "--train", "6", "--val", "2", "--quiet"]
    capsys.readouterr()
    assert main(arguments) == 2
    assert "exists; pass --resume" in capsys.readouterr().err
    before = (output / "seed0" / "curves.csv").read_text()
    assert main(arguments + ["--resume"]) == 0
    assert (output / "seed0" / "curves.csv").read_text() == before


def test_evaluate_prints_and_writes_errors(tiny, tmp_path, capsys):
    dataset, output = tiny
    report = tmp_path / "report.json"
    capsys.readouterr()
    assert main(["evaluate", str(output / "seed0" / "checkpoint.pt"), str(dataset), "--horizon", "10",
                 "--json", str(report)]) == 0
    printed = capsys.readouterr().out
    assert "one-step MSE" in printed and "multi-step MSE" in printed and "split test: 2 trajectories" in printed
    content = json.loads(report.read_text())
    assert len(content["multi_step"]["angle_mse"]) == 10 and content["trained_on_this_dataset"]
    assert np.isfinite(content["one_step"]["angle_mse"]) and np.isfinite(content["one_step"]["velocity_mse"])
    # consistency: the multi-step error at step 1 is the one-step error of the first transitions
    checkpoint = load_model(output / "seed0" / "checkpoint.pt")
    data = load_dataset(dataset)
    x0, actions, truth = trajectory_rollout_data(data, content["trajectories"], 10)
    multi = multi_step_errors(checkpoint.model, x0, actions, truth)
    first = one_step_errors(checkpoint.model, x0, actions[:, 0], truth[:, 0])
    assert multi.angle_mse[0] == pytest.approx(first.angle_mse, rel=1e-6)
    assert multi.velocity_mse[0] == pytest.approx(first.velocity_mse, rel=1e-6)
    assert content["multi_step"]["angle_mse"] == pytest.approx(multi.angle_mse.tolist(), rel=1e-9)
    # the rollouts ran in the compiled core and said so; the numpy reference, one flag away, gives the same errors
    assert content["rollout_implementation"] == "compiled" and "rollouts: compiled" in printed
    reference = tmp_path / "numpy.json"
    assert main(["evaluate", str(output / "seed0" / "checkpoint.pt"), str(dataset), "--horizon", "10",
                 "--implementation", "numpy", "--json", str(reference)]) == 0
    numpy_content = json.loads(reference.read_text())
    assert numpy_content["rollout_implementation"] == "numpy (--implementation numpy)"
    assert numpy_content["multi_step"]["angle_mse"] == pytest.approx(content["multi_step"]["angle_mse"], rel=1e-4)


def test_evaluate_errors_are_one_line(tiny, tmp_path, capsys):
    dataset, output = tiny
    checkpoint = output / "seed0" / "checkpoint.pt"
    other = write_tiny_dataset(tmp_path / "other.h5", 3, seed=9)
    capsys.readouterr()
    assert main(["evaluate", str(checkpoint), str(other)]) == 2
    assert "not the dataset" in capsys.readouterr().err
    assert main(["evaluate", str(checkpoint), str(other), "--split", "all", "--horizon", "5"]) == 0
    small = save_checkpoint(tmp_path / "small.pt", build_model(dynamics_config(state_dim=2, action_dim=1), 0))
    capsys.readouterr()
    assert main(["evaluate", str(small), str(dataset)]) == 2
    error = capsys.readouterr().err
    assert "state dim 2 and action dim 1, expected state dim 12 and action dim 6" in error
    assert error.count("\n") == 1
    truncated = tmp_path / "cut.pt"
    truncated.write_bytes(checkpoint.read_bytes()[:1000])
    assert main(["evaluate", str(truncated), str(dataset)]) == 2
    assert "truncated or corrupt" in capsys.readouterr().err


def test_train_input_errors(tiny, tmp_path, capsys):
    dataset, _ = tiny
    capsys.readouterr()
    assert main(["train", str(dataset), "--predicts", "state", "--inputs", "raw", "-o", str(tmp_path / "x"), "--train", "9", "--val", "2", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "split needs" in err and "9 train + 2 validation" in err and "--train/--val/--test" in err
    assert main(["train", str(dataset), "--predicts", "state", "--inputs", "raw", "-o", str(tmp_path / "y"), "--model", "DD", "--alpha", "0",
                 "--quiet"]) == 2
    assert "alpha > 0" in capsys.readouterr().err


def test_benchmark_report_writer_keeps_other_sections(tmp_path):
    from tools_import import benchmark_report
    path = tmp_path / "BENCHMARKS.md"
    origin = dict(commit="0" * 40, clean=True, command="python tools/bench_x.py --write")
    path.write_text("# Benchmarks\n\n## Data collection\n\n### Simulation\n\nfast enough\n")
    benchmark_report.write_benchmark_section("Learning library", "Training step", "| a | b |\n", origin, path)
    benchmark_report.write_benchmark_section("Learning library", "Rollout", "one\n", origin, path)
    benchmark_report.write_benchmark_section("Learning library", "Training step", "| c | d |\n", origin, path)
    text = path.read_text()
    assert text.startswith("# Benchmarks\n\n## Data collection\n\n### Simulation\n\nfast enough\n")
    assert text.count("## Learning library") == 1 and text.count("### Training step") == 1
    assert "| c | d |" in text and "| a | b |" not in text
    assert text.index("### Training step") < text.index("### Rollout")
    path.write_text("# Benchmarks\n\n## Learning library\n\n### Rollout\n\nold\n\n## Data collection\n\nkeep\n")
    benchmark_report.write_benchmark_section("Learning library", "Rollout", "new\n", origin, path)
    text = path.read_text()
    assert "new" in text and "old" not in text and text.rstrip().endswith("## Data collection\n\nkeep")


def test_a_benchmark_section_has_its_results_file(tmp_path):
    """Each benchmark's section of BENCHMARKS.md comes with docs/results/benchmarks/TOOL.json (issue 55): the run's
    provenance, its text and its tables as rows, which the pages quoting a benchmark name as their source."""
    import json
    from tools_import import benchmark_report
    path = tmp_path / "BENCHMARKS.md"
    origin = dict(commit="1" * 40, clean=True, command="python tools/bench_x.py --rounds 3 --write", machine="M")
    body = ("Goal: <= 1 ms.\n\n| case | ms / step | met |\n|---|---|---|\n| **compiled** | 0.436 | no |\n"
            "| numpy | 2.884 | no |\n\nsecond table:\n\n| a | b |\n|:--|--:|\n| 1 | 2 |\n")
    written = benchmark_report.write_benchmark_section("Learning library", "Rollout (tools/bench_x.py)", body, origin, path)
    assert written == tmp_path / "docs" / "results" / "benchmarks" / "bench_x.json"
    record = json.loads(written.read_text())
    assert record["provenance"] == origin and record["title"] == "Rollout (tools/bench_x.py)"
    assert record["tables"] == [[{"case": "compiled", "ms / step": "0.436", "met": "no"},
                                 {"case": "numpy", "ms / step": "2.884", "met": "no"}], [{"a": "1", "b": "2"}]]
    assert "Command: `python tools/bench_x.py --rounds 3 --write` (commit 1111111, clean tree)." in path.read_text()
    assert benchmark_report.write_benchmark_section("Learning library", "Other", "x\n", origin, path, record=False) is None
    assert benchmark_report.write_benchmark_section("Learning library", "Two", "x\n", origin, path,
                                                    name="bench_x_2_thread").name == "bench_x_2_thread.json"


@pytest.mark.slow
@pytest.mark.parametrize("model_type", ["DD", "DED"])
def test_train_alpha_auto_keeps_the_validation_best_and_records_the_grid(tiny, tmp_path, capsys, model_type):
    dataset, _ = tiny
    output = tmp_path / model_type
    arguments = ["train", str(dataset), "--predicts", "state", "--inputs", "raw", "-o", str(output), "--model", model_type, "--alpha", "auto",
                 "--alpha-grid", "0", "1e-3", "1", *(["--ensemble-size", "2"] if model_type == "DED" else []),
                 "--hidden-width", "16", "--hidden-layers", "2", "--epochs", "5", "--lr-schedule", "cosine", "--train", "6", "--val", "2", "--quiet"]
    assert main(arguments) == 0
    printed = capsys.readouterr().out
    assert "seed 0: chosen by validation: alpha" in printed
    summary = json.loads((output / "summary.json").read_text())
    selection = summary["alpha_selection"]["0"]
    # naive kept beside a lower validation MSE: the line says so (newcomer pass 2 read "chosen" as contradicted)
    lowest = int(np.argmin(selection["val_mse"]))
    assert (lowest != selection["chosen_index"]) == ("had the lowest validation MSE, its gain within validation's "
                                                      "noise (the bounds below)" in printed), printed
    assert selection["alphas"] == [0.0, 1e-3, 1.0]
    chosen = selection["chosen_index"]
    assert selection["val_mse"][chosen] <= selection["val_mse"][0]     # never worse than naive on validation
    assert "gain_over_naive_low" not in selection    # 2 validation trajectories: too few to pair, the lowest wins
    assert selection["val_mse"][chosen] == min(selection["val_mse"])
    checkpoint = load_model(output / "seed0" / "checkpoint.pt", state_dim=12, action_dim=6)
    assert checkpoint.metadata.alpha_selection == selection
    assert checkpoint.training_config.alpha == selection["chosen_alpha"]
    assert checkpoint.training_config.lr_schedule == "cosine"
    assert checkpoint.model_config.ensemble_size == (2 if model_type == "DED" else 1)
    lines = (output / "seed0" / "alpha_selection.csv").read_text().splitlines()
    assert lines[0] == "alpha,derivative_source,val_state_mse_standardized,best_epoch,chosen" and len(lines) == 4
    assert (output / "seed0" / "alpha_selection.png").read_bytes().startswith(b"\x89PNG")
    before = (output / "seed0" / "checkpoint.pt").read_bytes()
    assert main(arguments + ["--resume"]) == 0       # a finished run: nothing is trained again
    assert load_model(output / "seed0" / "checkpoint.pt").metadata.alpha_selection == selection
    if model_type == "DD":
        assert (output / "seed0" / "checkpoint.pt").read_bytes() == before


def test_train_relative_alpha_scale_uses_its_own_grid_and_records_it(tiny, tmp_path, capsys):
    """--alpha-scale relative: the relative grid by default, the scale in the checkpoint and the selection, and the
    chosen alpha's validation gain over naive printed; a derivative-free model refuses the flag."""
    dataset, _ = tiny
    output = tmp_path / "relative"
    assert main(["train", str(dataset), "--predicts", "state", "--inputs", "raw", "-o", str(output), "--model", "DD",
                 "--alpha-scale", "relative", "--hidden-width", "16", "--hidden-layers", "2", "--epochs", "3",
                 "--train", "6", "--val", "2", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "relative alpha chosen by validation from 0, 0.01, 0.1, 1, 10" in out
    selection = json.loads((output / "summary.json").read_text())["alpha_selection"]["0"]
    assert selection["alphas"] == [0.0, 0.01, 0.1, 1.0, 10.0] and selection["alpha_scale"] == "relative"
    checkpoint = load_model(output / "seed0" / "checkpoint.pt", state_dim=12, action_dim=6)
    assert checkpoint.training_config.alpha_scale == "relative"
    if selection["chosen_alpha"] > 0:
        assert "against naive training's" in out
    assert main(["train", str(dataset), "--predicts", "state", "--inputs", "raw", "-o", str(output), "--model", "DD",
                 "--hidden-width", "16", "--hidden-layers", "2", "--epochs", "3", "--train", "6", "--val", "2", "--quiet",
                 "--resume"]) == 2     # resumed on the other scale: refused, not silently kept
    assert "chose its alpha on the relative scale; resume it with --alpha-scale relative" in capsys.readouterr().err
    assert main(["train", str(dataset), "--predicts", "state", "--inputs", "raw", "-o", str(tmp_path / "naive"),
                 "--model", "D", "--alpha-scale", "relative", "--quiet"]) == 2
    assert "alpha_scale (--alpha-scale) shapes the derivative loss" in capsys.readouterr().err


def test_alpha_flag_errors(tiny, tmp_path, capsys):
    dataset, _ = tiny
    for extra, message in ((["--model", "D", "--alpha", "auto"], "trains without"),
                           (["--model", "DD", "--alpha", "often"], "expected a number >= 0 or 'auto'"),
                           (["--model", "DD", "--alpha", "-1"], "expected a number >= 0 or 'auto'"),
                           (["--model", "DD", "--alpha", "auto", "--alpha-grid", "0", "-2"], "--alpha-grid"),
                           (["--model", "DD", "--lr-schedule", "cosine", "--min-lr", "1"], "min_learning_rate")):
        capsys.readouterr()
        try:
            code = main(["train", str(dataset), "--predicts", "state", "--inputs", "raw", "-o", str(tmp_path / "x"), "--quiet", *extra])
        except SystemExit as stop:   # argparse's own usage errors
            code = stop.code
        assert code == 2
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err, (extra, err)


def test_training_settings_file_with_flags_over_it(tiny, tmp_path, capsys):
    """`--config` loads a typed TrainSettings YAML; flags given on the command line override its keys."""
    dataset, _ = tiny
    settings = tmp_path / "de.yaml"
    settings.write_text("model: DE\nensemble_size: 2\nhidden_width: 8\nhidden_layers: 1\nepochs: 2\nseeds: [4]\n"
                        "train: 6\nval: 2\nlr_schedule: cosine\n")
    assert main(["train", str(dataset), "--predicts", "state", "--inputs", "raw", "-o", str(tmp_path / "run"), "--config", str(settings), "--epochs", "3",
                 "--quiet"]) == 0
    checkpoint = load_model(tmp_path / "run" / "seed4" / "checkpoint.pt")
    config = checkpoint.model_config
    assert (config.ensemble_size, config.hidden_width, config.hidden_layers) == (2, 8, 1)
    assert checkpoint.training_config.lr_schedule == "cosine"
    assert checkpoint.training_config.max_epochs == 3 and checkpoint.history["epoch"][-1] == 3  # the flag won
    assert checkpoint.metadata.model_type == "DE" and checkpoint.metadata.split_seed == 0
    for text, message in (("epoch: 3\n", "malformed training settings"),          # unknown key (typo)
                          ("epochs: many\n", "malformed training settings"),      # wrong type
                          ("model: XD\n", "model (--model) must be one of"),      # bad value
                          ("hidden_layers: 0\n", "hidden_layers (--hidden-layers) must be >= 1")):
        settings.write_text(text)
        capsys.readouterr()
        assert main(["train", str(dataset), "--predicts", "state", "--inputs", "raw", "-o", str(tmp_path / "bad"), "--config", str(settings), "--quiet"]) == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1, err
        assert not (tmp_path / "bad").exists()  # checks come before any work
    settings.write_text("lr: 1000000.0\nepochs: 1\ntrain: 6\nval: 2\n")   # a value the flag overrides: unused
    assert main(["train", str(dataset), "--predicts", "state", "--inputs", "raw", "-o", str(tmp_path / "lr"), "--config",
                 str(settings), "--lr", "0.001", "--quiet"]) == 0


def test_train_flags_are_the_settings_fields(tmp_path):
    """`train`'s flags are generated from TrainSettings (issue 60): one flag per field, the defaults the settings'
    (nothing restated in the command), each default given back as its own flag text parses to the same value, and
    a new field is a new flag with its help, choices and type, and no other code."""
    import argparse
    import dataclasses
    import typing
    from stdm_drake.commands import train
    from stdm_drake.commands.arguments import _shown, add_settings_flags
    from stdm_drake.learning.settings import TrainSettings, setting
    parser = argparse.ArgumentParser()
    train.add_arguments(parser)
    flags = {action.dest: action for action in parser._actions}
    fields = dataclasses.fields(TrainSettings)
    assert all(field.name in flags for field in fields)
    args = parser.parse_args(["data.h5", "-o", str(tmp_path / "run")])
    assert train.training_settings(args) == (TrainSettings(), set())   # no flag given: the settings' defaults
    for field in fields:   # each default written as a flag reads back as itself
        value = getattr(TrainSettings(), field.name)
        if value is None or isinstance(value, bool):
            continue
        text = [str(item) for item in value] if isinstance(value, list) else [str(value)]
        if not text:
            continue
        given = parser.parse_args(["data.h5", "-o", "x", "--" + field.name.replace("_", "-"), *text])
        assert getattr(given, field.name) == value, field.name
        shown = " ".join(map(_shown, value)) if isinstance(value, list) else _shown(value)
        assert f"default {shown}" in flags[field.name].help, field.name   # the help states the settings' default

    @dataclasses.dataclass
    class WithDropout(TrainSettings):
        dropout: float = setting(0.1, "dropout of the hidden layers")
        norm: typing.Optional[str] = setting(None, "layer normalization (unset: none)", choices=("layer", "rms"))
    extended = argparse.ArgumentParser()
    add_settings_flags(extended, WithDropout)
    parsed = extended.parse_args(["--dropout", "0.25", "--norm", "rms"])
    assert (parsed.dropout, parsed.norm) == (0.25, "rms") and not hasattr(parsed, "epochs")
    help_text = extended.format_help()
    assert "dropout of the hidden layers (default 0.1)" in help_text and "{layer,rms}" in help_text
    with pytest.raises(SystemExit):
        extended.parse_args(["--norm", "batch"])
    with pytest.raises(Exception, match="must be one of"):   # validate checks the same choices
        WithDropout(norm="batch").validate()


@pytest.mark.parametrize("setting", [["--lr", "1e9"], ["--lr", "1e9", "--model", "DE", "--ensemble-size", "2"]])
def test_diverged_training_is_an_error_not_a_result(tiny, tmp_path, capsys, monkeypatch, setting):
    """Training whose every loss turns NaN or inf ends train with one line (exit 2): no checkpoint of untrained
    weights and no summary claim it trained, and the output folder it made is gone (issue 25). (A learning
    rate above settings.MAX_LR is refused before training: let through here to make it diverge.)"""
    from stdm_drake.learning import settings
    monkeypatch.setattr(settings, "MAX_LR", float("inf"))
    dataset, _ = tiny
    capsys.readouterr()
    code = main(["train", str(dataset), "--predicts", "state", "--inputs", "raw", "-o", str(tmp_path / "run"),
                 "--epochs", "3", "--train", "6", "--val", "2", "--quiet", *setting])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "training diverged in epoch 1" in lines[0] and "lower them" in lines[0]
    assert not (tmp_path / "run").exists()


def test_a_diverging_rollout_is_an_infinite_error_not_a_failure(tiny, tmp_path, capsys):
    """A model whose open-loop rollout leaves the finite numbers (held-out run 7: a barely trained model made
    evaluate and view stop with 'states contain NaN'): evaluate reports the infinite error, the trajectories and
    the step, and its --json stays strict JSON (null); the rollout of any model holds NaN after the divergence."""
    import torch
    from stdm_drake.closed_loop.replay import held_after_divergence
    from stdm_drake.dynamics.model import DynamicsModel
    from stdm_drake.learning.checkpoint import load_checkpoint
    dataset, output = tiny
    checkpoint = load_checkpoint(output / "seed0" / "checkpoint.pt")
    with torch.no_grad():
        for parameter in checkpoint.model.parameters():
            parameter.mul_(30.0)
    wild = save_checkpoint(tmp_path / "wild.pt", checkpoint.model, training_config=checkpoint.training_config,
                           metadata=checkpoint.metadata)
    report = tmp_path / "wild.json"
    capsys.readouterr()
    assert main(["evaluate", str(wild), str(dataset), "--json", str(report)]) == 0
    captured = capsys.readouterr()
    assert "Warning" not in captured.err and captured.err.count("\n") == 0
    assert "the open-loop rollout diverged" in captured.out and "of 2 trajectories, the first at step" in captured.out

    def no_constants(name):
        raise AssertionError(f"{name} in the JSON")
    content = json.loads(report.read_text(), parse_constant=no_constants)
    multi = content["multi_step"]
    assert multi["diverged"] >= 1 and multi["angle_mse"][-1] is None and multi["angle_mse_mean"] is None
    assert multi["angle_mse"][multi["first_diverged_step"] - 2] is not None

    class Exploding(DynamicsModel):
        name, state_dim, action_dim, sample_period = "exploding", 2, 1, 0.01

        def step(self, x, a):
            return x * np.where(x[:, :1] > 0, 1e100, 1.0)   # rows with q > 0: 1e100, 1e200, 1e300, inf

        def jacobians(self, x, a):
            raise NotImplementedError
    x0, actions = np.array([[1.0, 0.0], [-1.0, 0.0]]), np.zeros((2, 6, 1))
    rollout = Exploding().rollout(x0, actions)
    assert np.isfinite(rollout.mean[1]).all() and np.isfinite(rollout.mean[0, :3]).all()
    assert np.isinf(rollout.mean[0, 3, 0]) and np.isnan(rollout.mean[0, 4:]).all()
    errors = multi_step_errors(Exploding(), x0, actions, np.zeros((2, 6, 2)))   # (1e200 squared: inf)
    assert errors.diverged == 1 and errors.first_diverged_step == 2
    assert np.isfinite(errors.angle_mse[0]) and np.isinf(errors.angle_mse[1:]).all()
    held, step = held_after_divergence(np.array([[0.0], [1.0], [np.inf], [np.nan]]))
    assert step == 2 and held[2:].tolist() == [[1.0], [1.0]]
    assert held_after_divergence(np.zeros((3, 1)))[1] is None
