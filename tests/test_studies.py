"""The research studies' launcher, tools/study.py: every study of tools/studies/ listed and runnable by name,
each with the shape of a command (add_arguments, run), bad input as one line with exit status 2."""
import ast
import pathlib
import subprocess
import sys

import pytest

from tools_import import study

STUDIES = ("alpha-calibration", "closed-loop", "decisive", "default-train", "generalization-gap", "identification",
           "import-round-trip", "jacobian-accuracy", "model-structure", "published-arms", "realtime-loop", "robot-corpus",
           "reality-gap", "reality-gap-plans", "settling", "sampling-mpc", "mbrl-loop", "constrained-mpc",
           "quick-sine-sum", "sample-efficiency")


def test_list_names_every_study_with_its_one_line_description():
    result = subprocess.run([sys.executable, str(study.TOOLS / "study.py"), "--list"], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0 and result.stderr == ""
    listed = dict(line.split(maxsplit=1) for line in result.stdout.splitlines())
    assert sorted(listed) == sorted(STUDIES)
    for name, description in listed.items():
        assert description.endswith((".", ")")) and "\n" not in description, (name, description)


def test_every_module_of_the_folder_is_a_study_or_code_they_share():
    """A study defines both add_arguments and run; the folder's other modules (shared code) neither; none of
    them edits sys.path (the launcher does, once) or has a __main__ block of its own."""
    for path in sorted(study.STUDIES.glob("*.py")):
        tree = ast.parse(path.read_text())
        functions = {node.name for node in tree.body if isinstance(node, ast.FunctionDef)}
        is_study = path.stem.replace("_", "-") in STUDIES
        assert ({"add_arguments", "run"} & functions) == ({"add_arguments", "run"} if is_study else set()), path.name
        assert "sys.path" not in path.read_text() and "__main__" not in path.read_text(), path.name
    for name in STUDIES:
        module = study.load(name)
        assert callable(module.add_arguments) and callable(module.run) and module.__doc__.strip(), name


@pytest.mark.parametrize("name", STUDIES)
def test_each_study_shows_its_options(name, capsys):
    assert study.main([name, "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: tools/study.py {name}") and study.studies()[name] in " ".join(out.split())


def test_an_unknown_study_or_option_is_one_line_and_status_2(capsys):
    assert study.main(["no-such-study"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no study 'no-such-study'" in err and "--list" in err
    assert study.main(["decisive", "--no-such-option"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("tools/study.py decisive: error: ")
    assert study.main([]) == 2 and "usage: tools/study.py NAME" in capsys.readouterr().err


def test_bad_input_inside_a_study_is_one_line_and_status_2(tmp_path, capsys):
    """An InputError a study raises (here: a checkpoint that does not exist) ends the launcher with one line."""
    assert study.main(["jacobian-accuracy", "--allow-dirty", str(tmp_path / "none.h5"), str(tmp_path / "none.pt")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("tools/study.py jacobian-accuracy: error: ") and "none.h5" in err


def test_the_studies_live_outside_the_installed_package():
    package = pathlib.Path(study.ROOT / "stdm_drake")
    names = {path.stem for path in package.rglob("*.py")}
    assert not names & {"decisive", "reality_gap", "reality_gap_report", "identification_study",
                        "identification_closed_loop"}


def test_quick_sine_sum_refuses_a_single_network_and_an_earlier_result(tmp_path, capsys):
    """A paired interval needs two networks; results already written are never overwritten (both before any work)."""
    assert study.main(["quick-sine-sum", "--allow-dirty", "--networks", "1", "--seeds", "0", "-o", str(tmp_path)]) == 2
    assert "--networks must each be in 2..50" in capsys.readouterr().err
    (tmp_path / "results.json").write_text("{}")
    assert study.main(["quick-sine-sum", "--allow-dirty", "--networks", "2", "--seeds", "0", "-o", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "exists" in err and (tmp_path / "results.json").read_text() == "{}"
