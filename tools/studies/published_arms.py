"""Published arms: four published arm descriptions, used as they ship, through the README's flows (issue 20).

    python tools/study.py published-arms --descriptions ARMS -o OUT [--arms panda,ur10,...] [--quick]

ARMS holds the descriptions fetched from their repositories (see `docs/results/published_arms/PROVENANCE.md`
for the repositories, commits and folder layout); nothing in them is edited. For each arm this writes
a robot config (OUT/ARM/robot.yaml: the description's own files, its MoveIt SRDF, a home pose, nothing
else), then runs the stdm-drake commands a user would, each as its own process:

1. `collect --protocol excitation` (the paper's V.A protocol, ranges derived from the inertia) and
   `inspect`;
2. the README's control flow on identification data: `collect` (tracked plans under the dithered PID
   sized from the inertia, ideal sensor), `inspect`, `train --model DD --action-rate zero_order_hold
   --derivative-source true` (--model D for an arm whose damping stops a joint faster than the
   sample period, where `train` warns that derivative learning fails), `evaluate --json`, `mpc --plans 3`
   (the plant as model beside the learned model) and `view --html`.

OUT/summary.json and OUT/summary.csv: one row per arm with every command's exit status and time, the
learned model's one-step errors beside the Euler step, "velocity unchanged" and the plant, the closed
loops' tracking errors, limit violations and solve times, and the view's open-loop errors. The run
fails (exit status 1) when a command fails, the learned model does not beat the physics-free
baselines, or a closed loop leaves the limits or falls back to gravity compensation. --quick: fewer
trajectories and epochs (a smoke run, not a result).
"""
import argparse
import json
import os
import pathlib
import re
import subprocess
import sys
import time

from stdm_drake.files import rows_csv, write_text_atomic

# Each arm: its robot config, with paths relative to the descriptions folder. The homes are each maker's
# documented ready/home pose where one exists (Panda "ready", Kinova Gen3 "home"), else an elbow-up
# pose inside the limits; the tool frames are the descriptions' flange frames.
ARMS = {
    "panda": dict(
        name="franka_panda", model="panda_pybullet/franka_panda/panda.urdf",
        srdf="panda/moveit_resources_panda_moveit_config/config/panda.srdf",
        arm_joints=[f"panda_joint{i}" for i in range(1, 8)],
        locked_joints={"panda_finger_joint1": 0.02, "panda_finger_joint2": 0.02},
        home=[0.0, -0.785398, 0.0, -2.356194, 0.0, 1.570796, 0.785398], tool_frame="panda_hand"),
    "ur10": dict(
        name="ur10_ros", model="ur10/ur_description/urdf/ur10.urdf",
        package_paths={"ur_description": "ur10/ur_description", "ur10_moveit_config": "ur10/ur10_moveit_config"},
        srdf="package://ur10_moveit_config/config/ur10.srdf", weld_frame="base_link",
        arm_joints=["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
                    "wrist_3_joint"],
        home=[0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0], tool_frame="tool0"),
    "kinova_gen3": dict(
        name="kinova_gen3", model="kinova_gen3/kortex_description/arms/gen3/7dof/urdf/GEN3-7DOF-NOVISION_FOR_URDF_ARM_V12.urdf",
        package_paths={"kortex_description": "kinova_gen3/kortex_description"},
        srdf="DERIVED/gen3.srdf", weld_frame="base_link",
        arm_joints=[f"joint_{i}" for i in range(1, 8)],
        home=[0.0, 0.26, 3.14, -2.27, 0.0, 0.96, 1.57], tool_frame="end_effector_link"),
    "abb_irb1200": dict(
        name="abb_irb1200", model="abb_irb1200/abb_irb1200_support/urdf/irb1200_5_90.urdf",
        package_paths={"abb_irb1200_support": "abb_irb1200/abb_irb1200_support",
                       "abb_irb1200_5_90_moveit_config": "abb_irb1200/abb_irb1200_5_90_moveit_config"},
        srdf="package://abb_irb1200_5_90_moveit_config/config/abb_irb1200_5_90.srdf", weld_frame="base_link",
        arm_joints=[f"joint_{i}" for i in range(1, 7)],
        home=[0.0, 0.3, 0.3, 0.0, 0.6, 0.0], tool_frame="tool0"),
}
# Kinova ships its SRDF only as xacro, whose one argument is a name prefix (default empty): the file with
# the prefix expanded to its default is what `xacro` would write.
KINOVA_SRDF_XACRO = "kinova_gen3/kortex_move_it_config/gen3_move_it_config/config/7dof/gen3.srdf.xacro"


def robot_config(arm: str, descriptions: pathlib.Path, folder: pathlib.Path) -> pathlib.Path:
    """Write folder/robot.yaml for `arm` (paths made absolute under `descriptions`); return its path."""
    import yaml
    config = dict(ARMS[arm])
    if config["srdf"].startswith("DERIVED/"):
        text = (descriptions / KINOVA_SRDF_XACRO).read_text()
        text = text.replace("$(arg prefix)", "").replace('<xacro:arg name="prefix" default="" />', "")
        write_text_atomic(folder / "gen3.srdf", text)
        config["srdf"] = str(folder / "gen3.srdf")
    elif not config["srdf"].startswith("package://"):
        config["srdf"] = str(descriptions / config["srdf"])
    config["model"] = str(descriptions / config["model"])
    config["package_paths"] = {name: str(descriptions / path) for name, path in config.get("package_paths", {}).items()}
    path = folder / "robot.yaml"
    write_text_atomic(path, yaml.safe_dump(config, sort_keys=False))
    return path


def learned_model_type(robot_config: pathlib.Path, sample_period: float = 0.01) -> str:
    """The README's rule: DD, or D when `train` would warn that the description's damping stops a joint
    faster than the sample period (derivative learning failed there)."""
    import logging
    from stdm_drake.robots.plant import Dynamics
    from stdm_drake.robots.robot import load_robot
    for name in ("drake", "stdm_drake"):   # the commands themselves report the description's warnings
        logging.getLogger(name).setLevel(logging.ERROR)
    constants = Dynamics(load_robot(robot_config)).damping_time_constants()
    return "D" if (constants < sample_period).any() else "DD"


def command(log: list, folder: pathlib.Path, label: str, *arguments) -> tuple[int, str]:
    """Run `stdm-drake ARGUMENTS` as its own process; log its status and time; return (status, stdout)."""
    start = time.perf_counter()
    result = subprocess.run([sys.executable, "-m", "stdm_drake.cli", *map(str, arguments)], capture_output=True,
                            text=True, env=dict(os.environ, DRAKE_ALLOW_NETWORK="meshcat"))
    seconds = time.perf_counter() - start
    write_text_atomic(folder / f"{label}.log", result.stdout + result.stderr)
    log.append(dict(step=label, status=result.returncode, seconds=round(seconds, 1)))
    print(f"  {label}: exit {result.returncode}, {seconds:.0f} s", flush=True)
    return result.returncode, result.stdout


def run_arm(arm: str, descriptions: pathlib.Path, out: pathlib.Path, quick: bool) -> dict:
    folder = out / arm
    folder.mkdir(parents=True, exist_ok=True)
    robot = robot_config(arm, descriptions, folder)
    steps: list = []
    row = dict(arm=arm, name=ARMS[arm]["name"], joints=len(ARMS[arm]["arm_joints"]))
    counts = ["--count", "8"] if quick else []
    training = ["--epochs", "20"] if quick else []
    excitation, ident, runs = folder / "excitation.h5", folder / "ident.h5", folder / "runs"
    command(steps, folder, "collect_excitation", "collect", "--protocol", "excitation", "--robot", robot, *counts,
            "--quiet", "-o", excitation)
    command(steps, folder, "inspect_excitation", "inspect", excitation)
    command(steps, folder, "collect_identification", "collect", "--robot", robot, "--controller",
            "stdm-drake:controllers/pid_dither_sized.yaml", "--sensor", "stdm-drake:controllers/sensor_ideal.yaml",
            *counts, "--quiet", "-o", ident)
    command(steps, folder, "inspect_identification", "inspect", ident)
    model = learned_model_type(robot)
    row["model"] = model
    derivative = (["--action-rate", "zero_order_hold", "--derivative-source", "true", "--alpha", "1e-3"]
                  if model == "DD" else [])   # (the alpha of docs/published_arms.md's runs)
    command(steps, folder, "train", "train", ident, "--robot", robot, "--model", model, *derivative, *training,
            "--quiet", "-o", runs)
    checkpoint = runs / "seed0" / "checkpoint.pt"
    command(steps, folder, "evaluate", "evaluate", checkpoint, ident, "--robot", robot, "--json", folder / "evaluate.json")
    command(steps, folder, "mpc", "mpc", ident, "--robot", robot, "--model", f"{model}={checkpoint}", "--plans", "3",
            "--quiet", "-o", folder / "mpc")
    _, view = command(steps, folder, "view", "view", checkpoint, ident, "--robot", robot, "--html", folder / "view.html")
    row["steps"] = steps
    row["failed_steps"] = [step["step"] for step in steps if step["status"] != 0]
    if (folder / "evaluate.json").is_file():
        evaluation = json.loads((folder / "evaluate.json").read_text())
        row["one_step_q_mse_rad2"] = evaluation["one_step"]["angle_mse"]
        row["one_step_v_mse"] = evaluation["one_step"]["velocity_mse"]
        for baseline in evaluation["baselines"]:
            key = re.sub(r"[^a-z]+", "_", baseline["name"].lower()).strip("_")
            row[f"{key}_q_mse_rad2"] = baseline["one_step"]["angle_mse"]
            row[f"{key}_v_mse"] = baseline["one_step"]["velocity_mse"]
        row["ratio_to_euler_q"] = evaluation["ratio_to_euler_q"]
        row["ratio_to_velocity_unchanged_v"] = evaluation["ratio_to_velocity_unchanged_v"]
        row["verdict"] = evaluation["verdict"]
    if (folder / "mpc" / "mpc.json").is_file():
        for summary in json.loads((folder / "mpc" / "mpc.json").read_text())["summary"]:
            prefix = "mpc_plant" if summary["model"] == "plant" else "mpc_learned"
            for key in ("q_mse_rad2", "limit_violations", "fallbacks", "solve_ms_mean"):
                row[f"{prefix}_{key}"] = summary[key]
            if prefix == "mpc_learned":
                row["mpc_learned_vs_plant"] = summary["q_mse_vs_plant"]
    row["view"] = [line for line in view.splitlines() if line.startswith("trajectory ")]
    return row


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--descriptions", type=pathlib.Path, required=True,
                        help="folder with the fetched descriptions (PROVENANCE.md's layout)")
    parser.add_argument("-o", "--output", type=pathlib.Path, required=True)
    parser.add_argument("--arms", default=",".join(ARMS), help=f"comma-separated subset of {', '.join(ARMS)}")
    parser.add_argument("--quick", action="store_true", help="8 trajectories, 20 epochs: a smoke run")


def run(args: argparse.Namespace) -> int:
    from stdm_drake.errors import InputError
    arms = args.arms.split(",")
    unknown = [arm for arm in arms if arm not in ARMS]
    if unknown:
        raise InputError(f"unknown arm {unknown[0]!r}; choose from {', '.join(ARMS)}")
    missing = [ARMS[arm]["model"] for arm in arms if not (args.descriptions / ARMS[arm]["model"]).is_file()]
    if missing:
        raise InputError(f"{args.descriptions / missing[0]} not found; fetch the descriptions as PROVENANCE.md says")
    rows = []
    for arm in arms:
        print(f"{arm}:", flush=True)
        rows.append(run_arm(arm, args.descriptions.resolve(), args.output.resolve(), args.quick))
    write_text_atomic(args.output / "summary.json", json.dumps(dict(written_by="tools/study.py published-arms", provenance=args.provenance, quick=args.quick, arms=rows), indent=1) + "\n")
    columns = list(dict.fromkeys(key for row in rows for key in row if key not in ("steps", "view", "failed_steps")))
    flat = [{key: row.get(key, "") for key in columns} | dict(failed_steps=" ".join(row["failed_steps"])) for row in rows]
    write_text_atomic(args.output / "summary.csv", rows_csv(flat, columns + ["failed_steps"]))
    failed = [row["arm"] for row in rows if row["failed_steps"] or row.get("verdict") != "learned"
              or row.get("mpc_learned_limit_violations") or row.get("mpc_plant_limit_violations")
              or row.get("mpc_learned_fallbacks") or row.get("mpc_plant_fallbacks")]
    print(f"wrote {args.output}/summary.json, summary.csv; " + (f"failed: {', '.join(failed)}" if failed else "all passed"))
    return 1 if failed else 0

