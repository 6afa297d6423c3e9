"""`stdm-drake compare`: which model for this robot, on its own data. For one dataset (simulated, or a log `import`
wrote) and its robot, it fits every model kind on the dataset's train split, rates each on the test split open loop
beside the physics baselines and, where the dataset's plant is simulated and has plans, in closed loop under the
same MPC, and ends with a recommendation by a rule stated here and in the guide ("Which model for your robot").

Model kinds, in order of cost (what each asks of a user and of the control step): the robot's description
("plant": the nominal model, no fitting), the identified robot (`identify`: link inertias and friction, physically
consistent), the grey box on it (G: a network's correction of the identified robot's step), and the learned models
D (the paper's naive MLP), DD (with the derivative loss) and PE (a probabilistic ensemble). Every stage writes into
the output folder and is reused by a rerun (resumable, as `reproduce`): the identified robot, each model's
checkpoints (`train --resume`), the closed loops (`mpc`'s folder), then the tables compare.md, compare.csv,
compare.html and compare.json.

The recommendation rule (`recommend`): a learned kind is a candidate only if every seed of it learned (beat the
physics-free baselines, `physics.learning_verdict`); the description and the identified robot always are. The
candidates are rated on the closed loops' tracking (RMS joint-angle error per plan, a kind's seeds averaged) where
there are closed loops, else on the open-loop error at the longest horizon (RMS per test trajectory). The best is
the candidate of the lowest mean; the recommendation is the cheapest candidate not shown worse than the best: the
paired differences to the best over the plans (trajectories) have a 95 % interval that reaches 0 or below. With
fewer than two units there is no interval: the best, marked inconclusive. A kind whose loops left the robot's
limits or fell back, or whose error is not finite on some unit (a diverged rollout), is no candidate.
"""
from __future__ import annotations

import csv
import dataclasses
import html
import io
import json
import pathlib
import sys

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.files import atomic_paths, finite_json, line_text, write_text_atomic
from stdm_drake.outputs import check_output_folder, mark_output_folder, FINISHED_RESULTS
from stdm_drake.dynamics.model_files import load_model, load_model_file
from stdm_drake.provenance import results_header

KINDS = ("plant", "identified", "G", "D", "DD", "PE")   # in order of cost
LEARNED_KINDS = ("G", "D", "DD", "PE")
DEFAULT_OUTPUT = pathlib.Path("out/compare")
HORIZONS = (1, 20, 100)   # open-loop steps reported (capped at the test trajectories' length)


@dataclasses.dataclass(frozen=True)
class CompareProfile:
    """Sizes of one comparison: seeds per learned kind, training epochs and patience, the network's hidden width
    and layers, the PE's members, closed-loop plans tracked and plans each model's MPC setting is tuned on."""
    name: str
    seeds: int = 3
    epochs: int = 300
    patience: int = 30
    hidden_width: int = 100
    hidden_layers: int = 3
    ensemble_size: int = 5
    plans: int = 5
    tune: int = 2


FULL = CompareProfile("full")
QUICK = CompareProfile("quick", seeds=1, epochs=30, patience=10, hidden_width=64, hidden_layers=2, ensemble_size=2,
                       plans=2, tune=0)


@dataclasses.dataclass
class CompareJob:
    """What one comparison needs. dataset: the .h5 file; robot: its config YAML (None: the shipped preset the
    dataset was collected with, else the UR-10's); output: the folder (None: `DEFAULT_OUTPUT`, or the first of
    out/compare-2, -3, ... without results); profile: QUICK or FULL; kinds: which of KINDS to compare; closed_loop:
    False leaves the closed loops out (a log has none anyway); progress: progress bars and stage lines on stderr;
    force: write into a folder stdm-drake did not write."""
    dataset: pathlib.Path
    robot: pathlib.Path | None = None
    output: pathlib.Path | None = None
    profile: CompareProfile = FULL
    kinds: tuple = KINDS
    closed_loop: bool = True
    progress: bool = True
    force: bool = False

    def validate(self) -> None:
        unknown = [kind for kind in self.kinds if kind not in KINDS]
        if unknown or not self.kinds or len(set(self.kinds)) != len(self.kinds):
            raise InputError(f"--kinds must be distinct names among {', '.join(KINDS)}, got {', '.join(self.kinds)}")
        if "G" in self.kinds and "identified" not in self.kinds:
            raise InputError("--kinds G is the grey box on the identified robot: list identified too")
        self.kinds = tuple(kind for kind in KINDS if kind in self.kinds)   # (in order of cost, however given)


def say(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def interval(differences) -> tuple[float, float, float] | None:
    """(mean, low, high) of the 95 % t-interval of paired differences (n,), None for fewer than two."""
    from scipy import stats
    values = np.asarray(differences, dtype=float)
    if len(values) < 2:
        return None
    mean, error = float(values.mean()), float(values.std(ddof=1) / np.sqrt(len(values)))
    half = float(stats.t.ppf(0.975, len(values) - 1)) * error
    return mean, mean - half, mean + half


def recommend(scores: dict, candidates: list[str]) -> dict:
    """The rule of the module docstring. scores: kind -> per-unit values (n,) (lower is better, the same units in
    the same order for every kind); candidates: the kinds that may be recommended, in order of cost. Returns
    {"kind", "best", "why", "intervals": kind -> (mean, low, high) of kind - best, "inconclusive"}."""
    if not candidates:
        return dict(kind=None, best=None, why="no kind qualifies", intervals={}, inconclusive=True)
    means = {kind: float(np.mean(scores[kind])) for kind in candidates}
    best = min(candidates, key=lambda kind: means[kind])
    intervals = {kind: interval(np.asarray(scores[kind]) - np.asarray(scores[best])) for kind in candidates
                 if kind != best}
    units = len(scores[best])
    if units < 2:
        return dict(kind=best, best=best, why=f"the lowest mean; one unit, so no interval (inconclusive)",
                    intervals=intervals, inconclusive=True)
    for kind in candidates:
        if kind == best or intervals[kind][1] <= 0.0:
            why = ("the best mean" if kind == best else
                   f"the cheapest kind not shown worse than the best, {best} (paired difference "
                   f"{intervals[kind][0]:+.3g}, 95 % interval [{intervals[kind][1]:.3g}, {intervals[kind][2]:.3g}])")
            return dict(kind=kind, best=best, why=why, intervals=intervals, inconclusive=False)
    raise AssertionError("the best is always a candidate")


def run_compare(job: CompareJob) -> dict:
    """Run `job`: the checks first (the request, the output folder, the dataset and its robot, a folder of another
    comparison refused), then each stage not done before (identify, train per kind, the open-loop table, the
    closed loops), the tables printed and written; returns what compare.json holds. InputError (one line) for a bad
    input."""
    from stdm_drake.data.compatibility import resolve_robot   # lazy: pydrake
    from stdm_drake.data.dataset import load_dataset   # lazy: pydrake, h5py
    job.validate()
    dataset = load_dataset(job.dataset)
    robot = resolve_robot(job.robot, dataset)
    loops = job.closed_loop and dataset.is_simulated and dataset.has_plan
    if loops:
        robot.check_fully_actuated("the closed loops (--no-closed-loop leaves them out)")
    from stdm_drake.data.dataset import dataset_split   # lazy: pydrake, h5py
    from stdm_drake.learning.settings import TrainSettings   # lazy: torch, pydrake, h5py
    split, _ = dataset_split(dataset, TrainSettings(), advice="collect more (compare splits every dataset by train's "
                             "default rule, with no options to change it)")   # (refused before any work)
    size = job.profile   # the closed loops track test plans and tune on validation ones: checked before any training
    if loops and (len(split.test) < size.plans or len(split.val) < size.tune):
        raise InputError(f"{line_text(job.dataset)}: the {size.name} size's closed loops track {size.plans} held-out plans"
                         + (f" and tune on {size.tune} validation plans" if size.tune else "") + f", and train's split of "
                         f"its {dataset.num_trajectories} trajectories leaves {len(split.test)} test and {len(split.val)} "
                         "validation ones; collect more plans, or leave the closed loops out (--no-closed-loop)"
                         + (" or run the quick size (--quick)" if size.name == "full" else ""))
    request = json.loads(json.dumps(finite_json(dict(dataset_sha256=dataset.sha256, robot=robot.record(),
                                                     profile=dataclasses.asdict(job.profile), kinds=list(job.kinds)))))
    output = pathlib.Path(job.output) if job.output is not None else _default_folder(request)
    check_output_folder("-o/--output", output, inputs=[job.dataset, job.robot], force=job.force)
    _check_same_request(output, request)
    mark_output_folder(output)
    write_text_atomic(output / "request.json", json.dumps(finite_json(request), indent=1) + "\n")
    files = {}
    if "identified" in job.kinds:
        files["identified"] = [_identified(job, output, dataset)]
    for kind in (kind for kind in job.kinds if kind in LEARNED_KINDS):
        files[kind] = _trained(job, output, kind, dataset, files.get("identified", [None])[0])
    open_loop = _open_loop(job, dataset, robot, files)
    closed = _closed_loop(job, output, files) if loops else None
    record = _summary(job, dataset, robot, files, open_loop, closed, loops)
    _write(output, record)
    return record


STAGES = ("identified.yaml", "identified.json", "models", "mpc")   # what a comparison's stages leave in its folder


def _previous_request(output: pathlib.Path) -> dict | None:
    path = output / "request.json"
    return json.loads(path.read_text()) if path.exists() else None


def _default_folder(request: dict) -> pathlib.Path:
    """Without -o: out/compare, or the first of out/compare-2, -3, ... that holds no finished comparison and no other
    request's stages (a stopped run of this request continues in its folder)."""
    candidate, number = DEFAULT_OUTPUT, 1
    while candidate.exists() and (not candidate.is_dir() or any((candidate / name).exists() for name in
                                  FINISHED_RESULTS["compare"]) or _previous_request(candidate) not in (None, request)):
        number += 1
        candidate = DEFAULT_OUTPUT.with_name(f"{DEFAULT_OUTPUT.name}-{number}")
    return candidate


def _check_same_request(output: pathlib.Path, request: dict) -> None:
    """InputError (one line) where `output` holds another request's stages (their files are reused only for the same
    dataset, robot, profile and kinds), or stages without the request that made them."""
    before = _previous_request(output)
    if before is None:
        found = [name for name in STAGES if (output / name).exists()]
        if found:
            raise InputError(f"-o/--output {line_text(output)} holds {', '.join(found)} without the request.json of the "
                             "comparison that made them, so they cannot be reused; choose another folder")
    elif before != request:
        changed = sorted(key for key in set(before) | set(request) if before.get(key) != request.get(key))
        raise InputError(f"-o/--output {line_text(output)} holds a comparison of another {', '.join(changed)}; "
                         "choose another folder (its stages are reused only for the same request)")


def _identified(job: CompareJob, output: pathlib.Path, dataset) -> pathlib.Path:
    """The identified robot of the dataset's train split (identify's defaults: the same split as train's), reused
    where a run before wrote it."""
    from stdm_drake.identification.identify_job import IdentifyJob, identify_job   # lazy: pydrake
    path = output / "identified.yaml"
    if path.exists() and (output / "identified.json").exists():
        say(f"compare: identified robot: reused {line_text(path)}")
        return path
    say("compare: identifying the robot (link inertias and friction) on the train split")
    identify_job(IdentifyJob(dataset=job.dataset, output=path, robot=job.robot, progress=job.progress,
                             force=job.force))
    return path


def _trained(job: CompareJob, output: pathlib.Path, kind: str, dataset, identified) -> list[pathlib.Path]:
    """The checkpoints (one per seed) of `kind` trained at the profile's size on the dataset's default split,
    reused where a finished run wrote them (its summary.json), continued where one stopped."""
    from stdm_drake.learning.settings import TrainSettings   # lazy: torch, pydrake, h5py
    from stdm_drake.learning.train_job import TrainJob, train_job   # lazy: torch, pydrake, h5py
    profile, folder = job.profile, output / "models" / kind
    seeds = list(range(profile.seeds))
    paths = [folder / f"seed{seed}" / "checkpoint.pt" for seed in seeds]
    if (folder / "summary.json").exists() and all(path.exists() for path in paths):
        say(f"compare: {kind}: reused {line_text(folder)}")
        return paths
    fields = dict(model=kind, seeds=seeds, epochs=profile.epochs, patience=profile.patience,
                  hidden_width=profile.hidden_width, hidden_layers=profile.hidden_layers)
    if kind == "PE":
        fields["ensemble_size"] = profile.ensemble_size
    say(f"compare: training {kind} ({len(seeds)} seed(s), at most {profile.epochs} epochs)")
    train_job(TrainJob(dataset=job.dataset, output=folder, settings=TrainSettings(**fields), robot=job.robot,
                       physics=identified if kind == "G" else None, progress=job.progress, force=job.force,
                       resume=any((folder / f"seed{seed}").exists() for seed in seeds), given=frozenset(fields)))
    return paths


def _open_loop(job: CompareJob, dataset, robot, files: dict) -> dict:
    """Every model's and baseline's one-step MSE and open-loop q MSE at HORIZONS on the test split, and its q RMS
    over the longest horizon per test trajectory (the units of the rule without closed loops)."""
    from stdm_drake.data.inspect import noise_floor   # lazy: pydrake, h5py
    # lazy: torch
    from stdm_drake.learning.evaluate import compare_with_baselines, physics_baselines, trajectory_rollout_data
    from stdm_drake.data.dataset import dataset_split   # lazy: pydrake, h5py
    from stdm_drake.learning.settings import TrainSettings   # lazy: torch, pydrake, h5py
    test = np.asarray(dataset_split(dataset, TrainSettings())[0].test, dtype=int)
    models, kinds = [], []
    for kind, paths in files.items():
        for seed, path in enumerate(paths):
            source = load_model_file(path)
            if list(source.split_indices(dataset, "test")) != test.tolist():
                raise InputError(f"{line_text(path)} was fitted on another split of {line_text(job.dataset)} than "
                                 "the default one this comparison uses")
            models.append(load_model(source, robot, name=kind if kind == "identified" else f"{kind}-s{seed}"))
            kinds.append(kind)
    baselines = physics_baselines(dataset.sample_period, robot.state_dim, robot.action_dim, robot=robot,
                                  plant_config=dataset.metadata.plant_config(effects=False))
    if "plant" not in job.kinds:
        baselines = baselines[:-1]
    shortest = min(dataset.trajectory(int(i)).num_steps for i in test)
    horizon = min(max(HORIZONS), shortest)
    rollout = trajectory_rollout_data(dataset, test, horizon)
    say(f"compare: open loop on {len(test)} test trajectories, {horizon} steps")
    rows = compare_with_baselines(models + baselines, dataset.transitions(test), rollout,
                                  noise_floor=noise_floor(dataset, test))
    x0, actions, truth = rollout
    n = robot.num_joints
    per_trajectory = {}
    for model, row in zip(models + baselines, rows):
        predicted = np.asarray(model.rollout(x0, actions).mean, dtype=float)
        with np.errstate(over="ignore", invalid="ignore"):
            per_trajectory[row.name] = np.sqrt(np.mean((predicted[..., :n] - truth[..., :n]) ** 2, axis=(1, 2)))
    kinds += ["plant" if row.name == "plant" else "baseline" for row in rows[len(models):]]
    return dict(rows=rows, kinds=kinds, horizon=horizon, test=test.tolist(), per_trajectory=per_trajectory)


def _closed_loop(job: CompareJob, output: pathlib.Path, files: dict) -> list[dict]:
    """The runs of `mpc` on held-out plans with every model (and the description, "plant"), each model's MPC setting
    tuned first where the profile says; reused where a run before closed them on the same model files."""
    from stdm_drake.closed_loop.study import MpcStudy, run_mpc_study   # lazy: pydrake
    from stdm_drake.data.dataset import file_sha256   # lazy: pydrake, h5py
    folder = output / "mpc"
    models = [(kind if kind == "identified" else f"{kind}-s{seed}", path) for kind, paths in files.items()
              for seed, path in enumerate(paths)]
    if (folder / "mpc.json").exists():
        record = json.loads((folder / "mpc.json").read_text())
        given = [(model["name"], model.get("sha256")) for model in record["inputs"]["models"] if model["kind"] != "plant"
                 and model["kind"] != "plant with effects"]
        if given == [(name, file_sha256(path)) for name, path in models]:
            say(f"compare: closed loops: reused {line_text(folder)}")
            return record["runs"]
    say(f"compare: closed loops on {job.profile.plans} held-out plans" + (
        f", each model's MPC setting tuned on {job.profile.tune} plans first" if job.profile.tune else ""))
    result = run_mpc_study(MpcStudy(dataset=job.dataset, models=models, plant="plant" in job.kinds,
                                    plans=job.profile.plans, tune=job.profile.tune, robot=job.robot, output=folder,
                                    progress=job.progress, force=job.force))
    return [dataclasses.asdict(run) for run in result.results]


def _summary(job: CompareJob, dataset, robot, files: dict, open_loop: dict, closed: list | None, loops: bool) -> dict:
    """compare.json: per kind its open-loop errors (mean over seeds, with the spread of seeds), its closed-loop
    tracking and cost per control step, the candidates and the recommendation (`recommend`)."""
    rows, horizon = open_loop["rows"], open_loop["horizon"]
    steps = [step for step in HORIZONS if step <= horizon]
    table = []
    for kind in [kind for kind in KINDS if kind in job.kinds] + ["baseline"]:
        members = [(row, name_kind) for row, name_kind in zip(rows, open_loop["kinds"]) if name_kind == kind]
        for group in ([members] if kind != "baseline" else [[member] for member in members]):
            if not group:
                continue
            names = [row.name for row, _ in group]
            entry = dict(kind=kind if kind != "baseline" else names[0], models=names, seeds=len(group),
                         one_step_q_mse=float(np.mean([row.one_step.angle_mse for row, _ in group])),
                         one_step_v_mse=float(np.mean([row.one_step.velocity_mse for row, _ in group])),
                         open_loop_q_rms={str(step): float(np.mean([np.sqrt(row.multi_step.angle_mse[step - 1])
                                                                    for row, _ in group])) for step in steps},
                         verdicts=[row.verdict for row, _ in group if row.verdict is not None],
                         learned_every_seed=all((row.verdict or "").startswith("learned") for row, _ in group))
            table.append(entry)
    scores_open = {entry["kind"]: np.mean([open_loop["per_trajectory"][name] for name in entry["models"]], axis=0)
                   for entry in table}
    scores, unit = scores_open, "test trajectory (open-loop q RMS over the horizon, rad)"
    if closed is not None:
        by_model = {}
        for run in closed:
            by_model.setdefault(run["model"], []).append(run)
        plans = sorted({run["trajectory"] for run in closed})
        scores, unit = {}, "held-out plan (closed-loop q RMS, rad)"
        for entry in table:
            runs = [by_model.get(name, []) for name in entry["models"]]
            if entry["kind"] not in KINDS or not all(runs):
                continue
            rms = [[np.sqrt(next(r["q_mse_rad2"] for r in model_runs if r["trajectory"] == plan)) for plan in plans]
                   for model_runs in runs]
            scores[entry["kind"]] = np.mean(rms, axis=0)
            flat = [r for model_runs in runs for r in model_runs]
            entry.update(closed_loop_q_rms=float(np.mean(scores[entry["kind"]])),
                         limit_violations=int(sum(r["limit_violations"] for r in flat)),
                         fallbacks=int(sum(r["fallbacks"] for r in flat)),
                         solve_ms_mean=float(np.mean([r["solve_ms_mean"] for r in flat])))
    excluded = {}   # kind -> why it is no candidate
    for entry in (entry for entry in table if entry["kind"] in KINDS):
        kind = entry["kind"]
        reasons = ([] if kind in scores else ["no closed loop"]) + (
            ["its error is not finite (diverged)"] if kind in scores and not np.all(np.isfinite(scores[kind])) else []) + (
            [] if kind in ("plant", "identified") or entry["learned_every_seed"] else ["not every seed learned"]) + (
            [f"its loops left the robot's limits on {entry['limit_violations']} steps"] if entry.get("limit_violations")
            else []) + ([f"its loops fell back {entry['fallbacks']} times"] if entry.get("fallbacks") else [])
        if reasons:
            excluded[kind] = ", ".join(reasons)
    candidates = [entry["kind"] for entry in table if entry["kind"] in KINDS and entry["kind"] not in excluded]
    choice = recommend({kind: scores[kind] for kind in candidates}, candidates)
    if not candidates:
        choice["why"] = "no kind qualifies: " + "; ".join(f"{kind}: {why}" for kind, why in excluded.items())
    choice["unit"] = unit
    choice["intervals"] = {kind: None if value is None else dict(mean=value[0], low=value[1], high=value[2])
                           for kind, value in choice["intervals"].items()}
    return dict(**results_header(), dataset=str(job.dataset),
                dataset_sha256=dataset.sha256, robot=robot.record(), profile=dataclasses.asdict(job.profile),
                test_trajectories=open_loop["test"], horizon=horizon, closed_loop=loops,
                closed_loop_why_not=None if loops else ("left out" if not job.closed_loop else
                                                         "the dataset's plant is not simulated or it has no plans"),
                models={kind: [str(path) for path in paths] for kind, paths in files.items()},
                table=table, candidates=candidates, excluded=excluded, recommendation=choice)


def _markdown(record: dict) -> str:
    steps = [str(step) for step in HORIZONS if step <= record["horizon"]]
    closed = record["closed_loop"]
    header = (["kind", "seeds", "one-step q MSE (rad²)", "one-step v MSE ((rad/s)²)"]
              + [f"q RMS @{step} (rad)" for step in steps]
              + ["learned (one step, every seed)"] + (["closed-loop q RMS (rad)", "limits left", "fallbacks", "solve ms"] if closed else []))
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for entry in record["table"]:
        cells = [entry["kind"], str(entry["seeds"]), f"{entry['one_step_q_mse']:.3e}", f"{entry['one_step_v_mse']:.3e}"]
        cells += [f"{entry['open_loop_q_rms'][step]:.3g}" for step in steps]
        cells.append("(physics)" if entry["kind"] in ("plant", "identified") or not entry["verdicts"] else
                     "yes" if entry["learned_every_seed"] else "no")
        if closed:
            cells += ([f"{entry['closed_loop_q_rms']:.3g}", str(entry["limit_violations"]), str(entry["fallbacks"]),
                       f"{entry['solve_ms_mean']:.2f}"] if "closed_loop_q_rms" in entry else ["", "", "", ""])
        lines.append("| " + " | ".join(cells) + " |")
    choice = record["recommendation"]
    lines += ["", f"Units of the rule: per {choice['unit']}. Candidates: {', '.join(record['candidates']) or 'none'}.",
              f"**Recommendation: {choice['kind'] or 'none'}** ({choice['why']})."]
    if not closed:
        lines.append(f"No closed loops: {record['closed_loop_why_not']}.")
    return "\n".join(lines) + "\n"


def _write(output: pathlib.Path, record: dict) -> None:
    """compare.md (printed too), compare.csv, compare.html and compare.json in `output`."""
    text = _markdown(record)
    print(text, end="")
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    columns = ["kind", "seeds", "one_step_q_mse", "one_step_v_mse", "open_loop_q_rms", "learned_every_seed",
               "closed_loop_q_rms", "limit_violations", "fallbacks", "solve_ms_mean"]
    writer.writerow(columns)
    for entry in record["table"]:
        writer.writerow([json.dumps(entry[column]) if isinstance(entry.get(column), dict) else entry.get(column, "")
                         for column in columns])
    rows = "".join("<tr>" + "".join(f"<td>{html.escape(cell.strip())}</td>" for cell in line.strip("|").split("|"))
                   + "</tr>\n" for line in text.splitlines()[2:] if line.startswith("|"))
    head = "".join(f"<th>{html.escape(cell.strip())}</th>" for cell in text.splitlines()[0].strip("|").split("|"))
    notes = "".join(f"<p>{html.escape(line).replace('**', '')}</p>\n" for line in text.splitlines()
                    if line and not line.startswith("|"))
    page = (f"<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>stdm-drake compare</title></head>"
            f"<body>\n<h1>Which model for this robot</h1>\n<table>\n<tr>{head}</tr>\n{rows}</table>\n{notes}</body></html>\n")
    texts = {"compare.json": json.dumps(finite_json(record), indent=1) + "\n", "compare.csv": buffer.getvalue(),
             "compare.html": page, "compare.md": text}
    with atomic_paths([output / name for name in texts]) as temps:   # (one set: a signal replaces none of them)
        for temp, content in zip(temps, texts.values()):
            temp.write_text(content)
    print(f"wrote {line_text(output)}: compare.md, compare.csv, compare.html, compare.json")
