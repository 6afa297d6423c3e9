"""Benchmark: one held-torque plant step (the plant as a model: reset to (x, tau), advance one 10 ms period).

Robots: the UR-10 and Panda presets (primitive collision geometry) and a 6-joint arm whose links carry
dense STL collision meshes (an icosphere of 5120 triangles each, written by trimesh and loaded through
stdm-drake's OBJ conversion, as published descriptions are). Timed in the same run, interleaved
(median over rounds), on the same PlantSimulator:
  state reset   PlantSimulator.start: the context's state variables set back to their defaults
  full reset    the previous way: Diagram.SetDefaultContext (state and parameters, the scene graph's
                geometry included), then the same state and input
Both give bitwise the same next states (checked).

    python tools/bench_plant_step.py [--rounds 7] [--steps 20] [--write]
"""
from __future__ import annotations

import argparse
import logging
import os
import pathlib
import statistics
import sys
import tempfile
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))
os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")

from benchmark_report import machine_description, start_benchmark, write_benchmark_section  # noqa: E402
from stdm_drake.robots.plant import Dynamics, PlantConfig, PlantSimulator  # noqa: E402
from stdm_drake.robots.robot import MODELS_DIR, UR10_CONFIG, load_robot  # noqa: E402


def meshed_arm(folder: pathlib.Path):
    """A 6-joint serial arm (alternating z/y axes, 0.2 m links) whose every link has an STL collision
    mesh of 5120 triangles (and a cylinder visual)."""
    import trimesh
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.06)
    (folder / "meshes" / "link.stl").write_bytes(sphere.export(file_type="stl"))
    links, joints = ['<link name="base"/>'], []
    parent = "base"
    for i in range(1, 7):
        links.append(f'<link name="link{i}"><inertial><mass value="{4.0 / i:.3f}"/><origin xyz="0 0 0.1"/>'
                     '<inertia ixx="0.02" iyy="0.02" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>'
                     '<visual><geometry><cylinder radius="0.04" length="0.2"/></geometry></visual>'
                     '<collision><origin xyz="0 0 0.1"/><geometry><mesh filename="meshes/link.stl"/></geometry>'
                     '</collision></link>')
        axis = "0 0 1" if i % 2 else "0 1 0"
        joints.append(f'<joint name="j{i}" type="revolute"><parent link="{parent}"/><child link="link{i}"/>'
                      f'<origin xyz="0 0 {0.2 if i > 1 else 0.05}"/><axis xyz="{axis}"/>'
                      '<limit lower="-2.8" upper="2.8" effort="100" velocity="2.0"/></joint>')
        parent = f"link{i}"
    links.append('<link name="tool"/>')
    joints.append('<joint name="tool_fixed" type="fixed"><parent link="link6"/><child link="tool"/>'
                  '<origin xyz="0 0 0.2"/></joint>')
    (folder / "arm.urdf").write_text(f'<?xml version="1.0"?>\n<robot name="meshed_arm">{"".join(links + joints)}</robot>\n')
    (folder / "arm.yaml").write_text("name: meshed_arm\nmodel: arm.urdf\nweld_frame: base\n"
                                     "arm_joints: [j1, j2, j3, j4, j5, j6]\nhome: [0.0, 0.5, 0.0, 0.5, 0.0, 0.5]\n"
                                     "tool_frame: tool\n")
    return load_robot(folder / "arm.yaml")


def time_steps(simulator: PlantSimulator, states, torques, full_reset: bool) -> tuple[float, np.ndarray]:
    """Seconds per step over the given (x, tau) pairs, and the next states."""
    out = []
    start = time.perf_counter()
    for x, tau in zip(states, torques):
        if full_reset:
            simulator.diagram.SetDefaultContext(simulator.context)
        simulator.start(x, tau)
        out.append(simulator.advance_to(0.01))
    return (time.perf_counter() - start) / len(states), np.array(out)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--steps", type=int, default=20, help="plant steps per round")
    parser.add_argument("--write", action="store_true", help="update BENCHMARKS.md")
    args, origin = start_benchmark(parser)
    logging.getLogger("stdm_drake").setLevel(logging.WARNING)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        os.environ.setdefault("STDM_DRAKE_CACHE", folder)
        robots = [load_robot(UR10_CONFIG), load_robot(MODELS_DIR / "panda.yaml"), meshed_arm(pathlib.Path(folder))]
        for robot in robots:
            simulator = PlantSimulator(PlantConfig(), robot=robot)
            rng = np.random.default_rng(0)
            gravity = Dynamics(robot).actuated_gravity_torque(robot.home)
            states = [np.concatenate([robot.home + rng.normal(0, 0.05, robot.num_joints),
                                      rng.normal(0, 0.2, robot.num_joints)]) for _ in range(args.steps)]
            torques = [gravity + rng.normal(0, 0.5, robot.action_dim) for _ in range(args.steps)]
            times = {True: [], False: []}
            results = {}
            for _ in range(args.rounds):
                for full in (False, True):
                    seconds, results[full] = time_steps(simulator, states, torques, full)
                    times[full].append(seconds)
            if not np.array_equal(results[True], results[False]):
                raise SystemExit(f"{robot.name}: the two resets give different next states")
            fast, slow = (1e3 * statistics.median(times[flag]) for flag in (False, True))
            rows.append((robot.name, fast, slow))
            print(f"{robot.name}: state reset {fast:.3f} ms, full reset {slow:.3f} ms per step ({slow / fast:.1f}x)")
    table = ["| robot | collision geometry | state reset (ms per step) | full reset (ms per step) | speed-up |",
             "|---|---|---|---|---|"]
    kinds = {"ur10": "primitives", "panda": "primitives", "meshed_arm": "6 STL meshes, 5120 triangles each"}
    table += [f"| {name} | {kinds.get(name, '')} | {fast:.3f} | {slow:.3f} | {slow / fast:.1f}x |" for name, fast, slow in rows]
    report = "\n".join([
        f"One held-torque plant step (1 ms plant steps over a 10 ms period, SAP), {args.steps} random (x, tau) near "
        f"home per round, median of {args.rounds} rounds; both resets give bitwise the same next states.", "",
        *table, "",
        f"Machine: {machine_description()}.", ""])
    if args.write:
        write_benchmark_section("Deployment", "Plant step of the plant as model (tools/bench_plant_step.py)", report, origin)
    print(report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
