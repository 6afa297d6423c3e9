"""Every result names the code that made it (stdm_drake/provenance.py): the commit and whether the checkout was
clean, the command with no folder of this machine in it, the machine; a study or a benchmark that writes results
refuses a checkout with uncommitted changes unless told (--allow-dirty, recorded)."""
import argparse
import ast
import json
import pathlib
import re
import subprocess

import pytest

from stdm_drake.provenance import provenance, source_state
from tools_import import benchmark_report, results_provenance, study

ROOT = pathlib.Path(__file__).resolve().parents[1]


def git(folder, *arguments):
    subprocess.run(["git", "-C", str(folder), *arguments], check=True, capture_output=True)


@pytest.fixture
def checkout(tmp_path):
    """A git checkout with one committed file, clean."""
    folder = tmp_path / "checkout"
    folder.mkdir()
    git(folder, "init", "-q")
    (folder / "code.py").write_text("x = 1\n")
    git(folder, "add", "code.py")
    git(folder, "-c", "user.name=t", "-c", "user.email=t@example.org", "commit", "-q", "-m", "first")
    return folder


def test_the_state_of_a_checkout_is_its_commit_and_whether_tracked_files_changed(checkout, tmp_path):
    state = source_state(checkout)
    assert re.fullmatch(r"[0-9a-f]{40}", state["commit"]) and state["clean"] is True
    (checkout / "notes.txt").write_text("untracked files do not make a checkout dirty\n")
    assert source_state(checkout)["clean"] is True
    (checkout / "code.py").write_text("x = 2\n")
    assert source_state(checkout) == dict(commit=state["commit"], clean=False)
    outside = tmp_path / "not_a_checkout"
    outside.mkdir()
    assert source_state(outside) == dict(commit=None, clean=False)
    installed = checkout / ".venv" / "site-packages"   # (a regular install inside a checkout names no commit)
    installed.mkdir(parents=True)
    assert source_state(installed) == dict(commit=None, clean=False)


def test_the_results_a_run_writes_do_not_make_the_code_unclean(checkout):
    """A change to docs/ or a Markdown page (results files, BENCHMARKS.md) leaves the checkout's code clean."""
    (checkout / "docs").mkdir()
    for name in ("docs/results.json", "BENCHMARKS.md"):
        (checkout / name).write_text("{}\n")
    git(checkout, "add", "docs/results.json", "BENCHMARKS.md")
    git(checkout, "-c", "user.name=t", "-c", "user.email=t@example.org", "commit", "-q", "-m", "results")
    for name in ("docs/results.json", "BENCHMARKS.md"):
        (checkout / name).write_text('{"new": 1}\n')
    assert source_state(checkout)["clean"] is True
    (checkout / "code.py").write_text("x = 3\n")
    assert source_state(checkout)["clean"] is False


def test_a_record_names_the_code_the_command_and_the_machine(checkout):
    record = provenance("python tools/study.py settling --quick", root=checkout)
    assert set(record) == {"commit", "clean", "command", "machine", "stdm_drake"}
    assert record["clean"] and "cores" in record["machine"] and record["command"].endswith("--quick")
    assert provenance("x", allow_dirty=True, root=checkout)["allow_dirty"] is True


def test_the_recorded_command_holds_no_folder_of_this_machine(tmp_path):
    command = benchmark_report.recorded_command("python tools/study.py decisive", [
        "--quick", "-o", str(tmp_path / "out"), f"--data={tmp_path / 'data'}", "--checkpoint",
        str(tmp_path / "DD" / "checkpoint.pt"), "--plant-effects", str(ROOT / "models" / "effects.yaml"), "--model",
        f"DD={tmp_path / 'DD' / 'model.pt'}"])
    assert command == ("python tools/study.py decisive --quick -o DIR --data=DIR --checkpoint DIR/checkpoint.pt "
                       "--plant-effects models/effects.yaml --model DD=DIR/model.pt")
    assert str(tmp_path) not in command


def test_a_study_refuses_a_checkout_with_uncommitted_changes_unless_told(checkout, tmp_path, monkeypatch, capsys):
    """One line, exit status 2, before the study starts (here it would have said its input is missing); with
    --allow-dirty the study runs (and reaches that error). A study that writes no results is not refused."""
    monkeypatch.setattr(benchmark_report, "ROOT", checkout)
    (checkout / "code.py").write_text("x = 2\n")
    arguments = ["--results", str(tmp_path / "none.json"), "-o", str(tmp_path / "plan_level.json")]
    assert study.main(["reality-gap-plans", *arguments]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "uncommitted changes" in err and "--allow-dirty" in err and "none.json" not in err
    assert study.main(["reality-gap-plans", "--allow-dirty", *arguments]) == 2
    err = capsys.readouterr().err
    assert "uncommitted" not in err and "none.json" in err
    assert study.main(["jacobian-accuracy", str(tmp_path / "none.h5"), str(tmp_path / "none.pt")]) == 2
    assert "uncommitted" not in capsys.readouterr().err   # (it prints its figures, writes nothing)
    git(checkout, "stash", "-q")   # clean again: no flag needed
    assert study.main(["reality-gap-plans", *arguments]) == 2 and "uncommitted" not in capsys.readouterr().err


def test_a_benchmark_refuses_to_write_from_a_dirty_checkout_unless_told(checkout, monkeypatch, capsys):
    monkeypatch.setattr(benchmark_report, "ROOT", checkout)
    (checkout / "code.py").write_text("x = 2\n")

    def parser():
        made = argparse.ArgumentParser(prog="bench_example.py")
        made.add_argument("--write", action="store_true")
        return made
    with pytest.raises(SystemExit) as exit_:
        benchmark_report.start_benchmark(parser(), ["--write"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1 and err.startswith("bench_example.py: error: ")
    args, origin = benchmark_report.start_benchmark(parser(), [])   # (a run that writes nothing: measured only)
    assert origin["clean"] is False and "allow_dirty" not in origin
    args, origin = benchmark_report.start_benchmark(parser(), ["--write", "--allow-dirty"])
    assert origin["allow_dirty"] is True and origin["command"] == "python tools/bench_example.py --write --allow-dirty"
    assert "uncommitted changes, --allow-dirty" in benchmark_report.command_line(origin)


def test_a_benchmark_section_names_its_command_and_commit(tmp_path):
    path = tmp_path / "BENCHMARKS.md"
    origin = dict(commit="0123456789abcdef", clean=True, command="python tools/bench_x.py --write")
    benchmark_report.write_benchmark_section("Deployment", "X", "| a | b |\n", origin, path)
    assert "| a | b |\nCommand: `python tools/bench_x.py --write` (commit 0123456, clean tree).\n" in path.read_text()


def test_every_study_and_benchmark_writes_its_provenance():
    """Each study puts the launcher's provenance in its results (jacobian-accuracy writes none: it prints); each
    benchmark takes its own at the start (start_benchmark) and its BENCHMARKS.md section names it."""
    for name in study.studies():
        text = (ROOT / "tools" / "studies" / f"{name.replace('-', '_')}.py").read_text()
        writes = "provenance=args.provenance" in text or "args.provenance)" in text
        assert writes == (name != "jacobian-accuracy"), name
    for path in sorted((ROOT / "tools").glob("bench_*.py")):
        text = path.read_text()
        assert "start_benchmark(parser" in text and "parse_args(" not in text, path.name
        calls = [node for node in ast.walk(ast.parse(text)) if isinstance(node, ast.Call)
                 and getattr(node.func, "id", None) == "write_benchmark_section"]
        assert calls and all(len(call.args) == 4 and getattr(call.args[3], "id", None) == "origin" for call in calls), \
            path.name


def test_a_quick_study_run_records_the_commit_it_ran_on(tmp_path):
    """The cheapest study (reality-gap-plans: a re-reading of a committed results file) run through the
    launcher: its JSON names HEAD and the command, with no folder of this machine."""
    output = tmp_path / "plan_level.json"
    assert study.main(["reality-gap-plans", "--allow-dirty", "-o", str(output)]) == 0
    record = json.loads(output.read_text())["provenance"]
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    assert record["commit"] == head and record["clean"] == source_state(ROOT)["clean"]
    assert record["command"] == "python tools/study.py reality-gap-plans --allow-dirty -o DIR"
    assert record["allow_dirty"] is True and str(tmp_path) not in json.dumps(record)


def test_a_command_records_its_own_line_with_no_folder_of_this_machine(tmp_path):
    from stdm_drake.outputs import command_outputs
    from stdm_drake.provenance import command_provenance
    with command_outputs("mpc", [str(tmp_path / "model.pt"), "--plans", "3", "-o", str(tmp_path / "mpc")]):
        record = command_provenance()
    assert record["command"] == "stdm-drake mpc DIR/model.pt --plans 3 -o DIR"
    assert record["commit"] == source_state()["commit"] and command_provenance()["command"] == "stdm-drake"


def test_no_committed_page_or_result_holds_a_folder_of_the_machine_it_was_made_on():
    """The docs, their results files, README.md and BENCHMARKS.md: no absolute path of a machine (a run's
    folders are DIR, the Python install PYTHON), so a committed result says nothing that is true only there."""
    files = subprocess.run(["git", "-C", str(ROOT), "ls-files", "docs", "README.md", "BENCHMARKS.md"],
                           capture_output=True, text=True, check=True).stdout.split()
    machine_path = re.compile(r"(?<![\w.])/(work|tmp|home|root|Users|private/var)/")
    found = [f"{name}:{number}" for name in files if not name.endswith((".png", ".h5", ".pt", ".onnx"))
             for number, line in enumerate((ROOT / name).read_text(errors="replace").splitlines(), 1)
             if machine_path.search(line)]
    assert not found, found[:10]


def test_every_results_file_committed_since_provenance_names_a_clean_commit():
    """Each JSON results file added to docs/results/ after the commit that brought provenance records (163cfe9)
    names the full commit it ran on, from a clean tree or with --allow-dirty recorded (older files predate the
    record; their pages name their commits in prose)."""
    import re
    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    listed = subprocess.run(["git", "-C", str(ROOT), "log", "--diff-filter=A", "--name-only", "--format=",
                             "163cfe9..HEAD", "--", "docs/results"], capture_output=True, text=True)
    if listed.returncode != 0:
        pytest.skip("history before 163cfe9 not in this clone")
    added = sorted({name for name in listed.stdout.split() if name.endswith(".json") and (ROOT / name).is_file()})
    assert added, "no results file added since 163cfe9"
    for name in added:
        record = json.loads((ROOT / name).read_text()).get("provenance") or {}
        assert re.fullmatch(r"[0-9a-f]{40}", record.get("commit") or ""), name
        assert record.get("clean") is True or record.get("allow_dirty") is True, name


def test_every_committed_results_file_names_its_commit_or_is_in_the_index():
    """A results file names the commit its run ran on (its provenance), or it is one of the files written before the
    studies recorded it, each listed in docs/results/provenance_index.json with the commit that first added it; a new
    file without provenance, or an index entry for a file that now names its commit, fails here."""
    assert results_provenance.problems() == []
    index = json.loads(results_provenance.INDEX.read_text())["files"]
    assert all(re.fullmatch(r"[0-9a-f]{40}", entry["committed_in"]) for entry in index.values())


def test_a_results_file_names_its_commit_in_any_of_the_recorded_forms(tmp_path):
    names = results_provenance.names_commit
    for name, text in (("a.json", '{"provenance": {"commit": "abc", "clean": true}}'), ("b.json", '{"commit": "abc"}'),
                       ("c.jsonl", '{"provenance": {"frozen_copy_of": "abc"}}\n{"id": 1}\n'),
                       ("d.csv", "run,commit\n1,abc\n")):
        (tmp_path / name).write_text(text)
        assert names(tmp_path / name), name
    for name, text in (("e.json", '{"provenance": {"command": "x"}}'), ("f.jsonl", '{"id": 1}\n'),
                       ("g.csv", "run,value\n1,2\n"), ("h.json", "[1, 2]")):
        (tmp_path / name).write_text(text)
        assert not names(tmp_path / name), name
