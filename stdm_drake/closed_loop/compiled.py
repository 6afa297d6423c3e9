"""The compiled control step: the real-time iteration of `rti.py` and the limits of `constraints.py` in C++
(`core/control_step.hpp`, built at install as the extension module `stdm_drake._core`), with the prediction models
it covers linearized there too, so that nothing returns to Python within a control step.

What it covers: the models of `dynamics.compiled_core.compiled_model` (the toolbox's ensemble MLPs and the plant
as a model in RK4 steps). Other models run the numpy step, and the solver says so (`implementation`); the MPC's
outputs record which step ran.

The numpy implementation (`rti.RtiSolver`, `Rti(implementation="numpy")`) is the reference: the tests hold the
compiled step's torques equal to it (tests/test_compiled_step.py). The one place where the two may part is a QP
that does not settle within the iteration budget (`constraints.MAX_QP_ITERATIONS`): DAQP counts its active-set
changes, the compiled dual active-set method (Goldfarb & Idnani) counts its own, so the step that falls back to
the torque box alone may differ.
"""
from __future__ import annotations

import numpy as np

from stdm_drake.closed_loop.constraints import StateBounds
from stdm_drake.closed_loop.optimizer import OptimizerResult, TrackingCost, TrajectoryOptimizer
from stdm_drake.errors import InputError
from stdm_drake.dynamics.compiled_core import core_module


class CompiledRtiSolver(TrajectoryOptimizer):
    """The real-time iteration of `rti.RtiSolver` (same settings, same results) with the whole control step in
    C++; `core_model` from `dynamics.compiled_core.compiled_model`."""
    implementation = "compiled"

    def __init__(self, model, cost: TrackingCost, effort_limit: np.ndarray, config, bounds: StateBounds | None,
                 core_model):
        super().__init__(model, cost, effort_limit, bounds)
        self.config = config
        core = core_module()
        size = self.state_dim
        lower = bounds.lower if bounds is not None else np.full(size, -np.inf)
        upper = bounds.upper if bounds is not None else np.full(size, np.inf)
        self._core = core.RealTimeIteration(
            core_model, int(config.iterations), float(config.regularization), np.diag(cost.Q).astype(float),
            np.diag(cost.R).astype(float), float(cost.terminal_factor), self.effort_limit.astype(float),
            bounds is not None, bool(bounds is not None and bounds.hard), np.asarray(lower, dtype=float),
            np.asarray(upper, dtype=float), float(bounds.penalty_weight) if bounds is not None else 1.0,
            config.refresh_count())

    def solve(self, x0: np.ndarray, u_init: np.ndarray, reference: np.ndarray, u_ff: np.ndarray,
              offset: np.ndarray | None = None, x_init: np.ndarray | None = None) -> OptimizerResult:
        """As `rti.RtiSolver.solve`: x0 (2n,), u_init (H, m), reference (H+1, 2n), u_ff (H, m), offset (2n,),
        x_init (H+1, 2n) or None."""
        offset = np.zeros(self.state_dim) if offset is None else np.asarray(offset, dtype=float)
        as_float = np.ascontiguousarray
        u, x, cost, iterations, finite, active, slack = self._core.solve(
            as_float(x0, dtype=float), as_float(u_init, dtype=float), as_float(reference, dtype=float),
            as_float(u_ff, dtype=float), offset, None if x_init is None else as_float(x_init, dtype=float))
        return OptimizerResult(u, x, float(cost), int(iterations), bool(finite), bool(active), float(slack))

    def control_step(self, reference: np.ndarray, feedforward: np.ndarray, horizon: int, disturbance_gain: float):
        """policy.MpcStep's step in C++ over this solver (`_core.ControlStep`): reference (T, 2n) states and
        feedforward (T, m) N m at the sample period, held past the end."""
        return core_module().ControlStep(self._core, np.ascontiguousarray(reference, dtype=float),
                                         np.ascontiguousarray(feedforward, dtype=float), int(horizon),
                                         float(disturbance_gain))


def build_controller_program(output, compiler: str = "c++") -> None:
    """Compile the controller program (core/mpc_controller.cpp: reads a controller file and a plan, then a state per
    line on standard input, writes a torque per line) to the executable `output`, with this environment's Eigen
    (cmeel-eigen), Pinocchio (its headers and libpinocchio_default) and `compiler`; InputError (one line) where the
    compiler or the headers are missing or the build fails (about 80 s of one core)."""
    import pathlib
    import shutil
    import subprocess
    import cmeel
    if shutil.which(compiler) is None:
        raise InputError(f"no C++ compiler ({compiler!r} not found): the controller program needs one")
    prefix = pathlib.Path(cmeel.__file__).resolve().parent.parent / "cmeel.prefix"
    if not (prefix / "include" / "eigen3").is_dir() or not (prefix / "include" / "pinocchio").is_dir():
        raise InputError(f"Eigen's or Pinocchio's headers are missing under {prefix} (pip install cmeel-eigen pin)")
    core = pathlib.Path(__file__).resolve().parents[1] / "core"
    command = [compiler, "-std=c++17", "-O3", "-DNDEBUG", "-w", "-DPINOCCHIO_ENABLE_TEMPLATE_INSTANTIATION",
               "-DBOOST_MPL_LIMIT_LIST_SIZE=30", "-DBOOST_MPL_LIMIT_VECTOR_SIZE=30",
               "-DBOOST_MPL_CFG_NO_PREPROCESSED_HEADERS", "-DBOOST_FUSION_INVOKE_MAX_ARITY=12",
               f"-I{prefix / 'include'}", f"-I{prefix / 'include' / 'eigen3'}", str(core / "mpc_controller.cpp"),
               str(core / "rigid_body.cpp"), "-o", str(output), f"-L{prefix / 'lib'}", "-lpinocchio_default",
               f"-Wl,-rpath,{prefix / 'lib'}"]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        first = next((line for line in result.stderr.splitlines() if "error" in line), result.stderr.strip()[:200])
        raise InputError(f"the controller program did not build: {first}")
