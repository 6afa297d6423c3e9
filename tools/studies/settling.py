"""The settling experiment: naive against derivative learning with alpha by validation (raw and relative scales).

Design, endpoints, intervals, multiplicity, gate, verdict rules and what the default follows: docs/settling.md
(committed before any of its models trained). Four cells (the paper's literal data with a model class that
learns, with its current and its held-torque derivative targets; the default model on default excitation data;
the paper's black box on identification data); per cell 4 data seeds x 3 initializations, each pair one raw and
one relative alpha grid trained as stacks (member k = alpha_k alone), D = the alpha 0 member, DD = the alpha > 0
member of the lowest validation MSE. Runs on the local pool or a Ray cluster (`stdm_drake.cluster`).

    python tools/study.py settling [--quick] [--workers 2] [--backend local|ray] [--ray-address HOST:PORT]
        [-o docs/results/settling] [--data out/settling_data]
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
HORIZON = 20
RAW_GRID = (0.0, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2)
RELATIVE_GRID = (1e-2, 1e-1, 1.0, 10.0, 100.0)
EXTENSION = {"raw": 1e-1, "relative": 1e3}        # the next decade, added once (docs/settling.md)
SCALES = ("raw", "relative")
DATA_SEEDS = (100, 101, 102, 103)
INITS = (0, 1, 2)
ENDPOINTS = (("one_step_q", "one-step q"), ("one_step_v", "one-step v"), ("open_loop_q", f"q at step {HORIZON}"))
RANK = {"the paper reproduces": 5, "helps": 4, "no help": 3, "inconclusive": 3, "mixed": 2, "hurts": 1}


@dataclasses.dataclass(frozen=True)
class Cell:
    """One cell: its data (`data`: literal | excitation | identification), split, model structure (default |
    paper), derivative targets' action-rate scheme and epoch budget."""
    name: str
    data: str
    structure: str
    action_rate: str
    max_epochs: int = 500

    @property
    def robot_file(self) -> pathlib.Path:
        return ROOT / "models" / ("ur10_limit_free.yaml" if self.data == "literal" else "ur10.yaml")

    @property
    def model_structure(self):
        from stdm_drake.learning.structure import DEFAULT, PAPER
        return {"paper": PAPER, "default": DEFAULT}[self.structure]


CELLS = (
    Cell("literal-current", "literal", "default", "forward_difference"),
    Cell("literal-held", "literal", "default", "zero_order_hold"),
    Cell("default-excitation", "excitation", "default", "forward_difference"),
    Cell("blackbox-identification", "identification", "paper", "zero_order_hold", max_epochs=300),
)


@dataclasses.dataclass(frozen=True)
class Profile:
    """Sizes: trajectories collected per data kind, the split per data kind, epochs cap, seeds."""
    counts: dict
    splits: dict           # data kind -> (train, val, test) trajectories (identification: per pose)
    data_seeds: tuple
    inits: tuple
    epoch_cap: int | None = None


FULL = Profile(counts=dict(literal=240, excitation=100, identification=100),
               splits=dict(literal=(40, 40, 120), excitation=(60, 20, 20), identification=(18, 2, 5)),
               data_seeds=DATA_SEEDS, inits=INITS)
QUICK = Profile(counts=dict(literal=30, excitation=16, identification=16),
                splits=dict(literal=(5, 5, 10), excitation=(8, 4, 4), identification=(2, 1, 1)),
                data_seeds=(100, 101), inits=(0, 1), epoch_cap=5)


def split_of(cell: Cell, profile: Profile, dataset) -> dict:
    """Trajectory indices {train, val, test}: the literal protocol's fixed ranges (the decisive split: train
    0..n-1, validation from 2n, test after it), else `split_trajectories` with seed 0 (per pose for tracking)."""
    from stdm_drake.data.dataset import split_trajectories
    train, val, test = profile.splits[cell.data]
    if cell.data == "literal":
        return dict(train=list(range(train)), val=list(range(2 * train, 2 * train + val)),
                    test=list(range(2 * train + val, 2 * train + val + test)))
    split = split_trajectories(dataset.groups, train, val, test, seed=0, per_group=cell.data == "identification")
    return {key: [int(i) for i in value] for key, value in split.as_dict().items()}


def dataset_name(kind: str, data_seed: int, count: int) -> str:
    """The file name of a cell data kind's dataset (the name holds every setting that varies)."""
    if kind == "literal":
        return f"literal_seed{data_seed}_n{count}.h5"
    return f"{kind}_n{count}_seed{data_seed}.h5"


def collect(kind: str, data_seed: int, count: int) -> bytes:
    """The dataset of `kind` for `data_seed`, as the bytes of its file (collected in a scratch folder of the worker's
    node, so the driver gets it from any node of a cluster)."""
    import shutil
    import tempfile
    if kind == "literal":
        from studies.decisive import CELLS as DECISIVE_CELLS, collect_dataset
        return collect_dataset(DECISIVE_CELLS[0], data_seed, count)
    from stdm_drake.experiments.jobs import ensure_dataset
    scratch = pathlib.Path(tempfile.mkdtemp(prefix="stdm-drake-settling-"))
    robot = str(ROOT / "models" / "ur10.yaml")
    try:
        if kind == "excitation":
            dataset = ensure_dataset("excitation", count, data_seed, scratch, False, robot=robot)
        else:
            dataset = ensure_dataset("tracking", count, data_seed, scratch, False, name="identification", robot=robot,
                                     controller=str(ROOT / "controllers" / "pid_dither.yaml"),
                                     sensor=str(ROOT / "controllers" / "sensor_ideal.yaml"))
        return pathlib.Path(dataset.path).read_bytes()
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def chain_rule_check(path: str, transitions: int = 400) -> dict:
    """The time derivative of the data's own map x_{t+1} = Φ(x_t, a_t) (the simulator's step of the limit-free
    UR-10, central differences along the tangent) against the current (forward-difference) and held
    (zero-order-hold) derivative targets: relative RMS difference of the q̇ and q̈ rows, on `transitions`
    transitions of the first 40 trajectories."""
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.dynamics.physics import PlantModel
    from stdm_drake.robots.robot import load_robot
    dataset = load_dataset(path)
    robot = load_robot(ROOT / "models" / "ur10_limit_free.yaml")
    plant = PlantModel(dataset.sample_period, dataset.metadata.plant_config(effects=False), robot=robot,
                       integrator="simulator")
    schemes = {scheme: dataset.transitions(list(range(min(40, dataset.num_trajectories))), derivative_source="true",
                                           action_rate=scheme) for scheme in ("forward_difference", "zero_order_hold")}
    n = schemes["zero_order_hold"].state.shape[1] // 2
    rows = np.sort(np.random.default_rng(0).permutation(len(schemes["zero_order_hold"].state))[:transitions])
    result = {}
    for scheme, data in schemes.items():
        x, a = data.state[rows], data.action[rows]
        x_rate, a_rate, target = data.state_rate[rows], data.action_rate[rows], data.next_state_rate[rows]
        step = 1e-6
        derivative = (plant.step(x + step * x_rate, a + step * a_rate)
                      - plant.step(x - step * x_rate, a - step * a_rate)) / (2 * step)
        parts = {}
        for part, columns in (("velocity_rows", slice(0, n)), ("acceleration_rows", slice(n, 2 * n))):
            difference = np.sqrt(np.mean((target[:, columns] - derivative[:, columns]) ** 2))
            parts[part] = float(difference / np.sqrt(np.mean(derivative[:, columns] ** 2)))
        result[scheme] = parts
    result["transitions"] = int(transitions)
    return result


@dataclasses.dataclass(frozen=True)
class Member:
    """One grid member of one pair, tested: MSE in rad² (q) and (rad/s)² (v); ratios baseline/model."""
    cell: str
    data_seed: int
    init: int
    scale: str
    alpha: float
    val_mse: float
    best_epoch: int
    epochs: int
    one_step_q: float
    one_step_v: float
    open_loop_q: float
    ratio_to_euler_q: float
    ratio_to_unchanged_v: float
    verdict: str
    extension: bool = False


def train_pair(cell: Cell, data_seed: int, init: int, profile: Profile, scales, grids: dict | None, extension: bool,
               path: str, content: bytes | None = None, sha256: str | None = None) -> dict:
    """Train one pair's grids (raw: RAW_GRID incl. naive, relative: RELATIVE_GRID; or `grids` {scale: alphas})
    on the cell's data and test every member: {"members": [Member], "train_rule": {scale: alpha train's rule picks
    (0: naive kept)}}. `extension`: the grids are the extension's single alphas (no naive, no rule). The dataset:
    `path`, or on a Ray cluster its bytes `content` and their `sha256` (top-level arguments: Ray hands over bytes)."""
    import torch

    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.learning.alpha_selection import member_errors_by_group, naive_gain_bounds, train_alpha_grid
    from stdm_drake.learning.evaluate import compare_with_baselines, physics_baselines, trajectory_rollout_data
    from stdm_drake.learning.learned_model import LearnedModel
    from stdm_drake.learning.problem import training_problem
    from stdm_drake.learning.settings import TrainingConfig
    from stdm_drake.robots.robot import load_robot
    from stdm_drake.cluster import file_on_this_node
    torch.set_num_threads(1)
    grids = grids or dict(raw=RAW_GRID, relative=RELATIVE_GRID)
    dataset = load_dataset(file_on_this_node(path, content, sha256))
    split = split_of(cell, profile, dataset)
    robot = load_robot(cell.robot_file)
    structure = cell.model_structure
    problem = training_problem(dataset, split, model_type="DD", derivative_source="true", action_rate=cell.action_rate,
                               structure=structure, robot=robot, threads=1)
    epochs = min(cell.max_epochs, profile.epoch_cap or cell.max_epochs)
    test = split["test"]
    transitions, rollouts = dataset.transitions(test), trajectory_rollout_data(dataset, test, HORIZON)
    rows, errors = [], []
    for scale in scales:
        training = TrainingConfig(seed=init, max_epochs=epochs, alpha_scale=scale)
        result, selection = train_alpha_grid(problem.model_config, training, problem.train, problem.val,
                                             alphas=grids[scale])
        models = [LearnedModel(result.model.member(k), name=f"{scale} {alpha:g}", robot=robot, structure=structure,
                               sample_period=dataset.sample_period) for k, alpha in enumerate(selection.alphas)]
        baselines = physics_baselines(dataset.sample_period, robot.state_dim, robot.action_dim, plant=False)
        tested = compare_with_baselines(models + baselines, transitions, rollouts)[:len(models)]
        if not extension:
            errors.append(member_errors_by_group(result.model, problem.val))
        for k, (alpha, row) in enumerate(zip(selection.alphas, tested)):
            rows.append(Member(cell=cell.name, data_seed=data_seed, init=init, scale=scale, alpha=float(alpha),
                               val_mse=float(selection.val_mse[k]), best_epoch=int(selection.best_epochs[k]),
                               epochs=int(result.epochs_run), one_step_q=row.one_step.angle_mse,
                               one_step_v=row.one_step.velocity_mse, open_loop_q=float(row.multi_step.angle_mse[-1]),
                               ratio_to_euler_q=row.ratio_q, ratio_to_unchanged_v=row.ratio_v, verdict=row.verdict,
                               extension=extension))
    if extension:
        return dict(members=rows, train_rule={})
    # train's rule per scale: naive (the raw grid's alpha 0) and that scale's alphas > 0; an alpha > 0 only where its
    # validation gain over naive is above 0 at 95 % (paired over validation trajectories), then the lowest MSE
    rule = {}
    for position, scale in enumerate(scales):
        positive = [k for k, alpha in enumerate(grids[scale]) if alpha > 0]
        low = naive_gain_bounds(np.vstack([errors[0][0][None], errors[position][positive]]), 0)[1:]
        members = [row for row in rows if row.scale == scale and row.alpha > 0]
        clear = [row for row, bound in zip(members, low) if bound > 0]
        rule[scale] = min(clear, key=lambda row: row.val_mse).alpha if clear else 0.0
    return dict(members=rows, train_rule=rule)


def pair_cache(folder, cell: Cell, data_seed: int, init: int, profile: Profile, scales=SCALES,
               grids: dict | None = None, extension: bool = False) -> pathlib.Path:
    """Where the driver keeps a trained pair's result (JSON in `folder`/pairs, named by cell, data seed, init, scales,
    grids and the profile), so a run stopped part-way keeps what it trained and a rerun reads it back."""
    import hashlib
    design = json.dumps([dataclasses.asdict(profile), list(scales), {k: list(v) for k, v in (grids or {}).items()},
                         extension, RAW_GRID, RELATIVE_GRID], sort_keys=True, default=str)
    name = f"{cell.name}_seed{data_seed}_init{init}_{hashlib.sha256(design.encode()).hexdigest()[:12]}.json"
    return pathlib.Path(folder) / "pairs" / name


def read_pair(path: pathlib.Path) -> dict:
    stored = json.loads(path.read_text())
    return dict(members=[Member(**row) for row in stored["members"]], train_rule=stored["train_rule"])


def write_pair(path: pathlib.Path, result: dict) -> None:
    from stdm_drake.files import write_text_atomic
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(dict(members=[dataclasses.asdict(row) for row in result["members"]],
                                            train_rule=result["train_rule"])))


def nominal_plant_row(cell: Cell, data_seed: int, profile: Profile, path: str, content: bytes | None = None,
                      sha256: str | None = None) -> dict:
    """The nominal plant (the cell's robot description stepping the recorded torque) and the physics-free baselines
    on the cell's test trajectories of one dataset (`path`, or on Ray its bytes, as `train_pair`)."""
    from stdm_drake.cluster import file_on_this_node
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.learning.evaluate import compare_with_baselines, physics_baselines, trajectory_rollout_data
    from stdm_drake.robots.robot import load_robot
    dataset = load_dataset(file_on_this_node(path, content, sha256))
    robot = load_robot(cell.robot_file)
    test = split_of(cell, profile, dataset)["test"]
    rows = compare_with_baselines(physics_baselines(dataset.sample_period, robot.state_dim, robot.action_dim,
                                                    robot=robot,
                                                    plant_config=dataset.metadata.plant_config(effects=False)),
                                  dataset.transitions(test),
                                  trajectory_rollout_data(dataset, test, HORIZON))
    return dict(data=cell.data, split_of=cell.name, data_seed=data_seed, **{row.name: dict(
        one_step_q=row.one_step.angle_mse, one_step_v=row.one_step.velocity_mse,
        open_loop_q=float(row.multi_step.angle_mse[-1])) for row in rows})


def chosen(rows: list[Member], cell: str, scale: str, seeds, inits, extended: bool) -> dict:
    """DD of `scale` per (data seed, init): the alpha > 0 member of the lowest validation MSE (extension members
    included when the grid was extended)."""
    picked = {}
    for seed in seeds:
        for init in inits:
            candidates = [r for r in rows if r.cell == cell and r.scale == scale and r.alpha > 0 and r.data_seed == seed
                          and r.init == init and (extended or not r.extension)]
            if candidates:
                picked[(seed, init)] = min(candidates, key=lambda r: r.val_mse)
    return picked


def two_level(base: dict, method: dict, key: str) -> dict:
    """Ratio base/method per (data seed, init) pair, log-averaged over inits per data seed, then a Student-t 95 %
    interval and two-sided p-value over the data seeds' means."""
    from scipy import stats
    per_seed = {}
    for pair, row in base.items():
        if pair in method:
            per_seed.setdefault(pair[0], []).append(math.log(getattr(row, key) / getattr(method[pair], key)))
    means = np.array([np.mean(values) for values in per_seed.values()])
    mean = float(means.mean())
    if len(means) < 2 or means.std(ddof=1) == 0:
        return dict(ratio=math.exp(mean), low=0.0 if len(means) < 2 else math.exp(mean),
                    high=math.inf if len(means) < 2 else math.exp(mean), p=1.0 if mean == 0 or len(means) < 2 else 0.0,
                    data_seeds=len(means))
    spread = means.std(ddof=1) / math.sqrt(len(means))
    half = float(stats.t.ppf(0.975, len(means) - 1) * spread)
    p = float(2 * stats.t.sf(abs(mean) / spread, len(means) - 1))
    return dict(ratio=math.exp(mean), low=math.exp(mean - half), high=math.exp(mean + half), p=p,
                data_seeds=len(means))


def holm(p_values: list[float]) -> list[float]:
    """Holm-adjusted p-values (step-down, monotone), in the input's order."""
    order = np.argsort(p_values)
    adjusted, running = [0.0] * len(p_values), 0.0
    for rank, index in enumerate(order):
        running = max(running, min(1.0, (len(p_values) - rank) * p_values[index]))
        adjusted[index] = running
    return adjusted


def verdict(gated: bool, q: dict, v: dict) -> str:
    """docs/settling.md's rule on the one-step q and v ratios (with their Holm-adjusted p-values)."""
    if not gated:
        return "uninformative (naive has not learned)"
    if all(r["ratio"] >= 3 and r["low"] >= 2 for r in (q, v)):
        return "the paper reproduces"
    better = [r["p_holm"] < 0.05 and r["ratio"] > 1 for r in (q, v)]
    worse = [r["p_holm"] < 0.05 and r["ratio"] < 1 for r in (q, v)]
    if any(better) and any(worse):
        return "mixed"
    if any(better):
        return "helps"
    if any(worse):
        return "hurts"
    if all(0.8 <= r["low"] and r["high"] <= 1.25 for r in (q, v)):
        return "no help"
    return "inconclusive"


def summarize(cells, rows: list[Member], rules: dict, profile: Profile, extended: dict) -> list[dict]:
    """Per cell: the gate, per scale DD's two-level ratios with Holm-adjusted p-values and the verdict, the alpha
    choices, train's rule (`rules`: {scale: {(cell, data seed, init): alpha}}), and every grid alpha's ratio to D."""
    summary = []
    for cell in cells:
        naive = {(r.data_seed, r.init): r for r in rows if r.cell == cell.name and r.alpha == 0 and r.scale == "raw"}
        if not naive:
            continue
        gate_q = float(np.exp(np.mean([np.log(r.ratio_to_euler_q) for r in naive.values()])))
        gate_v = float(np.exp(np.mean([np.log(r.ratio_to_unchanged_v) for r in naive.values()])))
        gated = gate_q >= 2 and gate_v >= 2
        scales, tests = {}, []
        for scale in SCALES:
            picked = chosen(rows, cell.name, scale, profile.data_seeds, profile.inits, extended.get((cell.name, scale),
                                                                                                  False))
            ratios = {label: two_level(naive, picked, key) for key, label in ENDPOINTS}
            tests += [ratios[label] for _, label in ENDPOINTS]
            alphas = [r.alpha for r in picked.values()]
            picks = {(key[1], key[2]): alpha for key, alpha in rules.get(scale, {}).items() if key[0] == cell.name}
            rule_pairs = {pair: naive[pair] if alpha == 0 else next(
                r for r in rows if r.cell == cell.name and r.scale == scale and (r.data_seed, r.init) == pair
                and r.alpha == alpha) for pair, alpha in picks.items()}
            per_alpha = {}
            for alpha in sorted({r.alpha for r in rows if r.cell == cell.name and r.scale == scale and r.alpha > 0}):
                members = {(r.data_seed, r.init): r for r in rows
                           if r.cell == cell.name and r.scale == scale and r.alpha == alpha}
                per_alpha[f"{alpha:g}"] = {label: two_level(naive, members, key) for key, label in ENDPOINTS}
            scales[scale] = dict(
                DD=ratios, chosen_alphas={f"{a:g}": alphas.count(a) for a in sorted(set(alphas))},
                grid_extended=extended.get((cell.name, scale), False),
                DD_verdicts=[r.verdict for r in picked.values()],
                train_rule=dict(kept_naive=sum(1 for alpha in picks.values() if alpha == 0), pairs=len(picks),
                                ratios={label: two_level(naive, rule_pairs, key) for key, label in ENDPOINTS}),
                per_alpha=per_alpha)
        for test, adjusted in zip(tests, holm([t["p"] for t in tests])):
            test["p_holm"] = adjusted
        for scale in SCALES:
            ratios = scales[scale]["DD"]
            scales[scale]["verdict"] = verdict(gated, ratios["one-step q"], ratios["one-step v"])
        summary.append(dict(cell=cell.name, data=cell.data, structure=cell.structure, action_rate=cell.action_rate,
                            naive_vs_euler_q=gate_q, naive_vs_unchanged_v=gate_v, gated=gated, scales=scales))
    return summary


def needs_extension(rows: list[Member], cell: Cell, scale: str, profile: Profile) -> bool:
    """docs/settling.md's rule: the grid's largest alpha chosen in more than a third of the cell's grids."""
    picked = chosen(rows, cell.name, scale, profile.data_seeds, profile.inits, False)
    largest = max((RAW_GRID if scale == "raw" else RELATIVE_GRID))
    return sum(1 for r in picked.values() if r.alpha == largest) * 3 > len(picked)


def collect_datasets(kinds, profile: Profile, data: pathlib.Path, pool) -> tuple[dict, dict]:
    """Every data kind's dataset per data seed in `data` (collected on `pool` where missing): ({(kind, seed): path},
    {(kind, seed): what a task gets of it}: on Ray each file's bytes once into the object store, a scratch copy
    per node; locally the path itself)."""
    from stdm_drake.cluster import shared_file, task_error
    from stdm_drake.files import atomic_path
    data.mkdir(parents=True, exist_ok=True)
    paths = {(kind, seed): data / dataset_name(kind, seed, profile.counts[kind])
             for kind in kinds for seed in profile.data_seeds}
    futures = {key: pool.submit(collect, key[0], key[1], profile.counts[key[0]])
               for key, path in paths.items() if not path.exists()}
    for key, future in futures.items():
        try:
            content = future.result()
        except Exception as error:
            raise task_error(error, f"collecting {key[0]} data seed {key[1]}") from None
        with atomic_path(paths[key]) as temp:
            temp.write_bytes(content)
    return paths, {key: (str(path), *shared_file(pool, path)) for key, path in paths.items()}


def run_study(cells, profile: Profile, data: pathlib.Path, runner, progress=print) -> dict:
    """Collect, run the chain-rule check, train every pair's grids and the extensions the rule asks for, test the
    nominal plant; returns {"chain_rule", "runs", "plant", "summary", "extended", "seconds"}."""
    from stdm_drake.cluster import job_pool, task_error
    if runner.backend == "ray":   # this module's functions travel with the tasks, by value
        from stdm_drake.cluster import import_ray
        import_ray()
        import ray.cloudpickle
        ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    started = time.perf_counter()
    kinds = sorted({cell.data for cell in cells})
    with job_pool(runner) as pool:
        paths, sources = collect_datasets(kinds, profile, data, pool)
        progress(f"{len(paths)} datasets in {time.perf_counter() - started:.0f} s")
        check = None
        if "literal" in kinds:
            check = chain_rule_check(str(paths[("literal", profile.data_seeds[0])]),
                                     transitions=400 if profile is FULL else 50)
            progress(f"chain-rule check: {check}")
        rows, rules = [], {scale: {} for scale in SCALES}

        def collect_pair(key, result, cache):
            nonlocal rows
            rows += result["members"]
            for scale, alpha in result["train_rule"].items():
                rules[scale][key] = alpha
            if cache is not None:
                write_pair(cache, result)

        jobs = {}
        for cell in cells:
            for seed in profile.data_seeds:
                for init in profile.inits:
                    cache = pair_cache(data, cell, seed, init, profile)
                    if cache.exists():
                        collect_pair((cell.name, seed, init), read_pair(cache), None)
                    else:
                        jobs[pool.submit(train_pair, cell, seed, init, profile, SCALES, None, False,
                                         *sources[(cell.data, seed)])] = ((cell.name, seed, init), cache)
        first = {}   # one cell per data kind: the nominal plant on its test trajectories
        for cell in cells:
            first.setdefault(cell.data, cell)
        plants = [pool.submit(nominal_plant_row, cell, seed, profile, *sources[(cell.data, seed)])
                  for cell in first.values() for seed in profile.data_seeds]
        for finished, future in enumerate(concurrent.futures.as_completed(jobs), start=1):
            key, cache = jobs[future]
            try:
                collect_pair(key, future.result(), cache)
            except Exception as error:
                raise task_error(error, "pair {} data seed {} init {}".format(*key)) from None
            if finished % 6 == 0:
                progress(f"{finished}/{len(jobs)} pairs trained ({time.perf_counter() - started:.0f} s)")
        extended = {(cell.name, scale): needs_extension(rows, cell, scale, profile) for cell in cells for scale in SCALES}
        extra = {}
        for cell in cells:
            for scale in SCALES:
                if not extended[(cell.name, scale)]:
                    continue
                grids = {scale: (EXTENSION[scale],)}
                for seed in profile.data_seeds:
                    for init in profile.inits:
                        cache = pair_cache(data, cell, seed, init, profile, (scale,), grids, True)
                        if cache.exists():
                            rows += read_pair(cache)["members"]
                        else:
                            extra[pool.submit(train_pair, cell, seed, init, profile, (scale,), grids, True,
                                              *sources[(cell.data, seed)])] = ((cell.name, seed, init, scale), cache)
        if any(extended.values()):
            progress(f"grid extension: {sorted(f'{cell} {scale}' for (cell, scale), on in extended.items() if on)}")
        for future in concurrent.futures.as_completed(extra):
            key, cache = extra[future]
            try:
                result = future.result()
            except Exception as error:
                raise task_error(error, "extension {} data seed {} init {} ({})".format(*key)) from None
            rows += result["members"]
            write_pair(cache, result)
        plant_rows = [future.result() for future in plants]
    names = [cell.name for cell in cells]
    rows.sort(key=lambda r: (names.index(r.cell), r.data_seed, r.init, SCALES.index(r.scale), r.alpha))
    return dict(chain_rule=check, runs=rows, plant=plant_rows, extended=extended,
                train_rule={scale: [dict(cell=key[0], data_seed=key[1], init=key[2], alpha=alpha)
                                    for key, alpha in picks.items()] for scale, picks in rules.items()},
                summary=summarize(cells, rows, rules, profile, extended), seconds=round(time.perf_counter() - started, 1))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from stdm_drake.cluster import add_runner_arguments
    parser.add_argument("-o", "--output", type=pathlib.Path, default=ROOT / "docs" / "results" / "settling")
    parser.add_argument("--data", type=pathlib.Path, default=ROOT / "out" / "settling_data")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--quick", action="store_true",
                        help="2 cells, 2 data seeds x 2 initializations, small splits, 5 epochs (a pipeline check)")
    parser.add_argument("--plant-rows", action="store_true",
                        help="only the nominal plant's rows (the datasets collected into --data as the study does): "
                             "OUTPUT/plant_rows.json with the commit it ran on, results.json left as it is")
    add_runner_arguments(parser)


def flat_rows(summary: list[dict]) -> list[dict]:
    """One CSV row per cell and scale."""
    rows = []
    for s in summary:
        for scale, values in s["scales"].items():
            row = dict(cell=s["cell"], scale=scale, gated=s["gated"], naive_vs_euler_q=s["naive_vs_euler_q"],
                       naive_vs_unchanged_v=s["naive_vs_unchanged_v"], verdict=values["verdict"],
                       grid_extended=values["grid_extended"],
                       chosen_alphas=" ".join(f"{a}:{n}" for a, n in values["chosen_alphas"].items()),
                       train_rule_kept_naive=f"{values['train_rule']['kept_naive']}/{values['train_rule']['pairs']}")
            for _, label in ENDPOINTS:
                for part in ("ratio", "low", "high", "p", "p_holm"):
                    row[f"D/DD {label} {part}"] = values["DD"][label][part]
            rows.append(row)
    return rows


def markdown(summary: list[dict], chain_rule: dict | None) -> str:
    """results.md: the verdict table (one row per cell and scale) and the chain-rule check."""
    def ratio(r):
        return f"{r['ratio']:.3g}x [{r['low']:.3g}, {r['high']:.3g}] (p {r['p_holm']:.2g})"
    lines = ["| cell | naive vs Euler q / vs 'v unchanged' v | scale | alphas chosen (pairs) | D/DD one-step q | "
             "D/DD one-step v | D/DD q at step 20 | verdict | train's rule kept naive |", "|---" * 9 + "|"]
    for s in summary:
        for scale, values in s["scales"].items():
            chosen = ", ".join(f"{a}: {n}" for a, n in values["chosen_alphas"].items())
            extended = " (grid extended)" if values["grid_extended"] else ""
            lines.append(f"| {s['cell']} | {s['naive_vs_euler_q']:.3g}x / {s['naive_vs_unchanged_v']:.3g}x | {scale} | "
                         f"{chosen}{extended} | " + " | ".join(ratio(values["DD"][label]) for _, label in ENDPOINTS)
                         + f" | {values['verdict']} | {values['train_rule']['kept_naive']} of "
                         f"{values['train_rule']['pairs']} |")
    lines += ["", "Ratios MSE(D)/MSE(DD), > 1: derivative learning has the lower error; two-level 95 % intervals "
              "over data seeds; p: Holm-adjusted over the cell's 6 tests."]
    if chain_rule:
        lines += ["", "Chain-rule check (relative RMS difference between the targets and the simulator step's time "
                  f"derivative, {chain_rule['transitions']} transitions): " + "; ".join(
                      f"{scheme}: q̇ rows {values['velocity_rows']:.3g}, q̈ rows {values['acceleration_rows']:.3g}"
                      for scheme, values in chain_rule.items() if scheme != "transitions")]
    return "\n".join(lines) + "\n"


def plant_rows(cells, profile: Profile, data: pathlib.Path, runner, progress=print) -> list[dict]:
    """The nominal plant's rows of `run_study` alone (issue 55: recomputed after the plant baseline came to step
    the plant each dataset records): the datasets collected into `data` as the study collects them, the nominal
    plant and the physics-free baselines on one cell's test trajectories per data kind and data seed."""
    from stdm_drake.cluster import job_pool
    first = {}
    for cell in cells:
        first.setdefault(cell.data, cell)
    with job_pool(runner) as pool:
        paths, sources = collect_datasets(sorted(first), profile, data, pool)
        progress(f"{len(paths)} datasets ready")
        futures = [pool.submit(nominal_plant_row, cell, seed, profile, *sources[(cell.data, seed)])
                   for cell in first.values() for seed in profile.data_seeds]
        return [future.result() for future in futures]


def run(args: argparse.Namespace) -> int:
    from stdm_drake.cluster import runner_config_from_args
    from stdm_drake.files import json_default, rows_csv, write_text_atomic
    runner = runner_config_from_args(args)
    profile, cells = (QUICK, (CELLS[0], CELLS[3])) if args.quick else (FULL, CELLS)
    if args.plant_rows:
        rows = plant_rows(cells, profile, args.data, runner, progress=lambda text: print(text, flush=True))
        args.output.mkdir(parents=True, exist_ok=True)
        write_text_atomic(args.output / "plant_rows.json", json.dumps(dict(
            written_by="tools/study.py settling --plant-rows", provenance=args.provenance, quick=args.quick,
            profile=dataclasses.asdict(profile), plant=rows), indent=2, default=json_default) + "\n")
        for row in rows:
            print(f"{row['data']} seed {row['data_seed']}: " + "; ".join(
                f"{name} one-step q {values['one_step_q']:.3g} v {values['one_step_v']:.3g}, step {HORIZON} q "
                f"{values['open_loop_q']:.3g}" for name, values in row.items() if isinstance(values, dict)))
        return 0
    study = run_study(cells, profile, args.data, runner, progress=lambda text: print(text, flush=True))
    args.output.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.output / "runs.csv", rows_csv([dataclasses.asdict(row) for row in study["runs"]]))
    write_text_atomic(args.output / "cells.csv", rows_csv(flat_rows(study["summary"])))
    write_text_atomic(args.output / "results.md", markdown(study["summary"], study["chain_rule"]))
    write_text_atomic(args.output / "results.json", json.dumps(dict(
        written_by="tools/study.py settling", provenance=args.provenance, quick=args.quick, design="docs/settling.md",
        profile=dataclasses.asdict(profile), raw_grid=RAW_GRID, relative_grid=RELATIVE_GRID, extension=EXTENSION,
        horizon=HORIZON, cells=[dataclasses.asdict(c) for c in cells], seconds=study["seconds"],
        chain_rule=study["chain_rule"], extended=[f"{cell} {scale}" for (cell, scale), on in study["extended"].items()
                                                  if on],
        summary=study["summary"], plant=study["plant"], train_rule=study["train_rule"], runs=study["runs"]), indent=2, default=json_default) + "\n")
    for s in study["summary"]:
        print(f"\n{s['cell']}: naive vs Euler q {s['naive_vs_euler_q']:.3g}x, vs 'v unchanged' "
              f"{s['naive_vs_unchanged_v']:.3g}x")
        for scale, values in s["scales"].items():
            print(f"  {scale:>8}: {values['verdict']}; alphas chosen {values['chosen_alphas']}; train's rule kept naive "
                  f"{values['train_rule']['kept_naive']}/{values['train_rule']['pairs']}")
            for _, label in ENDPOINTS:
                r = values["DD"][label]
                print(f"    D/DD {label:>14}: {r['ratio']:.3g}x [{r['low']:.3g}, {r['high']:.3g}] p_holm {r['p_holm']:.2g}")
    print(f"\n{len(study['runs'])} members in {study['seconds']:.0f} s -> {args.output}")
    return 0
