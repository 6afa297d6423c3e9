"""The identification study's white and grey boxes (tools/studies/identification.py runs them; its docstring and
docs/identification.md say what each part does): the profiles, the affected plant's datasets, the white box's
identified robots and their errors (`run_study`), the grey and black boxes trained on the same plans
(`run_grey_box`), and their tables and files. The closed-loop part (`identification_closed_loop`) builds on them."""
import json
import pathlib

import numpy as np

from stdm_drake.robots.robot import Robot

# plans per start pose: training sizes, validation, test; smoothing windows searched (None: identify's); the
# learned models' seeds and epochs (the UR-10's 4 start poses: 100 plans, and 12 with QUICK)
# grey_sizes: the learned models' training sizes (plans per pose; each grey box on the robot identified from the
# same plans); closed_loop: the models in the tuned closed loop (at the largest size) and the MPC settings
# (effort-weight scale, observer gain) each prediction model chooses from on the validation plans (run 3)
FULL = dict(train_sizes=(5, 10, 18), val=2, test=5, windows=None, seeds=5, epochs=300, runs=("A", "B", "C"),
            grey_models=("D", "DD", "G-id-state", "GD-id-state"), grey_sizes=(5, 10, 18),
            closed_loop_models=("D", "G-id-state"), closed_loop_grid=((1e-4, 0.0), (1e-4, 0.3), (1e-4, 1.0)),
            closed_loop_steps=None)
QUICK = dict(train_sizes=(1,), val=1, test=1, windows=(9,), seeds=2, epochs=3, runs=("A", "C"),
             grey_models=("D", "G-id-state"), grey_sizes=(1,), closed_loop_models=("D", "G-id-state"),
             closed_loop_grid=((1e-4, 1.0),), closed_loop_steps=8)
# the grey-box comparison: name -> (train --model, the grey box's physics: None or "identified")
GREY_BOX_MODELS = {"D": ("D", None, "velocity"), "DD": ("DD", None, "velocity"), "G": ("G", None, "velocity"),
                   "G-id": ("G", "identified", "velocity"), "GD-id": ("GD", "identified", "velocity"),
                   # run 2 (docs/identification.md): the delta on the plant's whole next state (predicts "state":
                   # the plant's own q̂ kept, no trapezoid rule), since then `train --model G`'s default
                   "G-id-state": ("G", "identified", "state"), "GD-id-state": ("GD", "identified", "state")}
DATA_SEED = 1            # the amendment's fresh data (seed 0 was the development data)
RUNS = {"A": ("ideal", "true"), "B": ("ideal", "smoothed"), "C": ("paper", "smoothed")}
SENSORS = {"ideal": "sensor_ideal.yaml", "paper": "sensor.yaml"}
ROLLOUT_STEPS = 20


def dataset(folder: pathlib.Path, sensor: str, effects, plans: int, robot: Robot, workers: int = 2):
    """The affected plant's tracking data (dithered PID sized from its inertia) with `sensor`, reused when
    collected with the same settings."""
    from stdm_drake.experiments.jobs import ensure_dataset
    from studies.reality_gap import COLLECTION_CONTROLLER
    from stdm_drake.paths import CONTROLLERS_DIR
    return ensure_dataset("tracking", plans, DATA_SEED, folder, progress=False, name=f"identification_{sensor}",
                          robot=robot, plant_effects=effects, workers=workers,
                          controller=CONTROLLERS_DIR / COLLECTION_CONTROLLER, sensor=CONTROLLERS_DIR / SENSORS[sensor])


def model_errors(identified, data, robot: Robot, split) -> list[dict]:
    """One-step and ROLLOUT_STEPS-step q and v MSE on the test plans of the identified model, the Euler
    step, "stays put" and the nominal plant; the identified model's verdict against the physics-free
    baselines and the sensor's noise floor (as `evaluate` gives it)."""
    from stdm_drake.data.inspect import noise_floor
    from stdm_drake.learning.evaluate import compare_with_baselines, physics_baselines, trajectory_rollout_data
    model = identified.model(robot)
    baselines = physics_baselines(data.sample_period, robot.state_dim, robot.action_dim, robot=robot)
    rows = compare_with_baselines([model] + baselines, data.transitions(split.test),
                                  trajectory_rollout_data(data, split.test, ROLLOUT_STEPS),
                                  noise_floor=noise_floor(data, split.test))
    return [dict(model=row.name, one_step_q=row.one_step.angle_mse, one_step_v=row.one_step.velocity_mse,
                 q_at_20=float(row.multi_step.angle_mse[ROLLOUT_STEPS - 1]), verdict=row.verdict) for row in rows]


def run_study(profile: dict, folder: pathlib.Path, robot: Robot, effects, workers: int = 2, say=print) -> dict:
    """Every run of the study: a summary row per (run, training size), the identify reports, the model
    errors of A and C at the largest size."""
    from stdm_drake.data.dataset import split_trajectories
    from stdm_drake.identification.identify import IdentifySettings, identify
    from studies.reality_gap import start_poses
    folder.mkdir(parents=True, exist_ok=True)
    plans = start_poses(robot) * (max(profile["train_sizes"]) + profile["val"] + profile["test"])
    datasets = {sensor: dataset(folder, sensor, effects, plans, robot, workers) for sensor in SENSORS}
    rows, reports, errors, identified_files = [], {}, {}, {}
    largest = max(profile["train_sizes"])
    for run in profile["runs"]:
        sensor, source = RUNS[run]
        data = datasets[sensor]
        settings = IdentifySettings(derivative_source=source)
        if profile["windows"]:
            settings.windows = profile["windows"]
        for size in profile["train_sizes"]:
            split = split_trajectories(data.groups, size, profile["val"], profile["test"], seed=0, per_group=True)
            identified, report = identify(data, robot, split, settings)
            truth = report["truth"]["joints"]
            row = dict(run=run, sensor=sensor, derivatives=source, train_per_pose=size,
                       train_plans=len(split.train), samples=report["samples_train"],
                       condition_number=report["least_squares"]["condition_number"],
                       velocity_scale=report["chosen"]["velocity_scale"],
                       regularization=report["chosen"]["regularization"],
                       window=report["smoothing_window"],
                       torque_error=report["test"]["torque_error"],
                       least_squares_torque_error=report["test"]["least_squares_torque_error"],
                       description_torque_error=report["test"]["description_torque_error"],
                       torque_error_on_true_states=report["test"].get("torque_error_on_true_states",
                                                                      report["test"]["torque_error"]),
                       worst_viscous_error=_worst(truth["viscous"]["relative_error"]),
                       worst_coulomb_error=_worst(truth["coulomb"]["relative_error"]))
            rows.append(row)
            reports[f"{run}_train{size}"] = report
            say(f"{run} ({sensor} sensor, {source} derivatives), {size} plans per pose: torque error "
                f"{row['torque_error']:.3g} (description {row['description_torque_error']:.3g}), friction within "
                f"{row['worst_viscous_error']:.3g} (viscous) / {row['worst_coulomb_error']:.3g} (Coulomb)")
            if run in ("A", "C"):   # the grey boxes' physics at each size (run A's robot for the ideal sensor)
                identified_files.setdefault(sensor, {})[str(size)] = _write_identified(
                    folder / f"identified_{sensor}_train{size}.yaml", identified).name
                if size == largest:
                    errors[run] = model_errors(identified, data, robot, split)
    return dict(rows=rows, reports=reports, model_errors=errors, profile={k: v for k, v in profile.items()},
                data_seed=DATA_SEED, datasets={sensor: dict(path=pathlib.Path(d.path).name, sha256=d.sha256)
                                               for sensor, d in datasets.items()},
                identified_files=identified_files)


def in_data(folder: pathlib.Path, recorded: str) -> str:
    """A file the white box's results name (a dataset, an identified robot) in the data folder `folder`: the
    results hold its name (no folder of the machine that ran them; older results: a path, of which the name)."""
    return str(pathlib.Path(folder) / pathlib.PurePath(recorded).name)


def _write_identified(path: pathlib.Path, identified) -> pathlib.Path:
    """The identified robot's file (what a grey box's --physics names), written only when it changed."""
    from stdm_drake.files import write_text_atomic
    from stdm_drake.identification.identified import identified_text
    text = identified_text(identified)
    if not path.exists() or path.read_text() != text:
        write_text_atomic(path, text)
    return path


def grey_box_folders(profile: dict, folder: pathlib.Path, robot: Robot, white_box: dict, names, sizes,
                     workers: int = 2) -> dict:
    """The run folders of the models `names` (GREY_BOX_MODELS) on each sensor's data at each training size in
    `sizes` (plans per pose), trained in a pool of `workers` processes (`reality_gap.train`: a finished folder is
    reused, an interrupted one resumed); a grey box's physics is the robot identified from the same training
    plans (`white_box`: run_study's results). Returns {(sensor, name, size): folder}."""
    from stdm_drake.cluster import RunnerConfig, job_pool
    from stdm_drake.errors import InputError
    from studies.reality_gap import train
    config = None if robot.config_path is None else str(robot.config_path)
    jobs = {}
    for sensor, data in white_box["datasets"].items():
        for size in sizes:
            identified = white_box["identified_files"][sensor].get(str(size))
            identified = identified and in_data(folder, identified)
            if identified is None:
                raise InputError(f"identification study: no robot identified from {size} plans per pose on the "
                                 f"{sensor} sensor's data (the white box ran at {profile['train_sizes']})")
            for name in names:
                model_type, physics, predicts = GREY_BOX_MODELS[name]
                jobs[(sensor, name, size)] = (in_data(folder, data["path"]), model_type, (size, profile["val"], profile["test"]),
                                              profile["seeds"], profile["epochs"], str(folder / "runs" / f"{sensor}_{name}"),
                                              config, identified if physics else None,
                                              predicts if model_type.startswith("G") else None)   # (D, DD: train's)
    with job_pool(RunnerConfig(workers=workers)) as pool:
        futures = {key: pool.submit(train, *call) for key, call in jobs.items()}
        return {key: future.result() for key, future in futures.items()}


def run_grey_box(profile: dict, folder: pathlib.Path, robot: Robot, white_box: dict, workers: int = 2,
                 say=print) -> dict:
    """The profile's grey_models on each sensor's data at each of its grey_sizes (checkpoints in `folder`/runs,
    reused by a rerun); per sensor, size and model type the test errors of every seed and each type's ratio to D
    at the same size (one-step and 20-step q MSE, paired by seed, 95 % interval); the robot identified from the
    same plans and the baselines beside them."""
    import time
    started = time.perf_counter()
    names = tuple(dict.fromkeys(["D", *profile["grey_models"]]))
    folders = grey_box_folders(profile, folder, robot, white_box, names, profile["grey_sizes"], workers)
    say(f"grey box: {len(folders)} model types and sizes trained in {time.perf_counter() - started:.0f} s")
    results = {}
    for sensor, data in white_box["datasets"].items():
        for size in profile["grey_sizes"]:
            found = grey_box_errors(in_data(folder, data["path"]), {name: folders[(sensor, name, size)] for name in names},
                                    profile["seeds"], robot, in_data(folder, white_box["identified_files"][sensor][str(size)]))
            results.setdefault(sensor, {})[str(size)] = found
            say(f"grey box, {sensor} sensor, {size} plans per pose: " + "; ".join(
                f"{row['model']} one step {row['one_step_q']:.3g}, q@20 {row['q_at_20']:.3g}" for row in found["rows"]))
    return dict(split_per_pose=[profile["val"], profile["test"]], train_sizes=list(profile["grey_sizes"]),
                seeds=profile["seeds"], epochs=profile["epochs"], sensors=results,
                seconds=round(time.perf_counter() - started, 1))


def grey_box_errors(dataset_path: str, folders: dict, seeds: int, robot: Robot, identified_file: str) -> dict:
    """Test errors (one-step q and v MSE, q MSE at ROLLOUT_STEPS) of every seed of every type in `folders`,
    the identified robot and the baselines; per type the geometric mean over seeds and the ratio D / type
    paired by seed."""
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.data.inspect import noise_floor
    from stdm_drake.dynamics.model_files import load_model
    from stdm_drake.learning.evaluate import compare_with_baselines, physics_baselines, trajectory_rollout_data
    from stdm_drake.stats import paired_ratio
    data = load_dataset(dataset_path)
    learned = {name: [load_model(pathlib.Path(folder) / f"seed{seed}" / "checkpoint.pt", robot,
                                 name=f"{name} seed {seed}") for seed in range(seeds)]
               for name, folder in folders.items()}
    test = next(iter(learned.values()))[0].checkpoint.split_indices(data, "test")
    fixed = physics_baselines(data.sample_period, robot.state_dim, robot.action_dim, robot=robot)
    fixed.append(load_model(identified_file, robot))
    models = fixed + [model for group in learned.values() for model in group]
    rows = compare_with_baselines(models, data.transitions(list(test)),
                                  trajectory_rollout_data(data, test, ROLLOUT_STEPS), noise_floor=noise_floor(data, test))
    per_model = {row.name: dict(one_step_q=row.one_step.angle_mse, one_step_v=row.one_step.velocity_mse,
                                q_at_20=_diverged_as_large(float(row.multi_step.angle_mse[ROLLOUT_STEPS - 1])), verdict=row.verdict)
                 for row in rows}
    table = [dict(model=model.name, seeds=None, **per_model[model.name]) for model in fixed]
    for name, group in learned.items():
        values = [per_model[model.name] for model in group]
        entry = dict(model=name, seeds=len(group),
                     one_step_q=_geometric([value["one_step_q"] for value in values]),
                     one_step_v=_geometric([value["one_step_v"] for value in values]),
                     q_at_20=_geometric([value["q_at_20"] for value in values]),
                     verdict=", ".join(sorted({value["verdict"] for value in values})))
        for key in ("one_step_q", "q_at_20"):
            entry[f"d_over_model_{key}"] = paired_ratio([per_model[m.name][key] for m in learned["D"]],
                                                        [value[key] for value in values]).as_dict()
        table.append(entry)
    return dict(test_plans=[int(i) for i in test], rows=table, per_seed=per_model)


DIVERGED = 1e12      # rad²: the q MSE a diverged rollout (non-finite) counts as, so ratios stay defined


def _diverged_as_large(value: float) -> float:
    return value if np.isfinite(value) else DIVERGED


def _geometric(values) -> float:
    return float(np.exp(np.mean(np.log(np.asarray(values, dtype=float)))))


def _worst(errors: list) -> float:
    known = [error for error in errors if error is not None]
    return float(max(known)) if known else float("nan")


def summary_rows(results: dict) -> tuple[list, list]:
    """(header, rows) of the white box's table."""
    columns = ["run", "sensor", "derivatives", "train_per_pose", "condition_number", "window", "velocity_scale",
               "regularization", "torque_error", "least_squares_torque_error", "torque_error_on_true_states",
               "description_torque_error", "worst_viscous_error", "worst_coulomb_error"]
    return columns, [[_cell(row[column]) for column in columns] for row in results["rows"]]


def summary_table(results: dict) -> str:
    """The white box's rows as a Markdown table."""
    from stdm_drake.report import markdown_table
    return markdown_table(*summary_rows(results))


def _cell(value):
    if isinstance(value, float):
        return "-" if not np.isfinite(value) else f"{value:.3g}"
    return "-" if value is None else value


GREY_BOX_HEADER = ["model", "seeds", "one-step q MSE (rad²)", "one-step v MSE", f"q MSE at step {ROLLOUT_STEPS}",
                   "D / model, one step", f"D / model, step {ROLLOUT_STEPS}", "verdict"]


def grey_box_rows(result: dict) -> list:
    """One sensor's grey-box table rows (GREY_BOX_HEADER): every model's test errors (geometric mean over
    seeds) and each type's ratio to D."""
    rows = []
    for row in result["rows"]:
        ratios = [row.get(f"d_over_model_{key}") for key in ("one_step_q", "q_at_20")]
        rows.append([row["model"], row["seeds"] or "-", f"{row['one_step_q']:.3g}", f"{row['one_step_v']:.3g}",
                     f"{row['q_at_20']:.3g}"] + [interval_text(ratio) for ratio in ratios] + [row["verdict"] or "-"])
    return rows


def grey_box_table(grey: dict) -> str:
    """Per sensor and training size, the grey-box table in Markdown."""
    from stdm_drake.report import markdown_table
    lines = []
    for sensor, by_size in grey["sensors"].items():
        for size, result in by_size.items():
            lines += [f"{sensor} sensor, {size} training plans per pose, {len(result['test_plans'])} test plans, "
                      f"{grey['seeds']} seeds:", "", markdown_table(GREY_BOX_HEADER, grey_box_rows(result)), ""]
    return "\n".join(lines)


def interval_text(ratio) -> str:
    """e.g. "3.1x [2.2, 4.4]" (a ratio with its 95 % interval; "-" for none; one pair: no interval)."""
    if not ratio:
        return "-"
    if ratio["pairs"] < 2:
        return f"{ratio['ratio']:.3g}x"
    return f"{ratio['ratio']:.3g}x [{ratio['low']:.3g}, {ratio['high']:.3g}]"


def write_white_box(results: dict, out: pathlib.Path, quick: bool, origin: dict) -> dict:
    """The white box's files in `out`: reports/*.json (one identify report per run), results.json (the rows,
    model errors, datasets and identified files), summary.csv and summary.md; returns what results.json holds."""
    from stdm_drake.files import json_default, rows_csv, write_text_atomic
    results = dict(results)
    (out / "reports").mkdir(parents=True, exist_ok=True)
    for name, report in results.pop("reports").items():
        write_text_atomic(out / "reports" / f"{name}.json", json.dumps(report, indent=1, default=json_default) + "\n")
    results = dict(written_by="tools/study.py identification", provenance=origin, quick=quick, **results)
    write_text_atomic(out / "results.json", json.dumps(results, indent=1, default=json_default) + "\n")
    write_text_atomic(out / "summary.csv", rows_csv(results["rows"]))
    lines = [summary_table(results), ""]
    for run, rows in results["model_errors"].items():
        lines.append(f"Run {run}, test plans: one-step q / v MSE and q MSE at step {ROLLOUT_STEPS}")
        lines += [f"- {row['model']}: {row['one_step_q']:.3g} rad², {row['one_step_v']:.3g} (rad/s)², "
                  f"{row['q_at_20']:.3g} rad²" + (f" ({row['verdict']})" if row["verdict"] else "") for row in rows]
        lines.append("")
    write_text_atomic(out / "summary.md", "\n".join(lines))
    return results


def write_grey_box(grey: dict, out: pathlib.Path, quick: bool, origin: dict, stem: str = "grey_box") -> dict:
    """The grey box's files in `out`: {stem}.json and {stem}.md; returns what the JSON holds."""
    from stdm_drake.files import json_default, write_text_atomic
    grey = dict(written_by="tools/study.py identification", provenance=origin, quick=quick, **grey)
    write_text_atomic(out / f"{stem}.json", json.dumps(grey, indent=1, default=json_default) + "\n")
    write_text_atomic(out / f"{stem}.md", grey_box_table(grey) + "\n")
    return grey
