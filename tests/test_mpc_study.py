"""The MPC's optimizer as a tagged value of its settings, the comparison and the study choosing it, and the
study's outputs: a fresh default folder per run, mpc.json naming what it ran on."""
import dataclasses
import json
import re

import numpy as np
import pytest

from presets import UR10, free_limits
from test_mpc import HoldFeedforward, quintic_reference
from stdm_drake.cli import main
from stdm_drake.closed_loop.comparison import compare_controllers
from stdm_drake.closed_loop.ilqr import Ilqr, IlqrSolver
from stdm_drake.closed_loop.mpc import MpcConfig, load_mpc_config, run_closed_loop
from stdm_drake.closed_loop.optimizer import OptimizerSettings
from stdm_drake.closed_loop.rti import Rti, RtiSolver
from stdm_drake.closed_loop.compiled import CompiledRtiSolver
from stdm_drake.closed_loop.study import MpcStudy, run_mpc_study
from stdm_drake.dynamics.physics import PlantModel
from stdm_drake.errors import InputError


@pytest.fixture(scope="module")
def plant_model():
    return PlantModel(0.01, robot=UR10, integrator="rk4")


def test_the_shipped_settings_are_the_default_real_time_iteration():
    """controllers/mpc.yaml names the RTI with the numbers it always had: one iteration, regularization 1e-6, and the
    compiled control step (the default), every node's Jacobians in every step (the exact step)."""
    config = load_mpc_config()
    assert config.optimizer == Rti(iterations=1, regularization=1e-6, implementation="compiled") == MpcConfig().optimizer
    assert config.record()["optimizer"] == dict(type="Rti", iterations=1, regularization=1e-6, jacobian_refresh="all",
                                                implementation="compiled")


@pytest.mark.parametrize("text, kind, solver", [
    ("optimizer: !Rti {iterations: 2, regularization: 1.0e-5}\n", Rti(iterations=2, regularization=1e-5), CompiledRtiSolver),
    ("optimizer: !Rti {implementation: numpy}\n", Rti(implementation="numpy"), RtiSolver),
    ("optimizer: !Ilqr\n  max_iterations: 2\n  line_search: [1.0, 0.5]\n",
     Ilqr(max_iterations=2, line_search=[1.0, 0.5]), IlqrSolver),
    ("optimizer: {iterations: 3}\n", Rti(iterations=3), CompiledRtiSolver),     # untagged: the first, the default
])
def test_each_tag_loads_and_runs_one_plan(tmp_path, plant_model, text, kind, solver):
    path = tmp_path / "mpc.yaml"
    path.write_text("horizon: 5\n" + text)
    config = load_mpc_config(path)
    assert config.optimizer == kind and config.horizon == 5
    log = run_closed_loop(plant_model, quintic_reference(5), config, robot=UR10)
    assert len(log.torque) == 5 and not any(log.fallback) and np.all(np.isfinite(log.torque))
    assert type(config.solver(plant_model, free_limits(100.0))) is solver


@pytest.mark.parametrize("text, message", [
    ("optimizer: !Pets {samples: 100}\n", "unknown optimizer !Pets; the MPC's optimizers are !Rti, !Ilqr"),
    ("optimizer: !Ilqr\n", "optimizer !Ilqr takes its settings as a mapping: write `optimizer: !Ilqr {}`"),
    ("optimizer: !Rti {max_iterations: 2}\n", "write `iterations:` for its `max_iterations:`"),
    ("optimizer: !Ilqr {line_search: [0]}\n", "mpc optimizer !Ilqr line_search steps must be in [1e-06, 1]"),
    ("optimizer: !Rti {iterations: 0}\n", "mpc optimizer !Rti iterations must be in 1..100"),
    # the flat layout before the tag: the tagged value to write, from the file's own values
    ("horizon: 5\nmax_iterations: 1\n", "replace `max_iterations:` with `optimizer: !Rti {iterations: 1}`"),
    ("optimizer: ilqr\nmax_iterations: 3\nline_search: [1.0, 0.5]\nregularization: 1.0e-6\n",
     "replace `optimizer:`, `max_iterations:`, `line_search:`, `regularization:` with "
     "`optimizer: !Ilqr {max_iterations: 3, line_search: [1.0, 0.5], regularization: 1.0e-06}`"),
    ("optimizer: rti\nmax_iterations: 1\nline_search: [1.0]\nregularization: 1.0e-6\n",
     "with `optimizer: !Rti {iterations: 1, regularization: 1.0e-06}`"),
    ("optimizer: mppi\n", "(optimizer 'mppi' is none of rti, ilqr)"),
    # a tagged optimizer beside an old top-level key: the tag's kind, its settings and the old key in one value
    ("optimizer: !Ilqr {max_iterations: 2}\nregularization: 1.0e-5\n",
     "now: replace `optimizer:`, `regularization:` with `optimizer: !Ilqr {regularization: 1.0e-05, max_iterations: 2}`"),
])
def test_a_bad_or_old_optimizer_is_a_one_line_error(tmp_path, text, message):
    path = tmp_path / "mpc.yaml"
    path.write_text(text)
    with pytest.raises(InputError) as error:
        load_mpc_config(path)
    assert message in str(error.value) and "\n" not in str(error.value) and str(error.value).startswith(str(path))


def test_the_command_refuses_an_old_settings_file_in_one_line_before_any_work(tracking_dataset, tmp_path, capsys):
    path = tmp_path / "old.yaml"
    path.write_text("horizon: 20\noptimizer: rti\nmax_iterations: 1\nline_search: [1.0, 0.5, 0.25, 0.1]\n"
                    "regularization: 1.0e-6\n")
    capsys.readouterr()
    assert main(["mpc", str(tracking_dataset), "--plans", "1", "--config", str(path), "-o", str(tmp_path / "m")]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and error.startswith("stdm-drake mpc: error: ") and "Traceback" not in error
    assert "`optimizer: !Rti {iterations: 1, regularization: 1.0e-06}`" in error
    assert not (tmp_path / "m").exists()


def test_settings_in_code_must_name_an_optimizer():
    with pytest.raises(InputError, match="optimizer must be one of !Rti, !Ilqr"):
        dataclasses.replace(MpcConfig(), optimizer="ilqr").validate()


@dataclasses.dataclass
class Feedforward(OptimizerSettings):
    """Settings of an optimizer defined outside the toolbox: the test's HoldFeedforward."""

    def validate(self) -> None:
        """It has no settings, so nothing to check."""

    def solver(self, model, cost, effort_limit, horizon, bounds=None):
        return HoldFeedforward(model, cost, effort_limit, bounds)


def test_the_comparison_runs_the_optimizer_it_is_given(plant_model):
    """compare_controllers(optimizer=...) replaces the settings' optimizer for every loop: the iLQR's runs equal
    those of settings that name it and differ from the RTI's; an optimizer from outside (the feedforward, every
    torque the reference's gravity torque) shows in the metrics."""
    config = dataclasses.replace(load_mpc_config(), horizon=4)
    references = [(0, quintic_reference(6))]

    def metrics(**options):
        results = compare_controllers([plant_model], references, options.pop("config", config), progress=False,
                                      robot=UR10, **options)
        return [(r.q_mse_rad2, r.effort_beyond_gravity_rms_nm, r.q_error) for r in results]
    ilqr = Ilqr(max_iterations=3, line_search=[1.0, 0.5])
    assert metrics(optimizer=ilqr) == metrics(config=dataclasses.replace(config, optimizer=ilqr))
    assert metrics(optimizer=ilqr) != metrics() == metrics(optimizer=Rti())
    (_, effort, _), = metrics(optimizer=Feedforward())
    assert effort < 1e-9    # N m beyond gravity: the feedforward's torques, not the RTI's


def short_settings(tmp_path):
    path = tmp_path / "short.yaml"
    path.write_text("horizon: 5\noptimizer: !Rti {iterations: 1}\n")
    return path


def test_a_second_default_run_writes_a_fresh_folder(tracking_dataset, tmp_path, monkeypatch, capsys):
    """Without -o the first run writes out/mpc and a second out/mpc-2, leaving the first's results as they were."""
    settings = short_settings(tmp_path)
    monkeypatch.chdir(tmp_path)
    command = ["mpc", str(tracking_dataset), "--plans", "1", "--quiet", "--config", str(settings)]
    assert main(command) == 0
    first = {path.name: path.read_bytes() for path in (tmp_path / "out" / "mpc").iterdir()}
    assert {"mpc.md", "mpc.csv", "mpc.json", "mpc.png"} <= set(first)
    assert "wrote out/mpc: " in capsys.readouterr().out
    assert main(command) == 0
    assert "wrote out/mpc-2: " in capsys.readouterr().out
    assert {path.name: path.read_bytes() for path in (tmp_path / "out" / "mpc").iterdir()} == first
    assert (tmp_path / "out" / "mpc-2" / "mpc.json").is_file()
    record = json.loads(first["mpc.json"])   # (the command and code that made it, no folder of this machine)
    assert record["provenance"]["command"] == "stdm-drake mpc DIR/tracking.h5 --plans 1 --quiet --config DIR/short.yaml"
    assert record["provenance"]["commit"] and str(tmp_path) not in json.dumps(record["provenance"])


def test_the_study_records_its_inputs_and_the_optimizer_it_ran(tracking_dataset, tmp_path, capsys):
    """run_mpc_study, the library's `mpc`: the optimizer given replaces the file's; mpc.json names the dataset
    (path, sha256), the robot, each model with its kind and file, and the settings file with the settings run."""
    from stdm_drake.data.dataset import load_dataset
    settings = short_settings(tmp_path)
    result = run_mpc_study(MpcStudy(dataset=tracking_dataset, plans=1, settings=settings, progress=False,
                                    optimizer=Ilqr(max_iterations=2), output=tmp_path / "study"))
    assert result.folder == tmp_path / "study" and not result.failures
    assert [row["model"] for row in result.summary] == ["plant"] and len(result.results) == 1
    record = json.loads((tmp_path / "study" / "mpc.json").read_text())
    assert record["inputs"] == result.record["inputs"]
    inputs = record["inputs"]
    assert inputs["dataset"] == dict(path=str(tracking_dataset), sha256=load_dataset(tracking_dataset).sha256)
    assert inputs["robot"]["name"] == "ur10" and inputs["robot"]["config"].endswith("ur10.yaml") and len(inputs["robot"]["model_sha256"]) == 64
    assert [(model["name"], model["kind"]) for model in inputs["models"]] == [("plant", "plant")]
    assert inputs["models"][0]["file"] == str(UR10.model_path)
    assert inputs["mpc_settings"]["file"] == str(settings) and inputs["mpc_settings"]["optimizer_given"]
    assert inputs["mpc_settings"]["settings"]["horizon"] == 5
    assert inputs["mpc_settings"]["settings"]["optimizer"] == dict(type="Ilqr", max_iterations=2,
                                                                   line_search=[1.0, 0.5, 0.25, 0.1], regularization=1e-6)
    printed = capsys.readouterr().out
    assert "| plant | 1 |" in printed
    # the constraint summary: the settings' mode, the steps with a constraint active and with slack, the crossings
    steps = result.results[0].steps
    assert (f"- plant: torques a hard box in the optimizer, position and velocity limits soft (0.02 rad and "
            f"0.05 rad/s inside): a limit active on 0 of {steps} control steps, slack used on 0; the plant's limits "
            f"crossed on 0") in printed
    assert inputs["mpc_settings"]["settings"]["constraints"] == dict(mode="soft", position_margin=0.02,
                                                                     velocity_margin=0.05, penalty_weight=1e5)
    assert {"constraint_active_steps", "slack_steps"} <= set(record["runs"][0])


def test_a_bad_study_is_refused_before_any_work(tracking_dataset, tmp_path):
    for study, message in [
            (MpcStudy(dataset=tracking_dataset, plans=0), "--plans must be >= 1, got 0"),
            (MpcStudy(dataset=tracking_dataset, models=[("D", tmp_path / "a.pt"), ("D", tmp_path / "b.pt")]),
             "--model names must differ; D given more than once"),
            (MpcStudy(dataset=tracking_dataset, optimizer=Ilqr(line_search=[])), "line_search non-empty")]:
        study.output = tmp_path / "never"
        with pytest.raises(InputError, match=re.escape(message)):
            run_mpc_study(study)
    assert not (tmp_path / "never").exists()


def test_a_rerun_stopped_while_writing_its_report_replaces_none_of_it(tracking_dataset, tmp_path, monkeypatch):
    """Held-out run 28: mpc.md, mpc.json, mpc.csv and mpc.png are one set; a rerun into the folder that a signal stops
    as it draws the figure (the last of them) leaves the first run's four files as they were, the new ones' temporary
    files gone."""
    import stdm_drake.closed_loop.study as study_module
    settings = short_settings(tmp_path)
    study = MpcStudy(dataset=tracking_dataset, plans=1, settings=settings, progress=False, output=tmp_path / "study")
    run_mpc_study(study)
    names = ("mpc.md", "mpc.json", "mpc.csv", "mpc.png")
    before = {name: (tmp_path / "study" / name).read_bytes() for name in names}

    def stopped(*arguments):
        raise KeyboardInterrupt
    monkeypatch.setattr(study_module, "draw_results", stopped)
    with pytest.raises(KeyboardInterrupt):
        run_mpc_study(dataclasses.replace(study, optimizer=Ilqr(max_iterations=2), force=True))
    assert {name: (tmp_path / "study" / name).read_bytes() for name in names} == before
    assert sorted(path.name for path in (tmp_path / "study").iterdir() if path.name.startswith(".mpc")) == []
