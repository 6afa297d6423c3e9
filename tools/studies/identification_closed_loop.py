"""The identification study's closed loop (docs/identification.md, run 3): tuned MPC on the affected plant with
the nominal plant, the true plant (an oracle), the identified robot and every seed of the learned models (D and
the grey box G-id-state), each prediction model's setting chosen on the validation plans; does the grey box
track with the lowest error of all models a user has? `run_closed_loop` runs it, `write_closed_loop` writes
closed_loop.json and .md (`python tools/study.py identification --part closed`)."""
import pathlib

import numpy as np

from studies.identification_boxes import grey_box_folders, in_data, interval_text
from stdm_drake.robots.robot import Robot

# the closed loop's question (issue 23): does this model track with the lowest error of all models a user has
CLOSED_LOOP_TARGET = "G-id-state"


def run_closed_loop(profile: dict, folder: pathlib.Path, robot: Robot, white_box: dict, workers: int = 2,
                    say=print) -> dict:
    """The tuned closed loop (docs/identification.md, run 3) on each sensor's data at the largest grey size:
    MPC with the nominal plant, the true plant (an oracle), the identified robot and every seed of the
    profile's closed_loop_models, on the affected plant the dataset records (the MPC sees the plant's state);
    each prediction model's setting chosen from closed_loop_grid on the validation plans
    (`tuning.best_setting`), then the test plans with it. Per sensor: every run, the chosen settings and
    `closed_loop_summary`."""
    import time
    from stdm_drake.cluster import RunnerConfig, job_pool
    from studies.reality_gap import choose_settings, closed_loop_group
    started = time.perf_counter()
    size, seeds, grid = max(profile["grey_sizes"]), profile["seeds"], tuple(map(tuple, profile["closed_loop_grid"]))
    names = tuple(dict.fromkeys(["D", *profile["closed_loop_models"]]))
    folders = grey_box_folders(profile, folder, robot, white_box, names, (size,), workers)
    specs = {sensor: [("plant", None), ("true-plant", "true"),
                      ("identified", in_data(folder, white_box["identified_files"][sensor][str(size)]))]
             + [(f"{name} seed {seed}", str(pathlib.Path(folders[(sensor, name, size)]) / f"seed{seed}" / "checkpoint.pt"))
                for name in names for seed in range(seeds)] for sensor in white_box["datasets"]}
    splits = {sensor: str(pathlib.Path(folders[(sensor, "D", size)]) / "seed0" / "checkpoint.pt")
              for sensor in white_box["datasets"]}   # every model here has this split (same data, sizes, seed)
    steps = profile["closed_loop_steps"]

    def group(pool, sensor, spec, split, setting):
        return pool.submit(closed_loop_group, [spec], in_data(folder, white_box["datasets"][sensor]["path"]), splits[sensor], split,
                           steps, setting, robot)

    runner = RunnerConfig(workers=workers)
    with job_pool(runner) as pool:   # tuning: validation plans only
        futures = [(sensor, group(pool, sensor, spec, "val", setting)) for sensor in specs for spec in specs[sensor]
                   for setting in grid]
        tuning = [dict(row, sensor=sensor) for sensor, future in futures for row in future.result()]
    chosen = {sensor: choose_settings([run for run in tuning if run["sensor"] == sensor], grid) for sensor in specs}
    say(f"closed loop: settings chosen on the validation plans in {time.perf_counter() - started:.0f} s")
    with job_pool(runner) as pool:   # then the test plans, every choice made
        futures = [(sensor, group(pool, sensor, spec, "test", chosen[sensor][spec[0]])) for sensor in specs
                   for spec in specs[sensor]]
        runs = [dict(row, sensor=sensor) for sensor, future in futures for row in future.result()]
    sensors = {}
    for sensor in specs:
        mine = [run for run in runs if run["sensor"] == sensor]
        rows = closed_loop_summary(mine, names, seeds)
        sensors[sensor] = dict(chosen={name: list(setting) for name, setting in chosen[sensor].items()}, rows=rows,
                               verdict=closed_loop_verdict(rows), runs=mine,
                               tuning_runs=[run for run in tuning if run["sensor"] == sensor])
        say(f"closed loop, {sensor} sensor: " + "; ".join(f"{row['model']} q MSE {row['q_mse']:.3g}"
                                                          for row in sensors[sensor]["rows"]))
    return dict(train_per_pose=size, seeds=seeds, grid=[list(setting) for setting in grid], steps=steps,
                target=CLOSED_LOOP_TARGET, sensors=sensors, seconds=round(time.perf_counter() - started, 1))


def closed_loop_summary(runs: list, names, seeds: int, target: str = CLOSED_LOOP_TARGET) -> list:
    """Per model (the plants, "identified", each learned type over its seeds): the geometric-mean q MSE over
    its test runs, limit violations, fallbacks, solve time; and the ratio (other model's q MSE / the target's)
    paired by test plan within a seed, a geometric mean per seed, with a Student-t 95 % interval over the
    target's seeds (a learned model paired seed with seed; above 1: the target tracks better)."""
    import math
    from stdm_drake.closed_loop.tuning import finite_mse
    from studies.reality_gap import seed_interval
    labels = ["plant", "true-plant", "identified", *names]

    def members(label):
        return [run for run in runs if run["model"] == label or run["model"].startswith(f"{label} seed ")]

    def per_plan(model_runs):
        return {run["trajectory"]: math.log(finite_mse(run["q_mse_rad2"])) for run in model_runs}

    target_seeds = [per_plan([run for run in runs if run["model"] == f"{target} seed {seed}"]) for seed in range(seeds)]
    rows = []
    for label in labels:
        mine = members(label)
        if not mine:
            continue
        row = dict(model=label, runs=len(mine), q_mse=float(np.exp(np.mean([math.log(finite_mse(run["q_mse_rad2"]))
                                                                           for run in mine]))),
                   diverged=sum(not math.isfinite(run["q_mse_rad2"]) for run in mine),
                   limit_violations=int(sum(run["limit_violations"] for run in mine)),
                   fallbacks=int(sum(run["fallbacks"] for run in mine)),
                   solve_ms_mean=float(np.mean([run["solve_ms_mean"] for run in mine])))
        if label != target and all(target_seeds):
            logs = []
            for seed, target_logs in enumerate(target_seeds):
                other = per_plan([run for run in mine if run["model"] in (label, f"{label} seed {seed}")])
                logs.append(float(np.mean([other[plan] - target_logs[plan] for plan in target_logs])))
            row["model_over_target"] = seed_interval(logs)
        rows.append(row)
    return rows


def closed_loop_verdict(rows: list, target: str = CLOSED_LOOP_TARGET) -> dict:
    """Issue 23's closed-loop goal: the target tracks with the lowest error of all models a user has (every
    other model's ratio to it, the oracle true plant aside, with its interval above 1) and no limit violation."""
    others = [row for row in rows if "model_over_target" in row and row["model"] != "true-plant"]
    mine = next((row for row in rows if row["model"] == target), None)
    if mine is None or not others:
        return dict(met=False, text=f"{target} or the models to compare it with were not run")
    undecided = [row["model"] for row in others if row["model_over_target"]["low"] is None]
    if undecided:
        return dict(met=False, text=f"one seed: no interval for {', '.join(undecided)}; goal not decided")
    below = [row["model"] for row in others if row["model_over_target"]["low"] <= 1]
    met = not below and mine["limit_violations"] == 0
    text = (f"{target} tracks with the lowest error of all models" if met else
            f"not met: {target}'s error is not below {', '.join(below)}'s (interval reaches 1 or below)" if below else
            f"not met: {target}'s closed loops left the limits ({mine['limit_violations']} steps)")
    return dict(met=met, text=text, not_below=below, limit_violations=mine["limit_violations"])


CLOSED_LOOP_HEADER = ["model", "test runs", "q MSE (rad²)", "model / target [95 % CI]", "steps outside the limits",
                      "fallbacks", "solve ms / step", "MPC setting (effort scale, observer gain)"]


def closed_loop_rows(result: dict) -> list:
    """One sensor's closed-loop table rows (CLOSED_LOOP_HEADER)."""
    rows = []
    for row in result["rows"]:
        ratio = row.get("model_over_target")
        settings = sorted({tuple(setting) for name, setting in result["chosen"].items()
                           if name == row["model"] or name.startswith(f"{row['model']} seed ")})
        rows.append([row["model"], row["runs"], f"{row['q_mse']:.3g}",
                     "-" if ratio is None else interval_text(dict(ratio, pairs=ratio["seeds"])),
                     row["limit_violations"], row["fallbacks"], f"{row['solve_ms_mean']:.1f}",
                     " ".join(f"({scale:g}, {gain:g})" for scale, gain in settings)])
    return rows


def closed_loop_table(closed: dict) -> str:
    """Per sensor, the closed-loop table in Markdown with the goal's verdict."""
    from stdm_drake.report import markdown_table
    lines = []
    for sensor, result in closed["sensors"].items():
        lines += [f"{sensor} sensor's models, {closed['train_per_pose']} training plans per pose, tuned MPC on the "
                  f"test plans, {closed['seeds']} seeds per learned type (target {closed['target']}):", "",
                  markdown_table(CLOSED_LOOP_HEADER, closed_loop_rows(result)), "",
                  f"Verdict: {result['verdict']['text']}.", ""]
    return "\n".join(lines)


def write_closed_loop(closed: dict, out: pathlib.Path, quick: bool, origin: dict, stem: str = "closed_loop") -> dict:
    """The closed loop's files in `out`: {stem}.json (every run, the choices, the summary and verdict per sensor)
    and {stem}.md; returns what the JSON holds."""
    import json
    from stdm_drake.files import json_default, write_text_atomic
    closed = dict(written_by="tools/study.py identification", provenance=origin, quick=quick, **closed)
    write_text_atomic(out / f"{stem}.json", json.dumps(closed, indent=1, default=json_default) + "\n")
    write_text_atomic(out / f"{stem}.md", closed_loop_table(closed) + "\n")
    return closed
