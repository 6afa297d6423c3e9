"""The reality-gap experiment: learned models against the nominal model on an affected plant (design,
endpoints and success criteria in docs/reality_gap.md, fixed before the run).

Usage: python tools/reality_gap.py [--quick] [--workers 2] [-o docs/results/reality_gap]
       [--data out/reality_gap_data] [--robot models/ur10.yaml] [--plant-effects models/ur10_effects.yaml]

Part 1 (closed loop): D and DD models (`train`'s defaults, 5 seeds) on dithered-PID tracking data of the
affected plant (gains sized from its inertia); each prediction model's MPC setting (effort-weight scale,
observer gain) chosen from one grid on the validation plans; then MPC with the nominal plant, the true
plant and each learned model on the test plans, tuned and shipped settings; the torque Jacobian of each
model against the true plant's. Part 2 (open loop per effect): the same per plant with one effect at a
time and all of them: one-step and 20/100-step errors of the nominal model, the learned models and the
physics-free baselines. Datasets and checkpoints are kept in --data and reused by a rerun.
`stdm-drake reproduce --plant-effects FILE` runs the same as its "reality gap" stage.
"""
import os
import pathlib
import sys


os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from affected_plant import parser_for, robot_and_effects  # noqa: E402
from stdm_drake.experiments import reality_gap  # noqa: E402
from stdm_drake.experiments.reality_gap_report import write_results  # noqa: E402


def main(argv=None) -> int:
    args = parser_for(__doc__, "reality_gap", quick_minutes=1).parse_args(argv)
    loaded = robot_and_effects(args, "reality_gap")
    if loaded is None:
        return 2
    robot, effects = loaded
    results = reality_gap.run_experiment(reality_gap.QUICK if args.quick else reality_gap.FULL, args.data, robot, effects,
                              workers=args.workers, say=lambda line: print(line, flush=True))
    results = dict(written_by="tools/reality_gap.py", quick=args.quick, **results)
    write_results(results, args.output)
    for row in results["closed_loop"]:
        ratio = row["nominal_over_model"]
        interval = f" [{ratio['low']:.3g}, {ratio['high']:.3g}]" if "low" in ratio else ""
        print(f"{row['setting']:>7} {row['model']:>10} {row['mpc_settings']}: q MSE {row['q_mse']:.3g} rad², "
              f"nominal / model {ratio['ratio']:.3g}x{interval}, violations {row['limit_violations']}, "
              f"solve {row['solve_ms_mean']:.1f} ms")
    print(results["verdict"]["text"])
    for row in results["torque_jacobian"]:
        print(f"torque Jacobian B, {row['model']}: median relative error {row['relative_error']:.3g}")
    for row in results["open_loop"]:
        print(f"{row['plant']:>14} {row['model']:>38}: one-step q {row['one_step_q']:.3g}, q@20 "
              f"{row['open_loop_q_20']:.3g}, q@end {row['open_loop_q_end']:.3g}")
    print(f"-> {args.output} in {results['seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
