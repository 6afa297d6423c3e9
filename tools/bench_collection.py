"""Benchmark: data collection speed as a multiple of real time, against a bare Drake loop.

All three are measured in the same run, on the same default tracking plans (plant at 1 ms, PID):

- bare: a Drake diagram of plant + PidController + gravity compensation (InverseDynamics in
  gravity mode) + the plan as a TrajectorySource, simulated with one AdvanceTo per trajectory,
  no logging: what plain Drake costs;
- stdm-drake, 1 process: `Station.run` as `stdm-drake collect` uses it (sampled PID on the
  sensor model, zero-order hold, logging, true accelerations);
- stdm-drake, N processes: `collect()` end to end with N workers, planning and process start-up
  included;
- stdm-drake on the affected plant (models/ur10_effects.yaml: the Coulomb friction system in the
  diagram, rotor inertia, payload), 1 process: what `--plant-effects` costs.

Usage: python tools/bench_collection.py [--count 40] [--workers 2] [--write]
(--write replaces its subsection of BENCHMARKS.md).
"""
import argparse
import dataclasses
import os
import pathlib
import sys
import time

os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")

import numpy as np  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pydrake.systems.analysis import Simulator  # noqa: E402
from pydrake.systems.controllers import InverseDynamics, PidController  # noqa: E402
from pydrake.systems.framework import DiagramBuilder  # noqa: E402
from pydrake.systems.primitives import Adder, TrajectorySource  # noqa: E402
from pydrake.trajectories import PiecewisePolynomial  # noqa: E402

from benchmark_report import machine_description, start_benchmark, write_benchmark_section  # noqa: E402
from stdm_drake.cluster import RunnerConfig, job_pool  # noqa: E402
from stdm_drake.collection.collect import (CollectionRequest, init_station_worker, collect, plan_tracking,  # noqa: E402
                                           tracking_trajectory)
from stdm_drake.config import load_yaml_config  # noqa: E402
from stdm_drake.robots.control import SensorConfig, load_controller_config  # noqa: E402
from stdm_drake.collection.protocols import load_tracking_spec  # noqa: E402
from stdm_drake.paths import CONTROLLERS_DIR, MODELS_DIR, TRAJECTORIES_DIR  # noqa: E402
from stdm_drake.robots.effect_systems import actuation_input  # noqa: E402
from stdm_drake.robots.effects import load_plant_effects  # noqa: E402
from stdm_drake.robots.plant import PlantConfig, make_plant  # noqa: E402
from stdm_drake.robots.robot import UR10_CONFIG, load_robot  # noqa: E402
from stdm_drake.robots.station import Station, StationConfig  # noqa: E402

UR10 = load_robot(UR10_CONFIG)


def bare_drake_seconds(plans, settings) -> float:
    """Wall time to simulate every plan in a plain Drake PID diagram without logging."""
    builder = DiagramBuilder()
    plant, _ = make_plant(settings.plant, builder=builder, robot=settings.robot)
    gains = settings.controller
    pid = builder.AddSystem(PidController(kp=gains.kp, ki=gains.ki, kd=gains.kd))
    gravity = builder.AddSystem(InverseDynamics(plant, InverseDynamics.InverseDynamicsMode.kGravityCompensation))
    adder = builder.AddSystem(Adder(2, 6))
    times = np.arange(len(plans[0].q)) * settings.sample_period
    source = builder.AddSystem(TrajectorySource(
        PiecewisePolynomial.CubicHermite(times, plans[0].q.T, plans[0].qd.T), output_derivative_order=1))
    builder.Connect(plant.get_state_output_port(), pid.get_input_port_estimated_state())
    builder.Connect(source.get_output_port(), pid.get_input_port_desired_state())
    builder.Connect(plant.get_state_output_port(), gravity.get_input_port_estimated_state())
    builder.Connect(pid.get_output_port_control(), adder.get_input_port(0))
    builder.Connect(gravity.get_output_port_generalized_force(), adder.get_input_port(1))
    builder.Connect(adder.get_output_port(), actuation_input(builder, plant))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    started = time.perf_counter()
    for plan in plans:
        source.UpdateTrajectory(PiecewisePolynomial.CubicHermite(times, plan.q.T, plan.qd.T))
        diagram.SetDefaultContext(context)
        context.SetTime(0.0)
        plant.SetPositions(plant.GetMyContextFromRoot(context), plan.q[0])
        simulator.Initialize()
        simulator.AdvanceTo(times[-1])
    return time.perf_counter() - started


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=40, help="trajectories (1 s each)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3, help="best of this many runs of each")
    parser.add_argument("--write", action="store_true", help="update BENCHMARKS.md")
    args, origin = start_benchmark(parser)

    settings = StationConfig(robot=UR10, sensor=load_yaml_config(CONTROLLERS_DIR / "sensor.yaml", SensorConfig),
                                  controller=load_controller_config(CONTROLLERS_DIR / "pid.yaml"),
                                  plant=PlantConfig.discrete(0.001))
    request = CollectionRequest(protocol="tracking", count=args.count, seed=0, settings=settings,
                                tracking_spec=load_tracking_spec(TRAJECTORIES_DIR / "tracking.yaml", robot=UR10), workers=args.workers)
    with job_pool(RunnerConfig(workers=1), initializer=init_station_worker, initargs=(settings,)) as pool:
        plans, _ = plan_tracking(request, pool)
    simulated = sum(len(plan.q) - 1 for plan in plans) * settings.sample_period

    bare = min(bare_drake_seconds(plans, settings) for _ in range(args.repeats))

    def station_seconds(rig: Station) -> float:
        """Wall time of `Station.run` (as `collect` uses it) over every plan."""
        started = time.perf_counter()
        for i, plan in enumerate(plans):
            tracking_trajectory(rig, plan, np.random.default_rng([0, i]))
        return time.perf_counter() - started

    rig = Station(settings)
    ours = min(station_seconds(rig) for _ in range(args.repeats))

    def parallel_once():
        started = time.perf_counter()
        collect(request, progress=False)
        return time.perf_counter() - started

    parallel = min(parallel_once() for _ in range(args.repeats))
    affected_rig = Station(dataclasses.replace(settings, plant=PlantConfig.discrete(
        0.001, effects=load_plant_effects(MODELS_DIR / "ur10_effects.yaml"))))
    affected = min(station_seconds(affected_rig) for _ in range(args.repeats))

    rows = [
        ("bare Drake plant + PidController, no logging (baseline), 1 process", bare),
        ("stdm-drake sampled PID + sensor + logging, 1 process", ours),
        (f"stdm-drake `collect()` end to end, {args.workers} workers (planning, start-up included)", parallel),
        ("stdm-drake on the affected plant (`--plant-effects models/ur10_effects.yaml`), 1 process", affected),
    ]
    table = ["| loop | wall s | x real time | vs baseline |", "|---|---|---|---|"]
    for name, seconds in rows:
        table.append(f"| {name} | {seconds:.2f} | {simulated / seconds:.1f} | {bare / seconds:.2f}x |")
    report = "\n".join([
        f"{args.count} default tracking trajectories ({simulated:.0f} s simulated, plant step 1 ms, "
        f"data at 10 ms), best of {args.repeats}. Goal: >= 40x real time on 2 cores.", "",
        *table, "",
        f"Goal {'met' if simulated / parallel >= 40 else 'not met'}: {simulated / parallel:.1f}x end to end. The "
        f"stdm-drake loop costs {100 * (ours / bare - 1):+.0f}% against bare Drake in one process, so Drake's plant "
        f"step ({1e6 * bare / (simulated / 0.001):.0f} µs per 1 ms step here) bounds the rate; two workers add process "
        f"start-up and planning. The plant effects cost {100 * (affected / ours - 1):+.0f}% against the same loop on "
        "the nominal plant.", "",
        f"Machine: {machine_description()}."])
    print(report)
    if args.write:
        write_benchmark_section("Data collection", "Collection speed (tools/bench_collection.py)", report, origin)


if __name__ == "__main__":
    main()
