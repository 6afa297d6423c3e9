"""The compiled MPC controller outside Python: `export --target controller` writes the controller file, the C++
program of core/ (mpc_controller.cpp over controller.hpp) reads it with a plan, and on the states a
Drake closed loop recorded it writes the torques the Python controller applied (the same control step: observer,
warm start, limits)."""
import subprocess

import numpy as np
import pytest

from presets import UR10
from test_export import synthetic_checkpoint
from test_mpc import quintic_reference
from stdm_drake.cli import main
from stdm_drake.closed_loop.compiled import build_controller_program
from stdm_drake.closed_loop.mpc import load_mpc_config, run_closed_loop
from stdm_drake.closed_loop.controller_file import controller_text
from stdm_drake.dynamics.physics import PlantModel
from stdm_drake.learning.learned_model import LearnedModel
from stdm_drake.learning.structure import DEFAULT

pytestmark = pytest.mark.slow     # (the program's build: about 80 s of one core)
EFFORT = 330.0


@pytest.fixture(scope="module")
def program(tmp_path_factory):
    path = tmp_path_factory.mktemp("program") / "mpc_controller"
    build_controller_program(path)
    return path


def program_torques(program, controller, reference, states) -> np.ndarray:
    """The program's torques (N, m) for the recorded states (N, 2n), the plan the reference's states."""
    plan = controller.with_name("plan.txt")
    np.savetxt(plan, reference.window(0, len(reference.q)), fmt="%.17g")
    result = subprocess.run([str(program), str(controller), str(plan)], input="\n".join(
        " ".join(f"{value:.17g}" for value in state) for state in states) + "\n", capture_output=True, text=True,
        timeout=300)
    assert result.returncode == 0, result.stderr
    return np.loadtxt(result.stdout.splitlines(), ndmin=2)


@pytest.mark.parametrize("refresh", ["all", 5])
def test_the_program_applies_the_python_controllers_torques_with_the_plant_as_model(program, tmp_path, refresh):
    """Also under the multi-level iteration (`jacobian_refresh: 5`: the file carries K, the program keeps its
    Jacobians from step to step as the extension does)."""
    import dataclasses
    model = PlantModel(0.01, robot=UR10, integrator="rk4")
    reference, config = quintic_reference(40), load_mpc_config()
    config = dataclasses.replace(config, optimizer=dataclasses.replace(config.optimizer, jacobian_refresh=refresh))
    log = run_closed_loop(model, reference, config, robot=UR10)
    assert log.implementation == "compiled"
    controller = tmp_path / "plant.controller"
    controller.write_text(controller_text(model, config, UR10))
    torques = program_torques(program, controller, reference, np.array(log.state))
    np.testing.assert_allclose(torques, np.array(log.torque), rtol=0, atol=1e-9 * EFFORT)


def test_an_exported_default_model_runs_in_the_program_as_in_python(program, tmp_path):
    """The default structure (next velocity from the nominal acceleration, Pinocchio in the program too), exported
    by the command line; its closed loop with a network of random weights leaves the plan, so the gravity fallback
    and the observer's resets are exercised as well. (The float32 network's sums round differently in the program,
    built for generic x86-64 over Pinocchio's precompiled library, and in the extension, built for this CPU's
    vector instructions: 1e-5 of the effort limit.)"""
    checkpoint = synthetic_checkpoint(tmp_path / "d.pt", DEFAULT)
    controller = tmp_path / "d.controller"
    assert main(["export", str(checkpoint), "--target", "controller", "-o", str(controller)]) == 0
    assert controller.read_text().startswith("# stdm-drake controller 1")
    model = LearnedModel(checkpoint, robot=UR10)
    reference = quintic_reference(30)
    log = run_closed_loop(model, reference, load_mpc_config(), robot=UR10)
    torques = program_torques(program, controller, reference, np.array(log.state))
    np.testing.assert_allclose(torques, np.array(log.torque), rtol=0, atol=1e-5 * EFFORT)


def test_a_file_that_is_not_a_controller_is_one_line_and_exit_2(program, tmp_path):
    other = tmp_path / "other.controller"
    other.write_text("hello\n")
    plan = tmp_path / "plan.txt"
    plan.write_text(" ".join(["0"] * 12) + "\n")
    result = subprocess.run([str(program), str(other), str(plan)], input="", capture_output=True, text=True)
    assert result.returncode == 2
    assert result.stderr.strip() == f"mpc_controller: {other} is not a controller file of stdm-drake export (format 1)"
