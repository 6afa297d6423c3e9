"""Benchmark: per-step latency of an exported model at batch 1, what a controller pays each cycle, against the
toolbox's numpy path, in one run, one thread.

Models: the paper's black boxes of the UR-10 (18 inputs, 12 outputs, delta): D (3 x 100 swish), PE (5 probabilistic
members), and a D with tanh (what Drake's MultilayerPerceptron represents); fresh initializations with the input
and output scales of the UR-10's data (the time of a step does not depend on the weights).
Cases per model, every one the next state of one (x, τ) row:
    numpy path (baseline)        LearnedModel.step_single, the toolbox's own fastest single-row step
    ONNX Runtime, C API (C++)    tools/cpp/step_onnx bench: one Run on preallocated tensors, no Python
    ONNX Runtime, Python API     InferenceSession.run from Python
    Drake-native system          the step diagram's output port Eval (C++ systems, called from Python)
Goal (issue 44): at most 20 µs per step for the 3 x 100 network from C++, so a 500 Hz loop spends under 1 % of its
cycle on the model.

Usage: python tools/bench_export.py [--calls 20000] [--rounds 5] [--write]   (builds tools/cpp/step_onnx in a temporary folder:
needs g++ and the ONNX Runtime headers of tools/cpp/onnxruntime_headers.sh)
"""
import argparse
import os
import pathlib
import re
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")
for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):   # one thread (before numpy loads)
    os.environ.setdefault(_variable, "1")
TOOLS = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(TOOLS))
from benchmark_report import machine_description, start_benchmark, write_benchmark_section  # noqa: E402


def black_box_checkpoint(path: pathlib.Path, members: int, probabilistic: bool, activation: str, robot) -> pathlib.Path:
    """The sampling benchmark's fresh paper's black box of the UR-10 (`bench_sampling.black_box`) saved as a
    checkpoint (timing only)."""
    from bench_sampling import black_box
    from stdm_drake.learning.checkpoint import save_checkpoint
    from stdm_drake.learning.structure import PAPER
    network = black_box(members, probabilistic, robot, activation).network
    return save_checkpoint(path, network.float(), metadata=dict(sample_period=0.01, structure=PAPER.as_dict(),
                                                                model_type="PE" if members > 1 else "D"))


def micros(step, calls: int) -> tuple[float, float]:
    """Median and 99th percentile µs of `calls` calls of step() (after 200 unmeasured ones)."""
    import numpy as np
    for _ in range(200):
        step()
    seconds = np.empty(calls)
    clock = time.perf_counter
    for index in range(calls):
        started = clock()
        step()
        seconds[index] = clock() - started
    return 1e6 * float(np.median(seconds)), 1e6 * float(np.percentile(seconds, 99))


def drake_step(native_path: pathlib.Path, x, a):
    from stdm_drake.deploy.drake_native import build_step_diagram, load_native_model
    diagram, native = build_step_diagram(load_native_model(native_path))
    context = diagram.CreateDefaultContext()
    native.set_parameters(diagram, context)
    state, action = diagram.GetInputPort("state"), diagram.GetInputPort("action")
    port = diagram.GetOutputPort("next_state")

    def step():      # a new row every call, as in a loop (a fixed input would return the port's cached value)
        state.FixValue(context, x)
        action.FixValue(context, a)
        return port.Eval(context)
    return step


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=20000, help="calls per case in all (default 20000)")
    parser.add_argument("--rounds", type=int, default=5,
                        help="rounds the cases take turns in (default 5); a case's figures: the median over rounds")
    parser.add_argument("--write", action="store_true", help="replace this benchmark's section of BENCHMARKS.md")
    args, origin = start_benchmark(parser)
    import numpy as np
    import onnxruntime
    from stdm_drake.cli import main as cli
    from stdm_drake.learning.learned_model import LearnedModel
    from stdm_drake.robots.robot import UR10_CONFIG, load_robot
    robot = load_robot(UR10_CONFIG)
    folder = pathlib.Path(tempfile.mkdtemp(prefix="bench_export_"))
    subprocess.run(["bash", str(TOOLS / "cpp" / "build.sh"), str(folder / "cpp"),
                    os.environ.get("STDM_ONNXRUNTIME_HEADERS", str(TOOLS.parent / ".venv" / "include" / "onnxruntime")),
                    sys.executable], check=True)
    x = np.concatenate([robot.home, np.full(6, 0.1)])
    a = np.full(6, 5.0)
    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    rows = []
    for name, members, probabilistic, activation in (("D", 1, False, "swish"), ("PE", 5, True, "swish"),
                                                     ("PE, --mean-only", 5, True, "swish"), ("D tanh", 1, False, "tanh")):
        stem = name.replace(" ", "_").replace(",", "").replace("-", "")
        checkpoint = black_box_checkpoint(folder / f"{stem}.pt", members, probabilistic, activation, robot)
        onnx_path = folder / f"{stem}.onnx"
        assert cli(["export", str(checkpoint), "-o", str(onnx_path)] + (["--mean-only"] if "mean-only" in name else [])) == 0
        model = LearnedModel(checkpoint, robot=robot)
        session = onnxruntime.InferenceSession(str(onnx_path), options, providers=["CPUExecutionProvider"])
        feeds = {"state": x[None].astype(np.float32), "action": a[None].astype(np.float32)}
        np.concatenate([x, a]).astype(np.float32).tofile(folder / "row.f32")
        def cpp(calls, onnx_path=onnx_path):
            measured = subprocess.run([str(folder / "cpp" / "step_onnx"), str(onnx_path), "bench", str(folder / "row.f32"),
                                       str(calls)], check=True, capture_output=True, text=True).stdout
            values = dict(re.findall(r"(median|min|p99) ([0-9.]+) us", measured))   # "median 5.7 us, min ..., p99 ..."
            return float(values["median"]), float(values["p99"])
        timers = [("numpy path (baseline)", lambda calls: micros(lambda: model.step_single(x, a), calls)),
                  ("ONNX Runtime, C API (C++ step_onnx)", cpp),
                  ("ONNX Runtime, Python API", lambda calls: micros(lambda: session.run(["next_state"], feeds), calls))]
        if activation == "tanh":
            native_path = folder / f"{stem}.yaml"
            assert cli(["export", str(checkpoint), "--target", "drake", "-o", str(native_path)]) == 0
            native_step = drake_step(native_path, x, a)
            timers.append(("Drake-native system (port Eval from Python)", lambda calls: micros(native_step, calls)))
        rounds = [[timer(args.calls // args.rounds) for _, timer in timers] for _ in range(args.rounds)]   # interleaved
        cases = [(label, tuple(float(np.median([row[index][part] for row in rounds])) for part in (0, 1)))
                 for index, (label, _) in enumerate(timers)]
        baseline = cases[0][1][0]
        for case, (median, p99) in cases:
            goal = "<= 20 µs" if case.startswith("ONNX Runtime, C API") and name == "D" else ""
            rows.append(dict(model=name, case=case, median=median, p99=p99, ratio=baseline / median, goal=goal))
            print(f"{name:7s} {case:45s} {median:9.2f} µs (p99 {p99:.2f})  {baseline / median:5.2f}x", flush=True)
    text = [f"Machine: {machine_description(threads=1)}; onnxruntime {onnxruntime.__version__}, g++ -O2.", "",
            "The next state of one (x, τ) row at batch 1 (a controller's call), the paper's black boxes of the UR-10 "
            "(3 x 100, 18 inputs, 12 outputs; fresh initializations); the cases take turns in "
            f"{args.rounds} rounds of {args.calls // args.rounds} calls (after 200 warm-up calls each), and each figure "
            "is the median over the rounds of a round's median (or 99th percentile). Speed-up: the numpy path's "
            "median over the case's.", "",
            "| model | case | µs / step | p99 µs | speed-up | goal |", "|---|---|---|---|---|---|"]
    text += [f"| {row['model']} | {row['case']} | {row['median']:.1f} | {row['p99']:.1f} | {row['ratio']:.2f}x | "
             f"{row['goal']} |" for row in rows]
    text += [""]
    print("\n".join(text))
    if args.write:
        write_benchmark_section("Deployment", "Exported model, latency per step (tools/bench_export.py)", "\n".join(text), origin)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
