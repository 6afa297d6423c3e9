"""Sample efficiency and activations: naive against derivative learning with alpha by validation at 4-40 training plans, swish and tanh.

Design, endpoints, intervals, multiplicity, gate and verdict rules: docs/sample_efficiency.md (committed before any
of its models trained). 16 cells (data kind tracked | identification, N in 4, 12, 20, 40 training plans, swish |
tanh); per cell 4 data seeds x 2 initializations, each pair one raw alpha grid trained as a stack (member k = alpha_k
alone), D = the alpha 0 member, DD = the alpha > 0 member of the lowest validation MSE. The verdict tables and
intervals are the settling study's (`studies.settling`). Runs on the local pool or a Ray cluster.

    python tools/study.py sample-efficiency [--quick] [--workers 2] [-o docs/results/sample_efficiency]
        [--data out/sample_efficiency_data]
"""
from __future__ import annotations

import argparse
import concurrent.futures
import dataclasses
import json
import pathlib
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
HORIZON = 20
GRID = (0.0, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1)
KINDS = ("tracked", "identification")
ACTIVATIONS = ("swish", "tanh")
ENDPOINTS = (("one_step_q", "one-step q"), ("one_step_v", "one-step v"), ("open_loop_q", f"q at step {HORIZON}"))
PAPER_SIZES = (4, 12, 20)          # Fig. 17's training sizes


@dataclasses.dataclass(frozen=True)
class Profile:
    """Sizes: plans per dataset, per start pose the validation, test and pool counts, training sizes, seeds."""
    plans: int
    per_pose: tuple          # (validation, test, pool) plans per start pose
    sizes: tuple
    kinds: tuple
    activations: tuple
    data_seeds: tuple
    inits: tuple
    max_epochs: int


FULL = Profile(plans=100, per_pose=(5, 10, 10), sizes=(4, 12, 20, 40), kinds=KINDS, activations=ACTIVATIONS,
               data_seeds=(200, 201, 202, 203), inits=(0, 1), max_epochs=300)
QUICK = Profile(plans=20, per_pose=(1, 1, 3), sizes=(4, 8), kinds=("tracked",), activations=("swish",),
                data_seeds=(200, 201), inits=(0,), max_epochs=5)


@dataclasses.dataclass(frozen=True)
class Cell:
    kind: str
    size: int
    activation: str

    @property
    def name(self) -> str:
        return f"{self.kind}-N{self.size}-{self.activation}"


def cells(profile: Profile) -> list[Cell]:
    return [Cell(kind, size, activation) for kind in profile.kinds for size in profile.sizes
            for activation in profile.activations]


def split_of(groups, profile: Profile, size: int) -> dict:
    """{train, val, test} trajectory indices: per start pose (group) its plans in a fixed order (seed 0), the first
    `validation` validate, the next `test` test, and training takes the first size/poses of the rest (nested)."""
    poses = sorted(set(int(g) for g in groups))
    validation, test, pool = profile.per_pose
    if size % len(poses) or size // len(poses) > pool:
        raise ValueError(f"{size} training plans do not split evenly over {len(poses)} poses of {pool}")
    split = dict(train=[], val=[], test=[])
    for pose in poses:
        members = [i for i, g in enumerate(groups) if int(g) == pose]
        order = [members[i] for i in np.random.default_rng(0).permutation(len(members))]
        split["val"] += order[:validation]
        split["test"] += order[validation:validation + test]
        split["train"] += order[validation + test:validation + test + size // len(poses)]
    return {key: sorted(value) for key, value in split.items()}


def collect(kind: str, data_seed: int, plans: int, folder: str) -> str:
    """The dataset of `kind` (docs/sample_efficiency.md, Data) for `data_seed` in `folder`; its path."""
    from stdm_drake.experiments.jobs import ensure_dataset
    robot = str(ROOT / "models" / "ur10.yaml")
    if kind == "tracked":
        dataset = ensure_dataset("tracking", plans, data_seed, pathlib.Path(folder), False, name="tracked", robot=robot)
    else:
        dataset = ensure_dataset("tracking", plans, data_seed, pathlib.Path(folder), False, name="identification",
                                 robot=robot, controller=str(ROOT / "controllers" / "pid_dither.yaml"),
                                 sensor=str(ROOT / "controllers" / "sensor_ideal.yaml"))
    return str(dataset.path)


def train_pair(cell: Cell, data_seed: int, init: int, profile: Profile, path: str) -> dict:
    """One pair's alpha grid on the cell's data, every member tested: {"members": [row], "rule_alpha": alpha of
    train's rule (0: naive kept)}. Rows: MSE in rad² (q) and (rad/s)² (v), the baselines' ratios, the verdict."""
    import torch

    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.learning.alpha_selection import member_errors_by_group, naive_gain_bounds, train_alpha_grid
    from stdm_drake.learning.evaluate import compare_with_baselines, physics_baselines, trajectory_rollout_data
    from stdm_drake.learning.learned_model import LearnedModel
    from stdm_drake.learning.problem import training_problem
    from stdm_drake.learning.settings import TrainingConfig
    from stdm_drake.learning.structure import DEFAULT
    from stdm_drake.robots.robot import load_robot
    torch.set_num_threads(1)
    dataset = load_dataset(path)
    split = split_of(dataset.groups, profile, cell.size)
    robot = load_robot(ROOT / "models" / "ur10.yaml")
    problem = training_problem(dataset, split, model_type="DD", activation=cell.activation, structure=DEFAULT,
                               robot=robot, threads=1)
    training = TrainingConfig(seed=init, max_epochs=profile.max_epochs)
    result, selection = train_alpha_grid(problem.model_config, training, problem.train, problem.val, alphas=GRID)
    models = [LearnedModel(result.model.member(k), name=f"alpha {alpha:g}", robot=robot, structure=DEFAULT,
                           sample_period=dataset.sample_period) for k, alpha in enumerate(selection.alphas)]
    baselines = physics_baselines(dataset.sample_period, robot.state_dim, robot.action_dim, plant=False)
    tested = compare_with_baselines(models + baselines, dataset.transitions(split["test"]),
                                    trajectory_rollout_data(dataset, split["test"], HORIZON))[:len(models)]
    rows = [dict(cell=cell.name, kind=cell.kind, size=cell.size, activation=cell.activation, data_seed=data_seed,
                 init=init, alpha=float(alpha), val_mse=float(selection.val_mse[k]),
                 best_epoch=int(selection.best_epochs[k]), epochs=int(result.epochs_run),
                 one_step_q=row.one_step.angle_mse, one_step_v=row.one_step.velocity_mse,
                 open_loop_q=float(row.multi_step.angle_mse[-1]), ratio_to_euler_q=row.ratio_q,
                 ratio_to_unchanged_v=row.ratio_v, verdict=row.verdict)
            for k, (alpha, row) in enumerate(zip(selection.alphas, tested))]
    errors = member_errors_by_group(result.model, problem.val)
    positive = [k for k, alpha in enumerate(GRID) if alpha > 0]
    low = naive_gain_bounds(errors, 0)
    clear = [rows[k] for k in positive if low[k] > 0]
    rule_alpha = min(clear, key=lambda row: row["val_mse"])["alpha"] if clear else 0.0
    return dict(members=rows, rule_alpha=rule_alpha, derivative_source=dataset.default_derivative_source)


def plant_row(kind: str, data_seed: int, profile: Profile, path: str) -> dict:
    """The nominal plant (the description that simulated the data, stepping the recorded torque) and the
    physics-free baselines on the dataset's test trajectories."""
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.learning.evaluate import compare_with_baselines, physics_baselines, trajectory_rollout_data
    from stdm_drake.robots.robot import load_robot
    dataset = load_dataset(path)
    robot = load_robot(ROOT / "models" / "ur10.yaml")
    test = split_of(dataset.groups, profile, profile.sizes[0])["test"]
    rows = compare_with_baselines(physics_baselines(dataset.sample_period, robot.state_dim, robot.action_dim,
                                                    robot=robot, plant_config=dataset.metadata.plant_config(effects=False)),
                                  dataset.transitions(test), trajectory_rollout_data(dataset, test, HORIZON))
    return dict(kind=kind, data_seed=data_seed, **{row.name: dict(
        one_step_q=row.one_step.angle_mse, one_step_v=row.one_step.velocity_mse,
        open_loop_q=float(row.multi_step.angle_mse[-1])) for row in rows})


class Row:
    """A member row as attributes (what `settling.two_level` reads)."""
    def __init__(self, values: dict):
        self.__dict__.update(values)


def summarize(all_cells: list[Cell], members: list[dict], rules: dict, profile: Profile) -> list[dict]:
    """Per cell: the gate, DD's two-level ratios with Holm-adjusted p-values, the verdict, the alphas chosen (and
    whether at the grid's edge), train's rule, every alpha's ratio to D."""
    from studies.settling import holm, two_level, verdict
    summary = []
    for cell in all_cells:
        rows = [Row(m) for m in members if m["cell"] == cell.name]
        naive = {(r.data_seed, r.init): r for r in rows if r.alpha == 0}
        if not naive:
            continue
        picked = {pair: min((r for r in rows if (r.data_seed, r.init) == pair and r.alpha > 0), key=lambda r: r.val_mse)
                  for pair in naive}
        gate_q = float(np.exp(np.mean([np.log(r.ratio_to_euler_q) for r in naive.values()])))
        gate_v = float(np.exp(np.mean([np.log(r.ratio_to_unchanged_v) for r in naive.values()])))
        gated = gate_q >= 2 and gate_v >= 2
        ratios = {label: two_level(naive, picked, key) for key, label in ENDPOINTS}
        for test, adjusted in zip(ratios.values(), holm([t["p"] for t in ratios.values()])):
            test["p_holm"] = adjusted
        alphas = [r.alpha for r in picked.values()]
        positive = [a for a in GRID if a > 0]
        edge = sum(a in (positive[0], positive[-1]) for a in alphas) * 3 > len(alphas)
        rule = {key[1:]: alpha for key, alpha in rules.items() if key[0] == cell.name}
        rule_rows = {pair: naive[pair] if alpha == 0 else next(
            r for r in rows if (r.data_seed, r.init) == pair and r.alpha == alpha) for pair, alpha in rule.items()}
        per_alpha = {f"{alpha:g}": {label: two_level(naive, {(r.data_seed, r.init): r for r in rows if r.alpha == alpha},
                                                     key) for key, label in ENDPOINTS} for alpha in positive
                     if any(r.alpha == alpha for r in rows)}
        summary.append(dict(cell=cell.name, kind=cell.kind, size=cell.size, activation=cell.activation,
                            naive_vs_euler_q=gate_q, naive_vs_unchanged_v=gate_v, gated=gated, DD=ratios,
                            verdict=verdict(gated, ratios["one-step q"], ratios["one-step v"]),
                            chosen_alphas={f"{a:g}": alphas.count(a) for a in sorted(set(alphas))},
                            alpha_at_grid_edge=edge, DD_verdicts=[r.verdict for r in picked.values()],
                            train_rule=dict(kept_naive=sum(1 for a in rule.values() if a == 0), pairs=len(rule),
                                            ratios={label: two_level(naive, rule_rows, key) for key, label in ENDPOINTS}),
                            per_alpha=per_alpha,
                            naive_mse={key: float(np.exp(np.mean([np.log(getattr(r, key)) for r in naive.values()])))
                                       for key, _ in ENDPOINTS}))
    return summary


def claims(summary: list[dict], profile: Profile) -> dict:
    """docs/sample_efficiency.md's two rules: the sample-efficiency claim per data kind (swish, sizes 4, 12, 20),
    and the activation finding per data kind and size."""
    by_cell = {(s["kind"], s["size"], s["activation"]): s for s in summary}
    result = {"sample_efficiency": {}, "activation": {}}
    for kind in profile.kinds:
        verdicts = [by_cell[(kind, size, "swish")]["verdict"] for size in PAPER_SIZES if (kind, size, "swish") in by_cell]
        helps = sum(v in ("helps", "the paper reproduces") for v in verdicts)
        harmful = sum(v in ("hurts", "mixed") for v in verdicts)
        if verdicts and helps == len(verdicts) and len(verdicts) == len(PAPER_SIZES):
            claim = "supported"
        elif helps and not harmful:
            claim = "partly supported"
        elif "hurts" in verdicts and not helps:
            claim = "contradicted"
        elif helps and harmful:
            claim = "mixed"
        else:
            claim = "not shown"
        result["sample_efficiency"][kind] = dict(claim=claim, verdicts=dict(zip(
            [size for size in PAPER_SIZES if (kind, size, "swish") in by_cell], verdicts)))
        for size in profile.sizes:
            tanh, swish = by_cell.get((kind, size, "tanh")), by_cell.get((kind, size, "swish"))
            if tanh is None or swish is None:
                continue

            def direction(s):
                r = s["DD"]["one-step q"]
                return "better" if r["p_holm"] < 0.05 and r["ratio"] > 1 else "worse" if r["p_holm"] < 0.05 else "neither"
            found = ("uninformative" if not (tanh["gated"] and swish["gated"])
                     else "reproduces" if direction(tanh) == "worse" and direction(swish) != "worse"
                     else "does not reproduce" if direction(tanh) == "better" or direction(swish) == "worse"
                     else "not shown")
            result["activation"][f"{kind} N{size}"] = dict(finding=found, tanh=tanh["verdict"], swish=swish["verdict"],
                                                           tanh_q=direction(tanh), swish_q=direction(swish))
    return result


def run_study(profile: Profile, data: pathlib.Path, runner, progress=print) -> dict:
    """Collect the datasets, train every pair's grid (each pair's result kept in `data`/pairs, read back on a rerun),
    test the nominal plant; {"runs", "plant", "summary", "claims", "seconds"}."""
    from stdm_drake.cluster import job_pool, task_error
    from stdm_drake.files import write_text_atomic
    started = time.perf_counter()
    data.mkdir(parents=True, exist_ok=True)
    all_cells = cells(profile)
    tag = f"{profile.max_epochs}e_{profile.plans}p_{'-'.join(map(str, profile.per_pose))}"
    with job_pool(runner) as pool:
        keys = [(kind, seed) for kind in profile.kinds for seed in profile.data_seeds]
        futures = {key: pool.submit(collect, key[0], key[1], profile.plans, str(data)) for key in keys}
        paths = {}
        for key, future in futures.items():
            try:
                paths[key] = future.result()
            except Exception as error:
                raise task_error(error, f"collecting {key[0]} data seed {key[1]}") from None
        progress(f"{len(paths)} datasets in {time.perf_counter() - started:.0f} s")
        members, rules, jobs = [], {}, {}
        for cell in all_cells:
            for seed in profile.data_seeds:
                for init in profile.inits:
                    cache = data / "pairs" / f"{cell.name}_seed{seed}_init{init}_{tag}.json"
                    if cache.exists():
                        stored = json.loads(cache.read_text())
                        members += stored["members"]
                        rules[(cell.name, seed, init)] = stored["rule_alpha"]
                    else:
                        jobs[pool.submit(train_pair, cell, seed, init, profile, paths[(cell.kind, seed)])] = (
                            (cell.name, seed, init), cache)
        plants = [pool.submit(plant_row, kind, seed, profile, path) for (kind, seed), path in paths.items()]
        for finished, future in enumerate(concurrent.futures.as_completed(jobs), start=1):
            key, cache = jobs[future]
            try:
                result = future.result()
            except Exception as error:
                raise task_error(error, "pair {} data seed {} init {}".format(*key)) from None
            members += result["members"]
            rules[key] = result["rule_alpha"]
            cache.parent.mkdir(parents=True, exist_ok=True)
            write_text_atomic(cache, json.dumps(result))
            if finished % 8 == 0 or finished == len(jobs):
                progress(f"{finished}/{len(jobs)} pairs trained ({time.perf_counter() - started:.0f} s)")
        plant_rows = [future.result() for future in plants]
    names = [cell.name for cell in all_cells]
    members.sort(key=lambda r: (names.index(r["cell"]), r["data_seed"], r["init"], r["alpha"]))
    summary = summarize(all_cells, members, rules, profile)
    return dict(runs=members, plant=plant_rows, summary=summary, claims=claims(summary, profile),
                train_rule=[dict(cell=k[0], data_seed=k[1], init=k[2], alpha=a) for k, a in rules.items()],
                seconds=round(time.perf_counter() - started, 1))


def markdown(summary: list[dict], found: dict) -> str:
    """results.md: one row per cell, then the two claims."""
    def ratio(r):
        return f"{r['ratio']:.3g}x [{r['low']:.3g}, {r['high']:.3g}] (p {r['p_holm']:.2g})"
    lines = ["| data | N | activation | naive vs Euler q / vs 'v unchanged' v | alphas chosen (pairs) | D/DD one-step q | "
             "D/DD one-step v | D/DD q at step 20 | verdict | train's rule kept naive |", "|---" * 10 + "|"]
    for s in summary:
        chosen = ", ".join(f"{a}: {n}" for a, n in s["chosen_alphas"].items())
        edge = " (at the grid's edge)" if s["alpha_at_grid_edge"] else ""
        lines.append(f"| {s['kind']} | {s['size']} | {s['activation']} | {s['naive_vs_euler_q']:.3g}x / "
                     f"{s['naive_vs_unchanged_v']:.3g}x | {chosen}{edge} | "
                     + " | ".join(ratio(s["DD"][label]) for _, label in ENDPOINTS)
                     + f" | {s['verdict']} | {s['train_rule']['kept_naive']} of {s['train_rule']['pairs']} |")
    lines += ["", "Ratios MSE(D)/MSE(DD), > 1: derivative learning has the lower error; two-level 95 % intervals over "
              "data seeds; p: Holm-adjusted over the cell's 3 tests.", ""]
    lines += [f"- sample efficiency ({kind}): **{v['claim']}** ({v['verdicts']})" for kind, v in
              found["sample_efficiency"].items()]
    lines += [f"- activation finding ({key}): **{v['finding']}** (tanh {v['tanh']}, q {v['tanh_q']}; swish "
              f"{v['swish']}, q {v['swish_q']})" for key, v in found["activation"].items()]
    return "\n".join(lines) + "\n"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from stdm_drake.cluster import add_runner_arguments
    parser.add_argument("-o", "--output", type=pathlib.Path, default=ROOT / "docs" / "results" / "sample_efficiency")
    parser.add_argument("--data", type=pathlib.Path, default=ROOT / "out" / "sample_efficiency_data")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--quick", action="store_true",
                        help="one data kind, N 4 and 8, swish, 2 data seeds x 1 initialization, 5 epochs (a pipeline "
                             "check)")
    add_runner_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from stdm_drake.cluster import runner_config_from_args
    from stdm_drake.files import json_default, rows_csv, write_text_atomic
    runner = runner_config_from_args(args)
    profile = QUICK if args.quick else FULL
    study = run_study(profile, args.data, runner, progress=lambda text: print(text, flush=True))
    args.output.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.output / "runs.csv", rows_csv(study["runs"]))
    write_text_atomic(args.output / "results.md", markdown(study["summary"], study["claims"]))
    write_text_atomic(args.output / "results.json", json.dumps(dict(
        written_by="tools/study.py sample-efficiency", provenance=args.provenance, quick=args.quick,
        design="docs/sample_efficiency.md", profile=dataclasses.asdict(profile), grid=GRID, horizon=HORIZON,
        seconds=study["seconds"], claims=study["claims"], summary=study["summary"], plant=study["plant"],
        train_rule=study["train_rule"]), indent=2, default=json_default) + "\n")
    print(markdown(study["summary"], study["claims"]))
    print(f"{len(study['runs'])} members in {study['seconds']:.0f} s -> {args.output}")
    return 0
