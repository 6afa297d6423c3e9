"""Benchmark: the inverse-dynamics regressor Y(q, v, v̇) per sample, three ways, on the UR-10 description.

  AutoDiff   what `identify` uses (`identification.regressor.InverseDynamicsRegressor`): Drake's plant
             in AutoDiffXd, each link's SpatialInertia seeded with its 10 parameters' derivatives,
             CalcInverseDynamics, the gradient is Y
  symbolic   Drake's plant in symbolic::Expression, each link's parameters symbolic variables, the
             numeric state, CalcInverseDynamics, then DecomposeLumpedParameters (the manipulation
             course's route): W, the lumped parameters alpha(pi) and w0
  Pinocchio  pinocchio.computeJointTorqueRegressor on the same URDF (when the `pin` package is installed:
             it is not a dependency; the row says so when it is not)
All three agree: for random parameters pi, Y pi + tau_0 of the AutoDiff path equals W alpha(pi) + w0 of
the symbolic path to 1e-9 relative (checked each run); Pinocchio's regressor uses its own parameter
convention (inertia about the centre of mass frame's origin in its link frames), so its torque is checked
at the description's own parameters against Drake's inverse dynamics instead.

    python tools/bench_regressor.py [--samples 200] [--write]
"""
from __future__ import annotations

import argparse
import os
import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))
os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")

from benchmark_report import machine_description, start_benchmark, write_benchmark_section  # noqa: E402
from stdm_drake.identification.regressor import InverseDynamicsRegressor  # noqa: E402
from stdm_drake.robots.robot import UR10_CONFIG, load_robot  # noqa: E402


class SymbolicRegressor:
    """Y by Drake's symbolic plant and DecomposeLumpedParameters (one Expression pass per sample)."""

    def __init__(self, regressor: InverseDynamicsRegressor):
        from pydrake.multibody.tree import MultibodyForces_, SpatialInertia_, UnitInertia_
        from pydrake.symbolic import Expression, Variable
        self.plant = regressor.plant.ToSymbolic()
        self.context = self.plant.CreateDefaultContext()
        self.variables = []
        for link in regressor.links:
            p = [Variable(f"{link}.{name}") for name in ("m", "hx", "hy", "hz", "ixx", "iyy", "izz", "ixy", "ixz", "iyz")]
            self.variables += p
            m = Expression(p[0])
            com = [Expression(p[k]) / m for k in (1, 2, 3)]
            unit = UnitInertia_[Expression](p[4] / m, p[5] / m, p[6] / m, p[7] / m, p[8] / m, p[9] / m)
            self.plant.GetBodyByName(link).SetSpatialInertiaInBodyFrame(
                self.context, SpatialInertia_[Expression](m, com, unit, True))
        self.forces = MultibodyForces_[Expression](self.plant)
        self.order = regressor._velocity_indices

    def lumped(self, q, v, vd):
        """(W (n, k), alpha (k,) Expressions, w0 (n,)) at one numeric sample."""
        from pydrake.symbolic import DecomposeLumpedParameters, Expression
        n = len(q)
        positions, velocities, accelerations = (np.empty(n, dtype=object) for _ in range(3))
        positions[self.order] = [Expression(x) for x in q]
        velocities[self.order] = [Expression(x) for x in v]
        accelerations[self.order] = [Expression(x) for x in vd]
        self.plant.SetPositions(self.context, positions)
        self.plant.SetVelocities(self.context, velocities)
        self.plant.CalcForceElementsContribution(self.context, self.forces)
        torque = self.plant.CalcInverseDynamics(self.context, accelerations, self.forces)[self.order]
        return DecomposeLumpedParameters(torque, self.variables)


def pinocchio_regressor(robot):
    """(model, data, joint permutation) of Pinocchio for the robot's URDF, or None without the package."""
    try:
        import pinocchio
    except ImportError:
        return None
    model = pinocchio.buildModelFromUrdf(str(robot.model_path))
    return pinocchio, model, model.createData()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, default=200)
    parser.add_argument("--write", action="store_true", help="update BENCHMARKS.md")
    args, origin = start_benchmark(parser, argv)
    robot = load_robot(UR10_CONFIG)
    regressor = InverseDynamicsRegressor(robot)
    rng = np.random.default_rng(0)
    count, n = args.samples, robot.num_joints
    q = robot.home + rng.uniform(-1, 1, (count, n))
    v, vd = rng.uniform(-1, 1, (count, n)), rng.uniform(-5, 5, (count, n))
    rows = {}

    start = time.perf_counter()
    autodiff_rows, fixed = regressor.rigid_body_rows(q, v, vd)
    rows["Drake AutoDiff (identify's)"] = (time.perf_counter() - start) / count

    symbolic = SymbolicRegressor(regressor)
    symbolic_count = max(count // 10, 5)
    start = time.perf_counter()
    decompositions = [symbolic.lumped(q[i], v[i], vd[i]) for i in range(symbolic_count)]
    rows["Drake symbolic + DecomposeLumpedParameters"] = (time.perf_counter() - start) / symbolic_count
    parameters = regressor.parameters()[:regressor.num_link_parameters] * rng.uniform(0.5, 1.5)
    environment = dict(zip(symbolic.variables, parameters))
    for i, (W, alpha, w0) in enumerate(decompositions):
        lumped = np.array([a.Evaluate(env=environment) for a in alpha])
        number = np.vectorize(lambda entry: entry.Evaluate() if hasattr(entry, "Evaluate") else float(entry))
        torque_symbolic = number(W) @ lumped + number(w0)
        torque_autodiff = autodiff_rows[i] @ parameters + fixed[i]
        assert np.allclose(torque_symbolic, torque_autodiff, rtol=1e-9, atol=1e-9 * np.abs(torque_autodiff).max())
    lumped_count = len(decompositions[0][1])

    note = "not installed (`pip install pin` to time it)"
    pin = pinocchio_regressor(robot)
    if pin is not None:
        pinocchio, model, data = pin
        names = [model.names[i] for i in range(1, model.njoints)]
        index = [names.index(name) for name in robot.joint_names]
        start = time.perf_counter()
        for i in range(count):
            qi, vi, ai = (np.zeros(model.nq) for _ in range(3))
            qi[index], vi[index], ai[index] = q[i], v[i], vd[i]
            pinocchio.computeJointTorqueRegressor(model, data, qi, vi, ai)
        rows[f"Pinocchio {pinocchio.__version__} computeJointTorqueRegressor"] = (time.perf_counter() - start) / count
        from stdm_drake.robots.plant import Dynamics
        dynamics = Dynamics(robot)   # the description's own torque at one sample, both ways
        qi, vi, ai = (np.zeros(model.nq) for _ in range(3))
        qi[index], vi[index], ai[index] = q[0], v[0], vd[0]
        pin_torque = pinocchio.rnea(model, data, qi, vi, ai)[index]
        plant, context = dynamics.plant, dynamics.context
        plant.SetPositionsAndVelocities(context, np.concatenate([q[0], v[0]]))
        drake_torque = (plant.CalcMassMatrix(context) @ vd[0] + plant.CalcBiasTerm(context)
                        - plant.CalcGravityGeneralizedForces(context))
        assert np.allclose(pin_torque, drake_torque, rtol=1e-6, atol=1e-6), (pin_torque, drake_torque)
        note = "agrees with Drake's inverse dynamics at the description's parameters"
    baseline = rows["Drake AutoDiff (identify's)"]
    table = ["| regressor | ms per sample | relative to AutoDiff |", "|---|---|---|"]
    table += [f"| {name} | {seconds * 1e3:.3f} | {seconds / baseline:.2f}x |" for name, seconds in rows.items()]
    report = "\n".join([
        f"Y(q, v, v̇) of the UR-10 description ({len(regressor.links)} links, {regressor.num_link_parameters} "
        f"inertial parameters), {count} random samples ({symbolic_count} for the symbolic path); the symbolic "
        f"path's W alpha(pi) + w0 ({lumped_count} lumped parameters) equals the AutoDiff path's Y pi + tau_0 for "
        f"random pi (checked); Pinocchio: {note}.", "", *table, "",
        f"Machine: {machine_description()}."])
    print(report)
    if args.write:
        write_benchmark_section("Identification", "Inverse-dynamics regressor (tools/bench_regressor.py)", report, origin)
    return 0


if __name__ == "__main__":
    sys.exit(main())
