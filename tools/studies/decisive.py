"""The decisive experiment on the paper's UR-10 claim (derivative learning: 3-7x lower one-step MSE).

Design, endpoints, intervals and verdict rules: docs/learning.md, "The decisive experiment" (fixed
before the first run). Cells start from the paper-literal setting (`models/ur10_limit_free.yaml`, the
paper's torque ranges, gravity uncompensated, one start pose, direct outputs) and switch one factor at
a time; per cell `data_seeds` datasets x `inits` initializations of D, DD (alpha 1e-3, our units) and
the two label-matched controls D-2x (twice the training trajectories) and D-half (naive on the same
trajectories sampled at half the period, run twice per period with the torque held); the gate: the
cell's naive models beat the physics-free baselines by 2x. One cell swaps the paper's model class for
the default structure on the paper-literal data, so the claim is also tested on models that learn.
`run_study` runs it on the local pool or a Ray cluster (`stdm_drake.cluster`).

    python tools/study.py decisive [--quick] [--resume] [--workers 2] [--backend local|ray]
        [--ray-address HOST:PORT] [-o docs/results/decisive] [--data out/decisive_data]

--resume keeps the rows of the output folder's results.json when its design (seeds, split, alpha,
horizon) is this run's, and trains only the models it lacks (new cells or controls).
"""
from __future__ import annotations

import argparse
import concurrent.futures
import dataclasses
import json
import math
import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
HOME = [0.0, -1.2, 1.5, -1.9, -1.57, 0.0]
GLOBAL_LOWER, GLOBAL_UPPER = [-3.1, -2.6, -2.6, -3.1, -3.1, -3.1], [3.1, -0.5, 2.6, 3.1, 3.1, 3.1]
SCALED = [6.0, 6.0, 2.0, 0.015, 0.002, 0.00015]           # excitation.yaml's per-joint ranges (N m)
SPEED_BOUND = 3000.0                                      # rad/s: faster trajectories are redrawn
ALPHA = 1e-3
HORIZON = 20
QUICK_EPOCHS = 20   # the quick profile's epoch budget per model: a pipeline check, no verdict read from it
TRAIN, VALIDATION, TEST = 40, 40, 120


@dataclasses.dataclass(frozen=True)
class Cell:
    name: str
    switch: str
    sample_period: float = 0.01
    delta: bool = False
    start: str = "fixed"            # fixed | box | global
    compensated: bool = False
    structure: str = "paper"        # paper | default (stdm_drake.learning.structure)
    data: str = ""                  # another cell whose datasets this one uses ("": its own)

    @property
    def model_structure(self):
        from stdm_drake.learning.structure import DEFAULT, PAPER
        return {"paper": PAPER, "default": DEFAULT}[self.structure]


CELLS = (
    Cell("literal-10ms", "the paper-literal setting"),
    Cell("literal-50ms", "sample period 10 ms -> 50 ms", sample_period=0.05),
    Cell("delta", "direct -> delta outputs", delta=True),
    Cell("box-start", "fixed start -> home +- 0.5 rad", start="box"),
    Cell("global-start", "fixed start -> excitation.yaml's global box", start="global"),
    Cell("compensated", "no compensation -> g(q) + excitation.yaml's scaled ranges", compensated=True),
    Cell("learned-structure", "the paper's black box -> the default structure (delta v, trapezoid q, "
         "nominal-acceleration inputs)", delta=True, structure="default", data="literal-10ms"),
)
# alpha, training trajectories in units of TRAIN, trained at half the sample period
MODELS = {"D": (0.0, 1, False), "DD": (ALPHA, 1, False), "D-2x": (0.0, 2, False), "D-half": (0.0, 1, True)}
CONTROLS = ("D-2x", "D-half")
ENDPOINTS = (("one_step_q", "one-step q"), ("one_step_v", "one-step v"), ("open_loop_q", f"q at step {HORIZON}"))


def excitation_config(cell: Cell):
    from stdm_drake.collection.excitation import Excitation
    lower, upper = {"fixed": (HOME, HOME), "box": ([h - 0.5 for h in HOME], [h + 0.5 for h in HOME]),
                    "global": (GLOBAL_LOWER, GLOBAL_UPPER)}[cell.start]
    ranges = SCALED if cell.compensated else None
    return Excitation(amplitude_max=ranges or [0.3] * 6, offset_max=ranges or [1.0] * 6,
                            gravity_compensation=cell.compensated, initial_position_lower=list(lower),
                            initial_position_upper=list(upper), position_margin=0.0,
                            velocity_fraction=SPEED_BOUND / 1e4, check_self_collision=False, max_attempts=200)


def dataset_name(cell: Cell, data_seed: int, count: int, half: bool = False) -> str:
    return f"{cell.data or cell.name}{'_half' if half else ''}_seed{data_seed}_n{count}.h5"


def collect_dataset(cell: Cell, data_seed: int, count: int, half: bool = False) -> bytes:
    """The cell's dataset of `count` trajectories for data_seed, as the bytes of its file (collected in a
    scratch folder of the worker's node, so the driver gets it from any node of a cluster). With `half`
    the same protocol sampled at half the period for twice the steps (the same duration)."""
    import shutil
    import tempfile

    from stdm_drake.collection.collect import collect, collection_request
    from stdm_drake.data.writer import write_dataset
    from stdm_drake.paths import MODELS_DIR
    from stdm_drake.robots.robot import load_robot
    robot = load_robot(MODELS_DIR / "ur10_limit_free.yaml")
    excitation = excitation_config(cell)
    if half:
        excitation = dataclasses.replace(excitation, num_steps=2 * excitation.num_steps)
    request = collection_request("excitation", count=count, seed=1000 + data_seed, robot=robot,
                                 sample_period=cell.sample_period / (2 if half else 1), excitation=excitation,
                                 workers=1)
    request.settings.plant.self_collision = False
    trajectories, groups, metadata = collect(request, progress=False)
    scratch = pathlib.Path(tempfile.mkdtemp(prefix="stdm-drake-decisive-"))
    try:
        path = write_dataset(scratch / dataset_name(cell, data_seed, count, half), trajectories, groups, metadata)
        return path.read_bytes()
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


@dataclasses.dataclass(frozen=True)
class DecisiveRun:
    """One trained model of the decisive experiment, tested on its cell's test trajectories: a row of
    `runs.csv`. MSE in rad² (q) and (rad/s)² (v); open_loop_q at step HORIZON; the ratios are baseline
    MSE / this model's (above 1: the model is better); verdict: `compare_with_baselines`'s word on
    whether the model learned. train_sample_period: the period it was trained at (s; half the cell's for
    D-half); train_seconds: wall time of its training."""
    cell: str
    data_seed: int
    init: int
    model: str
    alpha: float
    train_trajectories: int
    train_sample_period: float
    epochs: int
    best_epoch: int
    train_seconds: float
    one_step_q: float
    one_step_v: float
    open_loop_q: float
    ratio_to_euler_q: float
    ratio_to_unchanged_v: float
    ratio_to_stays_put_open_loop_q: float
    verdict: str


def run_job(cell: Cell, data_seed: int, init: int, model: str, sizes: tuple, max_epochs: int | None, path: str,
            content: bytes | None = None, sha256: str | None = None, half_path: str | None = None,
            half_content: bytes | None = None, half_sha256: str | None = None) -> DecisiveRun:
    """Train and evaluate one model on the cell's dataset `path` (on a Ray cluster its bytes `content`
    and their `sha256`; top-level arguments, so Ray hands the task the bytes, not a reference). D-half
    trains on the half-period dataset (`half_*`, the same way) and is tested, like every model, on
    `path`'s test trajectories. max_epochs: None trains to the design's budget (TrainingConfig's default)."""
    import torch

    from stdm_drake.cluster import file_on_this_node
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.dynamics.model import HeldInputSubsteps
    from stdm_drake.learning.evaluate import compare_with_baselines, physics_baselines, trajectory_rollout_data
    from stdm_drake.learning.learned_model import LearnedModel
    from stdm_drake.learning.settings import TrainingConfig
    from stdm_drake.learning.problem import training_problem
    from stdm_drake.learning.alpha_selection import fit_model
    from stdm_drake.paths import MODELS_DIR
    from stdm_drake.robots.robot import load_robot
    torch.set_num_threads(1)
    train, validation, tested = sizes
    alpha, factor, half = MODELS[model]
    n_train = factor * train
    dataset = load_dataset(file_on_this_node(path, content, sha256))
    training_data = load_dataset(file_on_this_node(half_path, half_content, half_sha256)) if half else dataset
    test = list(range(2 * train + validation, 2 * train + validation + tested))
    split = dict(train=list(range(n_train)), val=list(range(2 * train, 2 * train + validation)), test=test)
    robot = load_robot(MODELS_DIR / "ur10_limit_free.yaml")
    structure = cell.model_structure
    problem = training_problem(training_data, split, model_type="DD" if alpha else "D", delta=cell.delta,
                               structure=structure, robot=robot)
    started = time.perf_counter()
    budget = {} if max_epochs is None else dict(max_epochs=max_epochs, patience=min(max_epochs, 50))
    result, _ = fit_model(problem.model_config, TrainingConfig(alpha=alpha, seed=init, **budget), problem.train,
                          problem.val)
    seconds = time.perf_counter() - started
    learned = LearnedModel(result.model, name=model, robot=robot, structure=structure,
                           sample_period=training_data.sample_period)
    if half:
        learned = HeldInputSubsteps(learned, 2, name=model)
    baselines = physics_baselines(dataset.sample_period, robot.state_dim, robot.action_dim, plant=False)
    mine, euler, stays = compare_with_baselines([learned] + baselines, dataset.transitions(test),
                                                trajectory_rollout_data(dataset, test, HORIZON))
    return DecisiveRun(cell=cell.name, data_seed=data_seed, init=init, model=model, alpha=alpha, train_trajectories=n_train,
                train_sample_period=training_data.sample_period, epochs=result.epochs_run,
                best_epoch=int(result.best_epochs[0]), train_seconds=round(seconds, 2),
                one_step_q=mine.one_step.angle_mse, one_step_v=mine.one_step.velocity_mse,
                open_loop_q=float(mine.multi_step.angle_mse[-1]), ratio_to_euler_q=mine.ratio_q,
                ratio_to_unchanged_v=mine.ratio_v, ratio_to_stays_put_open_loop_q=float(
                    stays.multi_step.angle_mse[-1] / mine.multi_step.angle_mse[-1]), verdict=mine.verdict)


def two_level_ratio(rows_base: list[DecisiveRun], rows_method: list[DecisiveRun], key: str) -> dict:
    """Ratio base/method: per (data seed, init) pair, log-averaged over inits per data seed, then a
    Student-t 95 % interval over the data seeds' means."""
    from scipy import stats
    method = {(r.data_seed, r.init): getattr(r, key) for r in rows_method}
    per_seed = {}
    for r in rows_base:
        pair = (r.data_seed, r.init)
        if pair in method:
            per_seed.setdefault(r.data_seed, []).append(math.log(getattr(r, key) / method[pair]))
    means = np.array([np.mean(values) for values in per_seed.values()])
    pairs = sum(len(values) for values in per_seed.values())
    mean = float(means.mean())
    if len(means) < 2:
        return dict(ratio=math.exp(mean), low=0.0, high=math.inf, data_seeds=len(means), pairs=pairs)
    half = float(stats.t.ppf(0.975, len(means) - 1) * means.std(ddof=1) / math.sqrt(len(means)))
    return dict(ratio=math.exp(mean), low=math.exp(mean - half), high=math.exp(mean + half), data_seeds=len(means),
                pairs=pairs)


def cell_verdict(gated: bool, ratios: dict) -> str:
    if not gated:
        return "uninformative (naive has not learned)"
    q, v = ratios["one-step q"], ratios["one-step v"]
    if all(r["ratio"] >= 3 and r["low"] >= 2 for r in (q, v)):
        return "the paper reproduces"
    if all(0.8 <= r["low"] and r["high"] <= 1.25 for r in ratios.values()):
        return "no help"
    return "inconclusive"




def summarize(cells, rows: list[DecisiveRun]) -> list[dict]:
    """Per cell: the naive models' gate, the two-level ratios D/DD and control/DD per endpoint (for each
    label-matched control in the rows), the verdict."""
    summary = []
    for cell in cells:
        mine = [r for r in rows if r.cell == cell.name]
        by_model = {model: [r for r in mine if r.model == model] for model in MODELS}
        naive = by_model["D"]
        gate_q = float(np.exp(np.mean([np.log(r.ratio_to_euler_q) for r in naive])))
        gate_v = float(np.exp(np.mean([np.log(r.ratio_to_unchanged_v) for r in naive])))
        gated = gate_q >= 2 and gate_v >= 2
        ratios = {label: two_level_ratio(naive, by_model["DD"], key) for key, label in ENDPOINTS}
        controls = {control: {label: two_level_ratio(by_model[control], by_model["DD"], key)
                              for key, label in ENDPOINTS} for control in CONTROLS if by_model[control]}
        summary.append(dict(cell=cell.name, switch=cell.switch, structure=cell.structure, naive_vs_euler_q=gate_q,
                            naive_vs_unchanged_v=gate_v, gated=gated, D_over_DD=ratios,
                            **{f"{control}_over_DD": ratio for control, ratio in controls.items()},
                            verdict=cell_verdict(gated, ratios)))
    return summary


def run_study(data: pathlib.Path, runner, *, cells=CELLS, data_seeds: int = 3, inits: int = 5,
              sizes: tuple = (TRAIN, VALIDATION, TEST), models=tuple(MODELS), done: list[DecisiveRun] = (),
              max_epochs: int | None = None, progress=print) -> dict:
    """Collect every cell's datasets into `data` (once; cells that share data share the files), train and
    evaluate every model on `runner` (`cluster.RunnerConfig`: local processes or Ray; on Ray each dataset
    travels once through the object store); rows in `done` (from an earlier run of the same design) are
    kept and their models not trained again. max_epochs: each model's epoch budget (None: the design's, 500;
    the quick profile's pipeline check trains QUICK_EPOCHS). Returns {"summary", "runs", "seconds", "reused"}."""
    from stdm_drake.cluster import job_pool, shared_file, task_error
    from stdm_drake.files import atomic_path
    if runner.backend == "ray":   # a cluster's workers have the package, not tools/studies: this module's
        from stdm_drake.cluster import import_ray   # functions and classes travel with the tasks, by value
        import_ray()
        import ray.cloudpickle
        ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    train, validation, test = sizes
    count = 2 * train + validation + test
    pathlib.Path(data).mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    key = lambda row: (row.cell, row.data_seed, row.init, row.model)  # noqa: E731
    wanted = [(cell, seed, init, model) for cell in cells for seed in range(data_seeds) for init in range(inits)
              for model in models]
    kept = {key(row): row for row in done}
    todo = [job for job in wanted if (job[0].name, *job[1:]) not in kept]
    needed = {}                      # dataset file name -> (cell, seed, half)
    for cell, seed, _, model in todo:
        needed.setdefault(dataset_name(cell, seed, count), (cell, seed, False))
        if MODELS[model][2]:
            needed.setdefault(dataset_name(cell, seed, count, half=True), (cell, seed, True))
    with job_pool(runner) as pool:
        paths, futures = {}, {}
        for name, (cell, seed, half) in needed.items():
            path = pathlib.Path(data) / name
            if path.exists():      # collected before with these settings (the name holds all of them)
                paths[name] = str(path)
            else:
                futures[name] = pool.submit(collect_dataset, cell, seed, count, half)
        for name, future in futures.items():
            try:
                content = future.result()
            except Exception as error:
                raise task_error(error, f"collecting {name}") from None
            path = pathlib.Path(data) / name
            with atomic_path(path) as temp:
                temp.write_bytes(content)
            paths[name] = str(path)
        progress(f"{len(paths)} datasets in {time.perf_counter() - started:.0f} s")
        # Ray: the bytes once into the object store, a scratch file per node
        sources = {name: (path, *shared_file(pool, path)) for name, path in paths.items()}
        jobs = {pool.submit(run_job, cell, seed, init, model, sizes, max_epochs,
                            *sources[dataset_name(cell, seed, count)],
                            *(sources[dataset_name(cell, seed, count, half=True)] if MODELS[model][2] else ())):
                (cell.name, seed, init, model) for cell, seed, init, model in todo}
        rows = [kept[(cell.name, *rest)] for cell, *rest in wanted if (cell.name, *rest) in kept]
        for finished, future in enumerate(concurrent.futures.as_completed(jobs), start=1):
            try:
                rows.append(future.result())
            except Exception as error:
                raise task_error(error, "model {} of {} (data seed {}, init {})".format(
                    jobs[future][3], jobs[future][0], jobs[future][1], jobs[future][2])) from None
            if finished % 15 == 0:
                progress(f"{finished}/{len(jobs)} models trained ({time.perf_counter() - started:.0f} s)")
    names, order = [c.name for c in cells], list(MODELS)
    rows.sort(key=lambda r: (names.index(r.cell), r.data_seed, r.init, order.index(r.model)))
    return dict(summary=summarize(cells, rows), runs=rows, seconds=round(time.perf_counter() - started, 1),
                reused=len(rows) - len(jobs))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from stdm_drake.cluster import add_runner_arguments
    parser.add_argument("-o", "--output", type=pathlib.Path, default=ROOT / "docs" / "results" / "decisive")
    parser.add_argument("--data", type=pathlib.Path, default=ROOT / "out" / "decisive_data")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--quick", action="store_true",
                        help="the literal and learned-structure cells, 2 data seeds x 2 inits, 50 trajectories "
                             "(pipeline check, 20 epochs per model)")
    parser.add_argument("--resume", action="store_true",
                        help="keep the output folder's rows of the same design; train only the missing models")
    add_runner_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from stdm_drake.cluster import runner_config_from_args
    from stdm_drake.files import json_default, rows_csv, write_text_atomic
    runner = runner_config_from_args(args)
    cells, data_seeds, inits, sizes, max_epochs = CELLS, 3, 5, (TRAIN, VALIDATION, TEST), None
    if args.quick:
        cells, data_seeds, inits, sizes, max_epochs = (CELLS[0], CELLS[-1]), 2, 2, (10, 10, 20), QUICK_EPOCHS
    design = dict(quick=args.quick, data_seeds=data_seeds, inits=inits,
                  split=dict(zip(("train", "validation", "test"), sizes)), alpha=ALPHA, horizon=HORIZON,
                  **({"max_epochs": max_epochs} if args.quick else {}))
    done = earlier_rows(args.output / "results.json", design, cells) if args.resume else []
    study = run_study(args.data, runner, cells=cells, data_seeds=data_seeds, inits=inits, sizes=sizes, done=done,
                      max_epochs=max_epochs, progress=lambda text: print(text, flush=True))
    summary, rows = study["summary"], study["runs"]
    args.output.mkdir(parents=True, exist_ok=True)
    ratios = ["D_over_DD"] + [f"{control}_over_DD" for control in CONTROLS]
    flat = [dict(cell=s["cell"], switch=s["switch"], structure=s["structure"], naive_vs_euler_q=s["naive_vs_euler_q"],
                 naive_vs_unchanged_v=s["naive_vs_unchanged_v"], gated=s["gated"], verdict=s["verdict"],
                 **{f"{which} {label} {part}": s[which][label][part] for which in ratios if which in s
                    for _, label in ENDPOINTS for part in ("ratio", "low", "high")}) for s in summary]
    write_text_atomic(args.output / "runs.csv", rows_csv([dataclasses.asdict(row) for row in rows]))
    write_text_atomic(args.output / "cells.csv", rows_csv(flat))
    write_text_atomic(args.output / "results.json", json.dumps(dict(
        written_by="tools/study.py decisive", provenance=args.provenance, **design, seconds=study["seconds"],
        train_seconds_total=round(sum(row.train_seconds for row in rows), 1),
        reused_rows=study["reused"], cells=[dataclasses.asdict(c) for c in cells], summary=summary, runs=rows),
        indent=2, default=json_default) + "\n")
    for s in summary:
        print(f"\n{s['cell']} ({s['switch']}): naive vs Euler q {s['naive_vs_euler_q']:.3g}x, vs 'v unchanged' "
              f"{s['naive_vs_unchanged_v']:.3g}x -> {s['verdict']}")
        for _, label in ENDPOINTS:
            print(f"  {label:>14}: " + "   ".join(
                f"{which[:-len('_over_DD')]}/DD {s[which][label]['ratio']:.3g}x [{s[which][label]['low']:.3g}, "
                f"{s[which][label]['high']:.3g}]" for which in ratios if which in s))
    print(f"\n{len(rows)} models ({study['reused']} kept from the earlier run) in {study['seconds']:.0f} s "
          f"-> {args.output}")
    return 0


def earlier_rows(path: pathlib.Path, design: dict, cells) -> list[DecisiveRun]:
    """The rows of an earlier results.json of the same design, for --resume (none if it does not exist)."""
    from stdm_drake.errors import InputError
    if not path.exists():
        return []
    try:
        earlier = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise InputError(f"--resume: cannot read {path}: {error}") from None
    differs = [name for name, value in design.items() if earlier.get(name) != value]
    if differs:
        raise InputError(f"--resume: {path} has another design ({', '.join(differs)} differ); "
                         "choose another -o or leave out --resume")
    periods = {cell.name: cell.sample_period for cell in cells}
    rows = [row for row in earlier.get("runs", []) if row.get("cell") in periods]
    for row in rows:   # rows written before D-half existed trained at their cell's own period
        row.setdefault("train_sample_period", periods[row["cell"]])
    try:
        return [DecisiveRun(**row) for row in rows]
    except TypeError as error:
        raise InputError(f"--resume: {path} has runs of another format ({error}); choose another -o or leave "
                         "out --resume") from None
