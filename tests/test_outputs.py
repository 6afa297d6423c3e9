"""Bad input never costs data: an output cannot clobber an input, a device or a foreign file; it is
checked before any work; counts out of range are refused with the valid range; every error is one
line with exit status 2 (issue 12's classes, one regression test each)."""
import hashlib
import os
import pathlib
import shutil
import stat

import pytest

from stdm_drake.cli import main
from stdm_drake.outputs import FOLDER_MARKER

SPEC = pathlib.Path(__file__).resolve().parents[1] / "trajectories" / "excitation.yaml"


def digest(path) -> str:
    return hashlib.sha256(pathlib.Path(path).read_bytes()).hexdigest()


def fails(capsys, argv, *messages) -> str:
    """Run the CLI; it must exit 2 with one line on stderr containing every message."""
    capsys.readouterr()
    assert main(argv) == 2, argv
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and error.startswith("stdm-drake"), error
    for message in messages:
        assert message in error, error
    return error


@pytest.fixture(scope="module")
def checkpoint(excitation_dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("ck") / "d"
    assert main(["train", str(excitation_dataset), "--model", "D", "--epochs", "1", "--train", "2", "--val", "1",
                 "--quiet", "-o", str(out)]) == 0
    return out / "seed0" / "checkpoint.pt"


def test_an_output_that_is_an_input_is_refused_and_the_input_kept(capsys, tmp_path, excitation_dataset, checkpoint):
    data = tmp_path / "data.h5"
    shutil.copy(excitation_dataset, data)
    before = digest(data)
    fails(capsys, ["evaluate", str(checkpoint), str(data), "--json", str(data)], "is one of the command's inputs")
    fails(capsys, ["view", str(checkpoint), str(data), "--html", str(data)], "is one of the command's inputs")
    link = tmp_path / "link.json"
    link.symlink_to(data)                                             # another name for the same file
    fails(capsys, ["evaluate", str(checkpoint), str(data), "--json", str(link)], "is one of the command's inputs")
    assert digest(data) == before
    spec = tmp_path / "spec.yaml"
    shutil.copy(SPEC, spec)
    fails(capsys, ["collect", "--protocol", "excitation", "--config", str(spec), "-o", str(spec)],
          "is one of the command's inputs")
    assert spec.read_text() == SPEC.read_text()
    fails(capsys, ["mpc", str(data), "--model", f"D={checkpoint}", "-o", str(data)], "is one of the command's inputs")
    assert digest(data) == before


def test_devices_folders_and_foreign_files_are_not_replaced(capsys, tmp_path, excitation_dataset, checkpoint):
    fails(capsys, ["collect", "--protocol", "excitation", "--count", "1", "-o", os.devnull], "is not a regular file")
    assert stat.S_ISCHR(os.stat(os.devnull).st_mode)
    fails(capsys, ["collect", "--protocol", "excitation", "--count", "1", "-o", str(tmp_path)], "is a folder")
    notes = tmp_path / "notes.txt"
    notes.write_text("mine\n")
    fails(capsys, ["collect", "--protocol", "excitation", "--count", "1", "-o", str(notes / "x.h5")],
          "is not a folder")
    fails(capsys, ["train", str(excitation_dataset), "-o", str(notes)], "exists and is not a folder")
    fails(capsys, ["evaluate", str(checkpoint), str(excitation_dataset), "--json", str(notes)],
          "stdm-drake did not write it; pass --force")
    assert notes.read_text() == "mine\n"
    foreign = tmp_path / "theirs"
    foreign.mkdir()
    (foreign / "thesis.tex").write_text("x")
    fails(capsys, ["train", str(excitation_dataset), "--epochs", "1", "-o", str(foreign)],
          "is a folder stdm-drake did not write")
    assert sorted(p.name for p in foreign.iterdir()) == ["thesis.tex"]
    assert main(["evaluate", str(checkpoint), str(excitation_dataset), "--horizon", "5", "--json", str(notes),
                 "--force"]) == 0                                  # --force allows it
    assert '"written_by": "stdm-drake evaluate"' in notes.read_text()
    assert main(["evaluate", str(checkpoint), str(excitation_dataset), "--horizon", "5", "--json", str(notes)]) == 0


@pytest.mark.slow
def test_what_others_are_made_from_is_replaced_only_with_force(capsys, tmp_path):
    """A dataset (even the same command's) needs --force, as a checkpoint trained on it records its SHA-256: a
    silent replacement would leave `evaluate` failing on that checkpoint. A report of a rerun replaces its own."""
    data = tmp_path / "data.h5"
    argv = ["collect", "--protocol", "excitation", "--count", "2", "--workers", "1", "--quiet", "-o", str(data)]
    assert main(argv) == 0
    out = tmp_path / "train"
    train = ["train", str(data), "--epochs", "1", "--train", "1", "--val", "1", "--test", "0", "--quiet", "-o", str(out)]
    assert main(train) == 0 and (out / FOLDER_MARKER).exists()
    fails(capsys, train, "checkpoint.pt exists; pass --resume")      # before any work, as before
    before = digest(data)
    fails(capsys, argv, f"-o/--output {data} exists and models trained on it record its SHA-256; choose another "
                        "path or pass --force")
    assert digest(data) == before
    report = ["evaluate", str(out / "seed0" / "checkpoint.pt"), str(data), "--split", "val", "--no-plant",
              "--json", str(tmp_path / "eval.json")]
    assert main(report) == 0 and main(report) == 0                    # its own report: replaced
    assert main(argv + ["--seed", "1", "--force"]) == 0 and digest(data) != before   # replaced when asked


@pytest.mark.parametrize("argv, message", [
    (["collect", "--count", "0", "-o", "x.h5"], "--count must be in 1..100000, got 0"),
    (["collect", "--workers", "0", "-o", "x.h5"], "--workers must be in 1..256, got 0"),
    (["collect", "--seed", "-1", "-o", "x.h5"], "--seed must be a non-negative integer"),
])
def test_counts_out_of_range_name_the_valid_range(capsys, tmp_path, monkeypatch, argv, message):
    monkeypatch.chdir(tmp_path)
    fails(capsys, argv, message)
    assert not (tmp_path / "x.h5").exists()


def test_counts_of_the_model_commands(capsys, tmp_path, excitation_dataset, checkpoint):
    data, ck = str(excitation_dataset), str(checkpoint)
    fails(capsys, ["mpc", data, "--plans", "0", "-o", str(tmp_path / "m")], "--plans must be >= 1, got 0")
    fails(capsys, ["mpc", data, "--model", f"D={ck}", "--plans", "1000", "--excitation-references",
                   "-o", str(tmp_path / "m")], "--plans 1000", "held-out plans")
    fails(capsys, ["mpc", data, "--model", f"D={ck}", "--model", f"D={ck}", "-o", str(tmp_path / "m")],
          "--model names must differ; D given more than once")
    fails(capsys, ["evaluate", ck, data, "--horizon", "1000"], "--horizon must be in 1..50")
    fails(capsys, ["view", ck, data, "--trajectories", "0", "--html", str(tmp_path / "v.html")],
          "--trajectories must be >= 1, got 0")
    assert not (tmp_path / "m").exists() and not (tmp_path / "v.html").exists()


def test_no_command_and_file_system_errors_are_one_line_exit_2(capsys, tmp_path, checkpoint):
    assert main([]) == 2
    assert "usage: stdm-drake" in capsys.readouterr().err
    folder = tmp_path / "folder.h5"
    folder.mkdir()
    fails(capsys, ["evaluate", str(checkpoint), str(folder)])        # a folder where a dataset is expected
    fails(capsys, ["inspect", str(tmp_path / "missing.h5")], "missing.h5")


def test_closed_loops_that_fall_back_or_leave_the_limits_are_failures():
    """MPC that fell back on most steps, or whose arm left its limits on any step, is not a result: one line
    per model, both causes in it where both hold (`mpc` prints them and exits 2)."""
    from stdm_drake.closed_loop.comparison import ClosedLoopResult, closed_loop_failures
    row = dict(trajectory=0, q_mse_rad2=1.0, v_mse=1.0, torque_rms_nm=1.0, effort_beyond_gravity_rms_nm=1.0,
               solve_ms_mean=1.0, solve_ms_p95=1.0, steps=100, q_error=[], constraint_active_steps=0, slack_steps=0)
    results = [ClosedLoopResult(model="plant", fallbacks=0, limit_violations=0, **row),
               ClosedLoopResult(model="NaN", fallbacks=100, limit_violations=0, **row),
               ClosedLoopResult(model="wild", fallbacks=10, limit_violations=0, **row),
               ClosedLoopResult(model="wild", fallbacks=10, limit_violations=3, **row),
               ClosedLoopResult(model="both", fallbacks=90, limit_violations=5, **row)]
    assert closed_loop_failures(results, note="the note") == [
        "model NaN fell back to gravity compensation on 100 of 100 steps (its predictions were not finite); "
        "its row is not a result; the note",
        "model wild left the robot's joint limits on 3 of 200 steps (1 of 2 plans); the note",
        "model both left the robot's joint limits on 5 of 100 steps (1 of 1 plans) and fell back to gravity "
        "compensation on 90 of 100 steps (its predictions were not finite); its row is not a result; the note"]


@pytest.mark.slow
def test_mpc_exits_2_when_a_closed_loop_leaves_the_limits(tracking_dataset, tmp_path, monkeypatch, capsys):
    """The command writes its tables and figure, then names the model whose arm left its limits and
    exits 2 (here the plant MPC's results, with violations injected after the real run)."""
    import dataclasses

    from stdm_drake.cli import main
    from stdm_drake.closed_loop import study as comparison
    real = comparison.compare_controllers

    def violating(*args, **kwargs):
        return [dataclasses.replace(result, limit_violations=4) for result in real(*args, **kwargs)]

    monkeypatch.setattr(comparison, "compare_controllers", violating)
    code = main(["mpc", str(tracking_dataset), "--plans", "1", "--quiet", "-o", str(tmp_path / "mpc")])
    err = capsys.readouterr().err
    assert code == 2
    assert "stdm-drake mpc: error: model plant left the robot's joint limits on 4 of" in err
    assert (tmp_path / "mpc" / "mpc.md").exists()


def test_a_new_output_inside_another_commands_folder_is_allowed_and_kept(capsys, tmp_path, excitation_dataset,
                                                                         checkpoint):
    """Nothing in another command's folder is replaced by a new file or folder beside its results (evaluate's
    JSON next to the checkpoint it scored); that command's rerun into its folder leaves it alone."""
    run = tmp_path / "run"
    shutil.copytree(checkpoint.parents[1], run)
    capsys.readouterr()
    assert main(["evaluate", str(run / "seed0" / "checkpoint.pt"), str(excitation_dataset), "--no-plant",
                 "--json", str(run / "eval.json")]) == 0
    scored = digest(run / "eval.json")
    assert main(["train", str(excitation_dataset), "--model", "D", "--epochs", "1", "--train", "2", "--val", "1",
                 "--quiet", "--resume", "-o", str(run)]) == 0
    assert digest(run / "eval.json") == scored
    fails(capsys, ["evaluate", str(run / "seed0" / "checkpoint.pt"), str(excitation_dataset), "--no-plant",
                   "--json", str(run / "summary.json")], "was written by `stdm-drake train`")


def test_a_failed_command_leaves_no_folder_it_made_for_nothing(tmp_path):
    """An error or a signal: an output folder this run made that holds only its marker (and empty folders) goes;
    one with a finished file stays, as does a folder that was there before."""
    from stdm_drake.outputs import command_outputs, mark_output_folder
    with pytest.raises(KeyboardInterrupt), command_outputs("train"):
        mark_output_folder(tmp_path / "new" / "deeper" / "run")
        (tmp_path / "new" / "deeper" / "run" / "seed0").mkdir()
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "before").mkdir()
    with pytest.raises(ValueError), command_outputs("train"):
        mark_output_folder(tmp_path / "before")
        mark_output_folder(tmp_path / "kept")
        (tmp_path / "kept" / "seed0").mkdir()
        (tmp_path / "kept" / "seed0" / "checkpoint.pt").write_bytes(b"a finished checkpoint")
        raise ValueError("disk full")
    assert (tmp_path / "before" / FOLDER_MARKER).exists() and (tmp_path / "kept" / "seed0" / "checkpoint.pt").exists()


def test_outputs_sharing_a_new_folder_leave_nothing_when_the_command_fails(capsys, tmp_path, excitation_dataset):
    """identify's robot and report are locked in the same new folder: both lock files go before the folders made
    for them, so a refusal after the output checks leaves nothing."""
    fails(capsys, ["identify", str(excitation_dataset), "--train", "9", "--val", "2", "-o",
                   str(tmp_path / "new" / "x" / "i.yaml")], "split needs")
    assert list(tmp_path.iterdir()) == []


def test_a_default_output_folder_never_replaces_an_earlier_run(tmp_path):
    """Without -o, mpc, reproduce and sine-sum write to their default folder only while it holds no finished
    run's results; then to default-2, default-3, ... A reproduce run stopped before its report (its cache
    only) continues in its folder."""
    from stdm_drake.outputs import FOLDER_MARKER, fresh_default_folder
    default = tmp_path / "out" / "mpc"
    assert fresh_default_folder(default, "mpc") == default
    default.mkdir(parents=True)
    (default / FOLDER_MARKER).write_text("marker\n")
    assert fresh_default_folder(default, "mpc") == default           # (only a marker: nothing to lose)
    (default / "mpc.json").write_text("{}")
    assert fresh_default_folder(default, "mpc") == tmp_path / "out" / "mpc-2"
    (tmp_path / "out" / "mpc-2").mkdir()
    (tmp_path / "out" / "mpc-2" / "mpc.csv").write_text("model")
    assert fresh_default_folder(default, "mpc") == tmp_path / "out" / "mpc-3"
    assert (default / "mpc.json").read_text() == "{}"
    reproduce = tmp_path / "out" / "reproduce"
    (reproduce / "cache").mkdir(parents=True)
    assert fresh_default_folder(reproduce, "reproduce") == reproduce   # unfinished: its cache is reused
    (reproduce / "report.md").write_text("# report")
    assert fresh_default_folder(reproduce, "reproduce") == tmp_path / "out" / "reproduce-2"


def test_json_outputs_write_non_utf8_file_names_as_ls_b_shows_them():
    """A checkpoint whose name holds a byte that is not UTF-8 (Python holds it as a surrogate) goes into mpc.json
    as "c\\xff.pt", which strict JSON parsers take, not as a lone surrogate (issue 56, held-out run 12)."""
    import json
    from stdm_drake.files import escaped_names
    name = os.fsdecode(b"c\xff.pt")
    record = escaped_names({"inputs": [name, pathlib.Path(name)], name: 1.0, "q": float("inf")})
    text = json.dumps(record)
    assert "\\udcff" not in text and json.loads(text)["inputs"] == ["c\\xff.pt", "c\\xff.pt"]
    assert json.loads(text)["c\\xff.pt"] == 1.0 and json.loads(text)["q"] == float("inf")   # (numbers as they were)
