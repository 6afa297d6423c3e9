"""Robot corpus: every arm of two public description packages, as shipped, through init, data, training and MPC (issue 42).

    python tools/study.py robot-corpus [-o docs/results/robot_corpus] [--work out/robot_corpus] [--only NAME ...]

The corpus: every .urdf and .sdf file of the wheels `pybullet` (its pybullet_data folder) and `rtb-data`
(the Robotics Toolbox for Python's data), as installed. A file is an arm when `robot init`'s rule finds a
chain of at least two movable joints from its root (`robots.starting_config.arm_chain`); the others
(objects, wheeled and legged robots, single links, xacro sources) are listed as not arms, with the
reason. Each arm goes through the commands a user would run, each its own process, on defaults:

1. `robot init FILE` (the starting YAML, checked: `robot check`), with `--masses-from-geometry` for a URDF
   that states no <inertial> at all (a kinematic description: issue 58), the YAML untouched either way;
2. `collect --protocol excitation` (12 trajectories);
3. arms of 6 or more joints: `collect --protocol tracking` (12 tracked plans), and the tracking quality
   per joint: MSE of the true joint angle against the plan (rad²) and the largest |q̈| against the plan's;
   for an arm with joint damping, the same plans again under Drake's own damping compensation on the
   measured velocity (`damping_compensation: measured`, the controller's former behaviour);
4. `train` on the excitation data (one seed, 20 epochs: a smoke run of the chain, not a model to use);
5. `mpc` on one held-out plan, the plant as model beside the learned model (arms under 6 joints: an
   excitation reference).

A stage passes when its command exits 0; `mpc` passes when the plant-as-model MPC keeps the limits (the
20-epoch model's own result is recorded, not judged). The first stage that fails gives the arm's one-line
reason: the command's last error line. Results: OUT/corpus.csv and OUT/corpus.json (one row per file), and
OUT/summary.json (counts, the share of arms of 6 or more joints that pass every stage, and the tracking MSE
of the damped arms against the undamped).
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import pathlib
import re
import subprocess
import sys
import time

import numpy as np

from stdm_drake.files import rows_csv, write_text_atomic

PACKAGES = ("pybullet_data", "rtbdata")   # the wheels pybullet and rtb-data
STAGES = ("init", "excitation", "tracking", "train", "mpc")
TRACKING_MIN_JOINTS = 6


def corpus_files() -> list[tuple[str, pathlib.Path]]:
    """(label PACKAGE/RELATIVE/PATH, path) of every .urdf and .sdf file of the corpus packages, sorted."""
    files = []
    for package in PACKAGES:
        spec = importlib.util.find_spec(package)
        if spec is None or not spec.submodule_search_locations:
            raise SystemExit(f"robot-corpus: package {package} is not installed (pip install pybullet rtb-data)")
        root = pathlib.Path(list(spec.submodule_search_locations)[0])
        for path in sorted(list(root.rglob("*.urdf")) + list(root.rglob("*.sdf"))):
            files.append((f"{package}/{path.relative_to(root)}", path))
    return files


def classify(path: pathlib.Path) -> tuple[list | None, str]:
    """(the arm joints `robot init` would choose, "") for an arm; (None, why not) for another file."""
    from stdm_drake.errors import InputError
    from stdm_drake.robots.description import check_tree, read_description
    from stdm_drake.robots.model_file import joint_facts
    from stdm_drake.robots.starting_config import arm_chain
    try:
        description = read_description(path)
        check_tree(description, path.name)
        chain = arm_chain(description, joint_facts(path)[2])
    except InputError as error:
        return None, str(error)
    if len(chain.arm_joints) < 2:
        return None, f"one movable joint on its chain ({chain.arm_joints[0]})"
    return chain.arm_joints, ""


def stdm_drake(folder: pathlib.Path, label: str, *arguments) -> tuple[int, str]:
    """Run `stdm-drake ARGUMENTS` as its own process, its output in folder/LABEL.log: (exit status, the last
    line of its standard error that says what went wrong, else "")."""
    result = subprocess.run([sys.executable, "-m", "stdm_drake.cli", *map(str, arguments)], capture_output=True,
                            text=True, env=dict(os.environ, DRAKE_ALLOW_NETWORK="meshcat"), cwd=folder)
    write_text_atomic(folder / f"{label}.log", result.stdout + result.stderr)
    lines = [line for line in result.stderr.splitlines() if "error" in line or "does not pass" in line
             or line.startswith("Traceback") or "Error:" in line]
    # (the reason itself: without `robot init`'s prefix, which names this machine's work folder)
    return result.returncode, re.sub(r"^stdm-drake robot init: .* does not pass its check yet: ", "",
                                     lines[-1] if lines else "")


def tracking_quality(dataset_path: pathlib.Path) -> dict:
    """Per joint over every tracked plan of a tracking dataset: MSE of q_true against q_planned (rad²), the
    largest |qdd| (true) and |qdd_planned| (rad/s²)."""
    from stdm_drake.collection.collect import tracking_mse
    from stdm_drake.data.dataset import load_dataset
    dataset = load_dataset(dataset_path)
    trajectories = [dataset.trajectory(index) for index in range(dataset.num_trajectories)]
    mse = tracking_mse(trajectories)   # (every joint has as many steps: their mean is the overall MSE)
    return dict(tracking_mse_rad2=float(np.mean(mse)), tracking_mse_worst_joint_rad2=float(np.max(mse)),
                qdd_max=float(max(np.abs(traj.qdd).max() for traj in trajectories)),
                qdd_planned_max=float(max(np.abs(traj.qdd_planned).max() for traj in trajectories)))


def run_arm(label: str, path: pathlib.Path, joints: list, work: pathlib.Path) -> dict:
    """Every stage of one arm (module docstring); its row."""
    folder = work / label.replace("/", "__").rsplit(".", 1)[0]
    folder.mkdir(parents=True, exist_ok=True)
    for stale in folder.iterdir():   # (a rerun starts clean: the commands refuse to write over their outputs)
        if stale.is_file():
            stale.unlink()
        else:
            import shutil
            shutil.rmtree(stale)
    row = dict(file=label, joints=len(joints), arm_joints=" ".join(joints), passed="", failed_stage="", reason="")
    robot = folder / "robot.yaml"
    tracks = len(joints) >= TRACKING_MIN_JOINTS
    started = time.perf_counter()
    kinematic = is_kinematic(path)
    row["masses_from_geometry"] = kinematic
    steps = [("init", ("robot", "init", path, "-o", robot, *(("--masses-from-geometry",) if kinematic else ()))),
             ("excitation", ("collect", "--robot", robot, "--protocol", "excitation", "--count", "12", "--quiet",
                             "-o", "excitation.h5"))]
    if tracks:
        steps.append(("tracking", ("collect", "--robot", robot, "--protocol", "tracking", "--count", "12", "--quiet",
                                   "-o", "tracking.h5")))
    steps.append(("train", ("train", "excitation.h5", "--robot", robot, "--epochs", "20", "--seeds", "0", "--quiet",
                            "-o", "model")))
    references = ("tracking.h5",) if tracks else ("excitation.h5", "--excitation-references")
    steps.append(("mpc", ("mpc", *references, "--robot", robot, "--model", "D=model/seed0/checkpoint.pt", "--plans",
                          "1", "--quiet", "-o", "mpc")))
    passed = []
    for stage, arguments in steps:
        status, reason = stdm_drake(folder, stage, *arguments)
        if stage == "mpc" and (folder / "mpc" / "mpc.json").is_file():
            summary = {entry["model"]: entry for entry in json.loads((folder / "mpc" / "mpc.json").read_text())["summary"]}
            plant, learned = summary.get("plant", {}), summary.get("D", {})
            row.update(mpc_plant_q_mse_rad2=plant.get("q_mse_rad2"), mpc_plant_limit_violations=plant.get("limit_violations"),
                       mpc_learned_q_mse_rad2=learned.get("q_mse_rad2"),
                       mpc_learned_limit_violations=learned.get("limit_violations"))
            status = 0 if plant and plant.get("limit_violations") == 0 else 1
            reason = reason if status else ""
            reason = reason or ("" if status == 0 else "the plant-as-model MPC left the limits")
        if stage == "init" and status == 0 and kinematic:
            row["geometry_mass_kg"] = geometry_mass(folder)
        if stage == "tracking" and status == 0:
            row.update(tracking_quality(folder / "tracking.h5"))
            if _damping(path, joints) > 0:
                row.update(measured_damping_tracking(folder, robot))
        if status != 0:
            row.update(failed_stage=stage, reason=reason or f"exit status {status}")
            break
        passed.append(stage)
    row["passed"] = " ".join(passed)
    row["passed_all"] = not row["failed_stage"]
    row["seconds"] = round(time.perf_counter() - started, 1)
    damping = _damping(path, joints)
    row["max_damping"] = damping
    return row


def geometry_mass(folder: pathlib.Path) -> float:
    """The total mass (kg) `robot init --masses-from-geometry` gave a kinematic arm: the sum of the <mass> values
    of the description's copy it wrote beside the YAML (NAME_masses.urdf)."""
    from stdm_drake.robots.xml_file import parse
    (copy,) = folder.glob("*_masses.urdf")
    return round(sum(float(mass.get("value")) for mass in parse(copy).iter("mass")), 3)


def is_kinematic(path: pathlib.Path) -> bool:
    """A URDF that states no <inertial> on any link: no dynamics of its own (`robot init --masses-from-geometry`)."""
    import xml.etree.ElementTree as ElementTree
    if path.suffix.lower() != ".urdf":
        return False
    try:
        root = ElementTree.parse(path).getroot()
    except ElementTree.ParseError:   # (robot init says why, in its one line)
        return False
    return root.find("link") is not None and root.find("link/inertial") is None


def measured_damping_tracking(folder: pathlib.Path, robot: pathlib.Path) -> dict:
    """The same tracked plans (seed, count) under the default controller with Drake's own damping compensation
    on the measured velocity (`damping_compensation: measured`, the former behaviour): its tracking quality,
    keys prefixed measured_damping_."""
    from stdm_drake.paths import shipped_file
    controller = folder / "controller_measured_damping.yaml"
    text = shipped_file("stdm-drake:controllers/inverse_dynamics.yaml").read_text()
    write_text_atomic(controller, text.rstrip() + "\n  damping_compensation: measured\n")
    status, _ = stdm_drake(folder, "tracking_measured_damping", "collect", "--robot", robot, "--protocol", "tracking",
                           "--controller", controller, "--count", "12", "--quiet", "-o", "tracking_measured_damping.h5")
    if status != 0:
        return dict(measured_damping_status=status)
    return {f"measured_damping_{key}": value
            for key, value in tracking_quality(folder / "tracking_measured_damping.h5").items()}


def _damping(path: pathlib.Path, joints: list) -> float:
    """The largest <dynamics damping> of the arm joints in the file (N m s/rad), 0 without."""
    import xml.etree.ElementTree as ElementTree
    values = [0.0]
    for joint in ElementTree.parse(path).getroot().iter("joint"):
        dynamics = joint.find("dynamics")
        if joint.get("name") in joints and dynamics is not None and dynamics.get("damping"):
            values.append(float(dynamics.get("damping")))
    return max(values)


def summary(rows: list) -> dict:
    """Counts and the issue's two goals from the per-file rows."""
    arms = [row for row in rows if row.get("joints")]
    big = [row for row in arms if row["joints"] >= TRACKING_MIN_JOINTS]
    tracked = [row for row in big if row.get("tracking_mse_rad2") is not None]
    damped = [row["tracking_mse_rad2"] for row in tracked if row["max_damping"] > 0]
    undamped = [row["tracking_mse_rad2"] for row in tracked if row["max_damping"] == 0]
    measured = [row["measured_damping_tracking_mse_rad2"] for row in tracked
                if row.get("measured_damping_tracking_mse_rad2") is not None]
    kinematic = [row for row in big if row.get("masses_from_geometry")]
    massive = [row for row in big if not row.get("masses_from_geometry")]
    return dict(files=len(rows), arms=len(arms),
                arms_6_plus_with_masses=len(massive), arms_6_plus_with_masses_passing=sum(row["passed_all"] for row in massive),
                arms_6_plus_kinematic=len(kinematic), arms_6_plus_kinematic_passing=sum(row["passed_all"] for row in kinematic),
                tracking_mse_damped_measured_compensation_median=float(np.median(measured)) if measured else None, arms_passing=sum(row["passed_all"] for row in arms),
                arms_6_plus=len(big), arms_6_plus_passing=sum(row["passed_all"] for row in big),
                share_6_plus_passing=(sum(row["passed_all"] for row in big) / len(big)) if big else None,
                tracking_mse_damped_median=float(np.median(damped)) if damped else None,
                tracking_mse_undamped_median=float(np.median(undamped)) if undamped else None,
                damped_over_undamped=(float(np.median(damped) / np.median(undamped)) if damped and undamped else None),
                failures={row["file"]: f"{row['failed_stage']}: {row['reason']}" for row in arms if not row["passed_all"]})


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-o", "--output", type=pathlib.Path,
                        help="results folder (default: docs/results/robot_corpus; required with --only, so that a "
                             "subset never replaces the committed results)")
    parser.add_argument("--work", type=pathlib.Path, default=pathlib.Path("out/robot_corpus"),
                        help="per-arm folders: robot.yaml, datasets, models, logs")
    parser.add_argument("--only", nargs="+", default=[], help="files whose label contains one of these words")


def run(args: argparse.Namespace) -> int:
    from stdm_drake.errors import InputError
    if args.only and args.output is None:
        raise InputError("--only needs -o: a subset's results never replace docs/results/robot_corpus")
    args.output = args.output or pathlib.Path("docs/results/robot_corpus")
    rows = []
    for label, path in corpus_files():
        if args.only and not any(word in label for word in args.only):
            continue
        joints, why = classify(path)
        if joints is None:
            rows.append(dict(file=label, joints=0, reason=f"not an arm: {why}"))
            continue
        row = run_arm(label, path, joints, args.work.resolve())
        print(f"{label}: {len(joints)} joints, " + ("passes" if row["passed_all"] else
              f"fails at {row['failed_stage']}: {row['reason']}") + f" ({row['seconds']:.0f} s)", flush=True)
        rows.append(row)
    args.output.mkdir(parents=True, exist_ok=True)
    result = dict(written_by="tools/study.py robot-corpus", provenance=args.provenance, summary=summary(rows), rows=rows)
    write_text_atomic(args.output / "corpus.json", json.dumps(result, indent=1) + "\n")
    columns = list(dict.fromkeys(key for row in rows for key in row))
    write_text_atomic(args.output / "corpus.csv", rows_csv([{key: row.get(key, "") for key in columns} for row in rows],
                                                          columns))
    print(json.dumps(result["summary"], indent=1))
    return 0
