"""Benchmark: time per control step of the sampling optimizers (closed_loop/sampling.py) against the gradient ones,
in one run, one thread.

Every optimizer solves the MPC problem of controllers/mpc.yaml (horizon 20, the UR-10's weights and effort
limits) from the UR-10's home pose, holding home, warm-started from its previous solve as in the closed loop,
on the paper's black boxes (3 x 100 swish, 18 inputs, 12 outputs; D: one network, PE: 5 probabilistic
members). Their weights are a fresh initialization with the input and output scales of the UR-10's data
(the time of a solve does not depend on the weights), or trained checkpoints (`--d`, `--pe`).

Goals (issue 43): iCEM's low budget (about 100 samples x 3 iterations, H = 20) on D at most 10 ms per
control step on one CPU core; PE with one particle per member (TS-infinity) and the PETS budget (400 x 5
iterations x 20 particles) stated on the CPU and, where a GPU exists (`--device cuda`), on the GPU.
Baselines in the same run: the real-time iteration (the MPC's default) and the iLQR on the same models, and the
samplers with the model's steps in numpy (`implementation: numpy`) beside the compiled core's steps (the
default, issue 54), also on a network of the default structure (its nominal acceleration from the robot's
rigid-body model: `bench_rollout.default_structure_model`).

With --write: BENCHMARKS.md's section and docs/results/compiled_step/bench_sampling.json (every row and the
commit the run's code is).

Usage: python tools/bench_sampling.py [--repeats 30] [--device cuda] [--d D.pt --pe PE.pt] [--write]
"""
import argparse
import os
import pathlib
import sys
import time

os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")
for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):   # one thread (before numpy loads)
    os.environ.setdefault(_variable, "1")
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from benchmark_report import machine_description, start_benchmark, write_benchmark_section  # noqa: E402


def black_box(members: int, probabilistic: bool, robot, activation: str = "swish"):
    """A fresh paper's black box (D or PE) of the UR-10 whose normalizers span the robot's joint ranges, speeds
    and torques (timing only)."""
    import numpy as np
    import torch
    from stdm_drake.learning.learned_model import LearnedModel
    from stdm_drake.learning.models import EnsembleMLP, ModelConfig
    from stdm_drake.robots.plant import Dynamics, joint_limits
    torch.manual_seed(0)
    network = EnsembleMLP(ModelConfig(input_dim=18, output_dim=12, residual=True, ensemble_size=members,
                                      probabilistic=probabilistic, activation=activation)).double()
    limits = joint_limits(Dynamics(robot).plant)
    spread = np.concatenate([np.full(6, 1.0), limits.velocity, limits.effort / 3])
    with torch.no_grad():
        network.input_normalizer.mean.copy_(torch.as_tensor(np.concatenate([robot.home, np.zeros(12)])))
        network.input_normalizer.std.copy_(torch.as_tensor(spread))
        network.output_normalizer.std.copy_(torch.as_tensor(np.concatenate([np.full(6, 1e-3), np.full(6, 1e-2)])))
    return LearnedModel(network, name="PE" if members > 1 else "D", sample_period=0.01)


def time_solves(solver, problem, repeats: int) -> dict:
    """Median and 95th percentile ms of `repeats` warm-started solves (after 3 unmeasured ones)."""
    import numpy as np
    x0, reference, u_ff = problem
    result = solver.solve(x0, u_ff, reference, u_ff)
    seconds = []
    for index in range(repeats + 3):
        started = time.perf_counter()
        result = solver.solve(x0, np.vstack([result.u[1:], result.u[-1:]]), reference, u_ff,
                              x_init=np.vstack([result.x[1:], result.x[-1:]]))
        if index >= 3:
            seconds.append(time.perf_counter() - started)
    return dict(median_ms=1e3 * float(np.median(seconds)), p95_ms=1e3 * float(np.percentile(seconds, 95)),
                finite=bool(result.finite))


def cases(device: str | None):
    """(label, model key, optimizer settings, goal text) of every measured case."""
    from stdm_drake.closed_loop.ilqr import Ilqr
    from stdm_drake.closed_loop.rti import Rti
    from stdm_drake.closed_loop.sampling import Cem, Icem, Mppi
    tsinf = dict(propagation="tsinf")
    rows = [("RTI, 1 iteration (baseline)", "D", Rti(), ""),
            ("iLQR, 1 iteration (baseline)", "D", Ilqr(max_iterations=1), ""),
            ("iCEM 100 x 3", "D", Icem(), "<= 10 ms"),
            ("iCEM 100 x 3, numpy steps (baseline)", "D", Icem(implementation="numpy"), ""),
            ("iCEM 100 x 3, PyTorch cpu", "D", Icem(framework="torch"), ""),
            ("MPPI 100 x 1", "D", Mppi(), ""),
            ("MPPI 100 x 1, numpy steps (baseline)", "D", Mppi(implementation="numpy"), ""),
            ("CEM 400 x 5", "D", Cem(), ""),
            ("CEM 400 x 5, numpy steps (baseline)", "D", Cem(implementation="numpy"), ""),
            ("RTI, 1 iteration (baseline)", "D (default structure)", Rti(), ""),
            ("iCEM 100 x 3", "D (default structure)", Icem(), ""),
            ("iCEM 100 x 3, numpy steps (baseline)", "D (default structure)", Icem(implementation="numpy"), ""),
            ("MPPI 100 x 1", "D (default structure)", Mppi(), ""),
            ("CEM 400 x 5", "D (default structure)", Cem(), ""),
            ("RTI, 1 iteration (baseline)", "PE", Rti(), ""),
            ("iCEM 100 x 3, TS-inf 5 particles", "PE", Icem(particles=5, **tsinf), "stated"),
            ("iCEM 100 x 3, TS-inf 5 particles, PyTorch cpu", "PE", Icem(particles=5, framework="torch", **tsinf), ""),
            ("PETS: CEM 400 x 5, TS-inf 20 particles", "PE", Cem(particles=20, **tsinf), "stated")]
    if device is not None:
        gpu = dict(framework="torch", device=device)
        rows += [("iCEM 100 x 3, " + device, "D", Icem(**gpu), ""),
                 ("iCEM 100 x 3, TS-inf 5 particles, " + device, "PE", Icem(particles=5, **tsinf, **gpu), ""),
                 ("PETS: CEM 400 x 5, TS-inf 20 particles, " + device, "PE", Cem(particles=20, **tsinf, **gpu),
                  "<= 10 ms")]
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--device", help="also run the PyTorch cases on this device (e.g. cuda)")
    parser.add_argument("--d", type=pathlib.Path, help="a trained D checkpoint of the paper's black box")
    parser.add_argument("--pe", type=pathlib.Path, help="a trained PE checkpoint of the paper's black box")
    parser.add_argument("--write", action="store_true", help="replace this benchmark's section of BENCHMARKS.md")
    args, origin = start_benchmark(parser, threads=1)   # (at the start: the code this run imports)
    import numpy as np
    import torch
    torch.set_num_threads(1)
    from stdm_drake.closed_loop.mpc import load_mpc_config
    from stdm_drake.learning.learned_model import LearnedModel
    from stdm_drake.robots.plant import Dynamics, joint_limits
    from stdm_drake.robots.robot import UR10_CONFIG, load_robot
    robot = load_robot(UR10_CONFIG)
    from bench_rollout import default_structure_model
    models = {"D": LearnedModel(args.d, robot=robot) if args.d else black_box(1, False, robot),
              "PE": LearnedModel(args.pe, robot=robot) if args.pe else black_box(5, True, robot),
              "D (default structure)": default_structure_model()[1]}
    config = load_mpc_config()
    dynamics = Dynamics(robot)
    limit = joint_limits(dynamics.plant).effort
    x0 = np.concatenate([robot.home, np.zeros(6)])
    problem = (x0, np.tile(x0, (config.horizon + 1, 1)), np.tile(dynamics.gravity_torque(robot.home), (config.horizon, 1)))
    rows = []
    for label, key, settings, goal in cases(args.device):
        solver = settings.solver(models[key], config.cost(6), limit, config.horizon)
        measured = time_solves(solver, problem, args.repeats)
        rows.append(dict(case=label, model=key, goal=goal, **measured))
        print(f"{label:50s} {key:22s} {measured['median_ms']:8.2f} ms (p95 {measured['p95_ms']:.2f})", flush=True)
    weights = "trained checkpoints" if args.d or args.pe else "fresh initializations"
    text = [f"Machine: {machine_description(threads=1)}." + (f" GPU: {torch.cuda.get_device_name()}." if args.device else
                                                            " No GPU on this machine: the GPU rows were not measured."),
            "", f"UR-10, horizon 20, controllers/mpc.yaml's weights, warm-started solves at home; the paper's black "
            f"boxes (3 x 100 swish; {weights}); median and 95th percentile of {args.repeats} solves, cases in one run.",
            "", "| optimizer | model | ms / step | p95 ms | goal |", "|---|---|---|---|---|"]
    text += [f"| {row['case']} | {row['model']} | {row['median_ms']:.2f} | {row['p95_ms']:.2f} | {row['goal']} |"
             for row in rows]
    text += [""]
    print("\n".join(text))
    if args.write:
        import json
        from stdm_drake.files import write_text_atomic
        write_benchmark_section("Deployment", "Sampling MPC, time per control step (tools/bench_sampling.py)",
                                "\n".join(text), origin, record=False)   # (its own results file below)
        folder = pathlib.Path(__file__).resolve().parents[1] / "docs" / "results" / "compiled_step"
        folder.mkdir(parents=True, exist_ok=True)
        write_text_atomic(folder / "bench_sampling.json", json.dumps(dict(
            provenance=origin, weights=weights,
            rows=rows), indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
