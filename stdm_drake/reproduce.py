"""`stdm-drake reproduce`: the paper's UR-10 experiments (section V) end to end, with a report.

Stages: (1) datasets: excitation (simulated UR-10, V.A) and tracked task-space plans (our stand-in
for the real robot, V.B); (2) training jobs, two worker processes, each checkpoint cached under
`<output>/cache` by a hash of its dataset and settings, so a rerun reuses what exists; (3) figures
and tables: activations (Figs. 11, 16), sample efficiency (Figs. 12, 17), learning curves (Fig. 13),
multi-step prediction and rollout time (Figs. 18, 19); the sine-sum study (III.B) and the
closed-loop MPC comparison; (4) `report.md` / `report.html` with the paper's reported values in
clearly labelled "paper" columns and a plain statement wherever ours differ. Raw results go to
`results.json` and CSV files. Every other number is computed by the run.
"""
import argparse
import concurrent.futures
import dataclasses
import hashlib
import json
import multiprocessing
import pathlib
import sys
import time

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.files import json_default, write_text_atomic
from stdm_drake.learn import CHECKPOINT_VERSION, DEFAULT_ALPHA, DEFAULT_ALPHA_GRID
from stdm_drake.stats import paired_ratio

ALL_ACTIVATIONS = ("tanh", "sigmoid", "relu", "leaky_relu", "softplus", "selu", "elu", "gelu", "swish")
MODEL_TYPES = ("D", "P", "DE", "PE", "DD", "PD", "DED", "PED")
CONTROL_MODEL_TYPES = ("D", "DD", "PE", "PED")  # compared in closed loop (MPC)

# The paper's reported values (numbers stated in its text), shown in "paper" columns only.
PAPER = {
    "tracking_mse": {"q": 1.818e-5, "v": 0.029},
    "sim_activation_improvement": "3-7x lower MSE (improvement >= 200%) for all activations",
    "sim_sample_efficiency_factor": {"q": {10: 11, 20: 5, 40: 9}, "v": {10: 3, 20: 5, 40: 6}},
    "real_swish_improvement_percent": {"q": 60, "v": 80},
    "real_sample_efficiency_percent": {"q": {1: 17, 3: 7, 5: 56}, "v": {1: 54, 3: 47, 5: 77}},
    "rollout_seconds_100_steps": {"single": 0.033, "ensemble": 0.15},
}


@dataclasses.dataclass(frozen=True)
class Profile:
    """Sizes of one reproduction run. Trajectory counts for the tracking splits are per initial pose."""
    name: str
    excitation_count: int = 200
    tracking_count: int = 100
    seeds: int = 5
    activations: tuple = ALL_ACTIVATIONS
    sim_train_sizes: tuple = (10, 20, 40)
    sim_val: int = 40
    sim_test: int = 120
    real_train_sizes: tuple = (1, 3, 5)
    real_val: int = 5
    real_test: int = 15
    multistep_train: int = 5
    ensemble_size: int = 5
    max_epochs: int = 500
    patience: int = 50
    horizon: int = 100
    sine_sum: str = "full"
    identification_count: int = 100  # tracked plans with dithered PID and an ideal sensor (MPC models)
    control_train: int = 18          # per initial pose
    control_val: int = 2
    control_test: int = 5
    control_seeds: int = 3           # initializations of each MPC model type
    control_max_epochs: int = 300    # single models stop early at 250-400 epochs; ensembles gain little after
    mpc_plans: int = 20              # held-out plans tracked by every MPC
    mpc_steps: int | None = None  # control steps per MPC run (None: the whole plan)


FULL = Profile("full")
QUICK = Profile("quick", excitation_count=40, tracking_count=40, seeds=1, activations=("tanh", "relu", "swish"),
                sim_train_sizes=(5, 10), sim_val=10, sim_test=20, real_train_sizes=(1, 2), real_val=2, real_test=5,
                multistep_train=2, ensemble_size=2, max_epochs=25, patience=10, horizon=50, sine_sum="quick",
                identification_count=20, control_train=3, control_val=1, control_test=1, control_seeds=2, mpc_plans=2,
                mpc_steps=20)


@dataclasses.dataclass(frozen=True)
class TrainJob:
    """One model (or alpha grid) to train and evaluate. Trajectory index lists are into the dataset file.

    alphas: a grid job (naive/derivative comparisons): one stack of single networks from the same
    initialization, one per alpha (see learn.train_alpha_grid); it yields the variants "D" (alpha 0),
    "DD" (the paper's alpha) and, when the grid has more, "DD-auto" (chosen by validation), paired.
    alpha_mode "auto": a derivative model type whose alpha is chosen by validation (learn.fit_model).
    """
    experiment: str
    dataset: str
    dataset_sha256: str
    train: tuple
    val: tuple
    test: tuple
    model_type: str
    activation: str
    seed: int
    ensemble_size: int
    max_epochs: int
    patience: int
    horizon: int
    multistep: bool
    train_size: int  # the experiment's label: trajectories (sim) or trajectories per initial pose (real)
    derivative_source: str | None = None  # None: the dataset's default (Dataset.transitions)
    alphas: tuple | None = None
    alpha_mode: str = "fixed"
    action_rate: str = "forward_difference"  # Dataset.transitions: how the tangent's Δa/Δt is formed

    def key(self) -> str:
        fields = dataclasses.asdict(self)
        for label in ("dataset", "experiment", "train_size"):  # the content hash identifies the data
            fields.pop(label)
        if fields["action_rate"] == "forward_difference":  # the default keeps the keys it always had
            fields.pop("action_rate")
        fields["loss_version"] = CHECKPOINT_VERSION  # results of older loss scalings are not reused
        return hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()[:20]


# ---- stage 1: datasets ----------------------------------------------------------------------------

def _reusable_dataset(path: pathlib.Path, request):
    """The dataset at `path` if it is readable and was collected exactly as `request` asks (count, seed,
    robot, plant, sensor, controller, plan or excitation settings; package versions aside), else None."""
    from stdm_drake.collect import collection_metadata
    from stdm_drake.dataset import load_dataset
    if not path.exists():
        return None
    try:
        dataset = load_dataset(path)
    except InputError:  # unreadable (e.g. truncated): it will be collected again
        return None
    expected = json.loads(json.dumps(collection_metadata(request)))
    expected.pop("package_versions")
    same = all(dataset.metadata.get(key) == value for key, value in expected.items())
    return dataset if same else None


def ensure_dataset(protocol: str, count: int, seed: int, folder: pathlib.Path, progress: bool,
                   name: str | None = None, options: tuple = ()):
    """Collect the dataset (`stdm-drake collect` with its defaults plus the command-line `options`)
    unless a file of that name collected with exactly these settings exists."""
    from stdm_drake.collect import add_arguments, collect, request_from_args
    from stdm_drake.dataset import load_dataset, write_dataset
    path = folder / f"{name or protocol}_n{count}_seed{seed}.h5"
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    request = request_from_args(parser.parse_args(["--protocol", protocol, "--count", str(count), "--seed", str(seed),
                                                   "-o", str(path), *options]))
    dataset = _reusable_dataset(path, request)
    if dataset is not None:
        return dataset
    trajectories, groups, metadata = collect(request, progress=progress)
    write_dataset(path, trajectories, groups, metadata)
    return load_dataset(path)


# ---- stage 2: training jobs (run in worker processes) --------------------------------------------

def _evaluate(model, dataset, job: TrainJob) -> dict:
    """One-step test MSE (q, v) and, for multistep jobs, the open-loop curves and rollout time."""
    from stdm_drake.evaluate import multi_step_errors, one_step_errors, trajectory_rollout_data
    from stdm_drake.predict import InferenceModel, rollout

    test = dataset.transitions(list(job.test))
    errors = one_step_errors(model, test.state, test.action, test.next_state)
    result = dict(q_mse=errors.angle_mse, v_mse=errors.velocity_mse)
    if job.multistep:
        x0, actions, truth = trajectory_rollout_data(dataset, job.test, job.horizon)
        multi = multi_step_errors(model, x0, actions, truth)
        engine = InferenceModel(model)
        rollout(engine, x0[:1], actions[:1])  # warm-up
        timings = []
        for _ in range(20):
            tick = time.perf_counter()
            rollout(engine, x0[:1], actions[:1])
            timings.append(time.perf_counter() - tick)
        result.update(multistep_q=multi.angle_mse.tolist(), multistep_v=multi.velocity_mse.tolist(),
                      multistep_q_std=multi.angle_mse_std.tolist(), multistep_v_std=multi.velocity_mse_std.tolist(),
                      rollout_ms=1e3 * float(np.median(timings)))
    return result


def grid_variants(alphas) -> dict:
    """Variant name -> index into `alphas` of a grid job: D (0), DD (the paper's alpha), DD-auto (chosen)."""
    alphas = [float(a) for a in alphas]
    variants = {"D": alphas.index(0.0), "DD": alphas.index(DEFAULT_ALPHA)}
    if len(alphas) > 2:
        variants["DD-auto"] = None  # the selection's index
    return variants


def run_job(job: TrainJob, cache: pathlib.Path) -> list[dict]:
    """Train (or reuse) one job; return one result row per model it yields (test metrics, curves)."""
    import torch
    torch.set_num_threads(1)
    from stdm_drake.dataset import load_dataset
    from stdm_drake.learn import RegressionData, TrainingConfig, fit_model, save_checkpoint, train_alpha_grid
    from stdm_drake.models import dynamics_config, parse_model_type

    key = job.key()
    result_path = cache / f"{key}.json"
    labels = {"experiment": job.experiment, "train_size": job.train_size}
    if result_path.exists() and (cache / f"{key}.pt").exists():
        return [row | labels | {"reused": True} for row in json.loads(result_path.read_text())]
    dataset = load_dataset(job.dataset)
    kind = parse_model_type(job.model_type)
    config = dynamics_config(state_dim=12, action_dim=6, activation=job.activation,
                             ensemble_size=job.ensemble_size if kind.ensemble else 1, probabilistic=kind.probabilistic)
    training = TrainingConfig(alpha=DEFAULT_ALPHA if kind.derivative else 0.0, seed=job.seed,
                              max_epochs=job.max_epochs, patience=job.patience)
    source = job.derivative_source
    train = RegressionData.from_transitions(dataset.transitions(list(job.train), derivative_source=source,
                                                                action_rate=job.action_rate))
    val = RegressionData.from_transitions(dataset.transitions(list(job.val), derivative_source=source,
                                                              action_rate=job.action_rate))
    common = dict(key=key, activation=job.activation, seed=job.seed, train_trajectories=len(job.train))
    metadata = dict(dataset_path=job.dataset, dataset_sha256=job.dataset_sha256, sample_period=dataset.sample_period,
                    model_type=job.model_type, split=dict(train=list(job.train), val=list(job.val), test=list(job.test)))
    started = time.perf_counter()
    rows = []
    if job.alphas is not None:
        grid, selection = train_alpha_grid(config, training, train, val, alphas=job.alphas)
        seconds = time.perf_counter() - started
        for name, index in grid_variants(job.alphas).items():
            index = selection.index if index is None else index
            rows.append(dict(common, model_type=name, alpha=float(job.alphas[index]), train_seconds=seconds,
                             epochs=grid.epochs_run, best_epoch=int(grid.best_epochs[index]),
                             val_mse=float(grid.best_scores[index]), epoch_axis=grid.history["epoch"],
                             val_mse_curve=[scores[index] for scores in grid.member_val_mse],
                             alpha_selection=selection.as_dict(),
                             **_evaluate(grid.model.member(index), dataset, job)))
        saved, history = grid.model, grid.history
        saved_training = dataclasses.replace(training, alpha=0.0, alpha_grid=tuple(job.alphas))
        metadata["alpha_selection"] = selection.as_dict()
    else:
        trained, selection = fit_model(config, training, train, val, alpha=job.alpha_mode if kind.derivative else
                                       "fixed", metadata=metadata)
        seconds = time.perf_counter() - started
        alpha = selection.alpha if selection is not None else training.alpha
        rows.append(dict(common, model_type=job.model_type, alpha=alpha, train_seconds=seconds,
                         epochs=trained.epochs_run, epoch_axis=trained.history["epoch"],
                         val_mse_curve=trained.history["val_mse"],
                         alpha_selection=selection.as_dict() if selection is not None else None,
                         **_evaluate(trained.model, dataset, job)))
        saved, history = trained.model, trained.history
        saved_training = dataclasses.replace(training, alpha=alpha)
        if selection is not None:
            metadata["alpha_selection"] = selection.as_dict()
    save_checkpoint(cache / f"{key}.pt", saved, training_config=saved_training, history=history,
                    metadata=metadata)
    write_text_atomic(result_path, json.dumps(rows, default=json_default))
    return [row | labels | {"reused": False} for row in rows]


def _run_job(arguments):
    job, cache = arguments
    return run_job(job, cache)


# relative training cost of a job, to start the longest first (measured on the full profile: an
# ensemble trained with the derivative term on the identification data takes ~100x a 10-trajectory grid)
JOB_COST = {"control": 20.0, "sim_local": 15.0, "multistep": 2.0, "sim": 1.0, "real": 1.0}


def job_cost(job: TrainJob) -> float:
    from stdm_drake.models import parse_model_type
    kind = parse_model_type(job.model_type)
    members = len(job.alphas) if job.alphas else (job.ensemble_size if kind.ensemble else 1)
    derivative = 1.5 if job.alphas or kind.derivative else 1.0
    return JOB_COST.get(job.experiment, 1.0) * members * derivative * len(job.train)


def run_jobs(jobs: list[TrainJob], cache: pathlib.Path, workers: int, progress: bool) -> list[dict]:
    """Train every job (the most expensive first, so the workers finish together); rows in job order."""
    from tqdm import tqdm
    bar = tqdm(total=len(jobs), desc="train", unit="model", disable=not progress, file=sys.stderr)
    results = []
    if workers > 1:
        context = multiprocessing.get_context("spawn")
        order = sorted(range(len(jobs)), key=lambda index: -job_cost(jobs[index]))
        rows_of: dict[int, list] = {}
        with concurrent.futures.ProcessPoolExecutor(workers, mp_context=context) as pool:
            futures = {pool.submit(_run_job, (jobs[index], cache)): index for index in order}
            for future in concurrent.futures.as_completed(futures):
                rows_of[futures[future]] = future.result()
                bar.update()
        for index in range(len(jobs)):
            results.extend(rows_of[index])
    else:
        for job in jobs:
            results.extend(run_job(job, cache))
            bar.update()
    bar.close()
    return results


def plan_jobs(profile: Profile, excitation, local, tracking, identification) -> list[TrainJob]:
    """Every training job (sim, sim_local, real, multistep, control); the splits use split seed 0, the
    seeds vary initialization. Naive/derivative comparisons are grid jobs (TrainJob.alphas): the paper's
    alpha beside naive for every activation, and the full alpha grid (alpha chosen by validation) for swish."""
    from stdm_drake.dataset import split_trajectories
    common = dict(max_epochs=profile.max_epochs, patience=profile.patience, ensemble_size=profile.ensemble_size)

    def comparison(experiment, dataset, sizes, n_val, n_test, per_group, multistep=False):
        """One grid job per seed: all activations at the largest size, swish at the others."""
        horizon = len(dataset.trajectory(0)["tau"])
        for size in sizes:
            split = split_trajectories(dataset.groups, size, n_val, n_test, seed=0, per_group=per_group)
            for activation in (profile.activations if size == max(sizes) else ("swish",)):
                alphas = DEFAULT_ALPHA_GRID if activation == "swish" else (0.0, DEFAULT_ALPHA)
                for seed in range(profile.seeds):
                    yield TrainJob(experiment, str(dataset.path), dataset.sha256, tuple(split.train.tolist()),
                                   tuple(split.val.tolist()), tuple(split.test.tolist()), "D", activation, seed,
                                   multistep=multistep and activation == "swish", train_size=size, horizon=horizon,
                                   alphas=alphas, **common)

    jobs = list(comparison("sim", excitation, profile.sim_train_sizes, profile.sim_val, profile.sim_test, False,
                           multistep=True))
    # the coverage study's second regime: start poses in a box around a home pose, swish at the largest size
    largest = max(profile.sim_train_sizes)
    jobs += [dataclasses.replace(job, activation="swish") for job in
             comparison("sim_local", local, (largest,), profile.sim_val, profile.sim_test, False, multistep=True)
             if job.activation == "swish"]
    jobs += comparison("real", tracking, profile.real_train_sizes, profile.real_val, profile.real_test, True)
    split = split_trajectories(tracking.groups, profile.multistep_train, profile.real_val, profile.real_test, seed=0,
                               per_group=True)
    for model_type in MODEL_TYPES:
        jobs.append(TrainJob("multistep", str(tracking.path), tracking.sha256, tuple(split.train.tolist()),
                             tuple(split.val.tolist()), tuple(split.test.tolist()), model_type, "swish", 0,
                             multistep=True, train_size=profile.multistep_train, horizon=profile.horizon,
                             alpha_mode="auto", **common))
    # models for the closed-loop MPC comparison: simulated data, so the derivative targets are the true ones
    split = split_trajectories(identification.groups, profile.control_train, profile.control_val,
                               profile.control_test, seed=0, per_group=True)
    # the paper's alpha (not chosen by validation: on these data the grid picked alpha = 0 or 1e-4 for
    # every DD and PED seed, which makes the closed-loop comparison one of naive models; see README),
    # with the derivative targets of held torques: the dither changes the torque every sample, so the
    # forward-difference tangent (a smooth-torque approximation) teaches a wrong torque response
    control = dict(common, max_epochs=min(profile.max_epochs, profile.control_max_epochs),
                   action_rate="zero_order_hold")
    for model_type in CONTROL_MODEL_TYPES:
        for seed in range(profile.control_seeds):
            jobs.append(TrainJob("control", str(identification.path), identification.sha256,
                                 tuple(split.train.tolist()), tuple(split.val.tolist()), tuple(split.test.tolist()),
                                 model_type, "swish", seed, multistep=False, train_size=profile.control_train,
                                 horizon=profile.horizon, derivative_source="true", **control))
    return jobs


# ---- stage 3: tables, figures, report -------------------------------------------------------------

def _select(results, **conditions):
    return [r for r in results if all(r[key] == value for key, value in conditions.items())]


def _mean_std(values):
    values = np.asarray(values, dtype=float)
    return float(values.mean()), float(values.std())


def improvement_percent(naive: float, derivative: float) -> float:
    """The paper's accuracy improvement (MSE_naive - MSE_derivative) / MSE_derivative x 100."""
    return 100.0 * (naive - derivative) / derivative


DERIVATIVE_VARIANTS = (("DD", "paper alpha"), ("DD-auto", "alpha by validation"))


def paired(results, experiment: str, size: int, activation: str, variant: str, metric) -> tuple[list, list]:
    """(naive values, variant values) of one metric, paired by seed (the grid's shared initialization).
    metric: a result key, or a function of a result row."""
    value = metric if callable(metric) else (lambda row: row[metric])
    rows = {variant_name: {r["seed"]: value(r) for r in _select(results, experiment=experiment, train_size=size,
                                                               activation=activation, model_type=variant_name)}
            for variant_name in ("D", variant)}
    seeds = sorted(set(rows["D"]) & set(rows[variant]))
    return [rows["D"][seed] for seed in seeds], [rows[variant][seed] for seed in seeds]


def comparison_row(results, experiment: str, size: int, activation: str, metrics: dict) -> dict:
    """Means and paired ratios (naive / variant, 95 % CI) of every metric for the derivative variants
    present. metrics: label -> result key or function of a row."""
    row = dict(activation=activation, train_trajectories=size)
    for label, metric in metrics.items():
        for variant, _ in DERIVATIVE_VARIANTS:
            naive, derivative = paired(results, experiment, size, activation, variant, metric)
            if not naive:
                continue
            row[f"{label}_naive"], row[f"{label}_naive_std"] = _mean_std(naive)
            row[f"{label}_{variant}"], row[f"{label}_{variant}_std"] = _mean_std(derivative)
            row[f"{label}_{variant}_improvement_percent"] = improvement_percent(np.mean(naive), np.mean(derivative))
            row[f"{label}_{variant}_ratio"] = paired_ratio(naive, derivative).as_dict()
    return row


ONE_STEP = {"q": "q_mse", "v": "v_mse"}


def activation_table(results, experiment: str, size: int) -> list[dict]:
    activations = dict.fromkeys(r["activation"] for r in _select(results, experiment=experiment, train_size=size))
    return [comparison_row(results, experiment, size, activation, ONE_STEP) for activation in activations]


def size_table(results, experiment: str) -> list[dict]:
    sizes = sorted({r["train_size"] for r in _select(results, experiment=experiment, activation="swish")})
    return [comparison_row(results, experiment, size, "swish", ONE_STEP) for size in sizes]


def coverage_table(results, size: int) -> list[dict]:
    """The coverage study: per regime (sim: start poses over joint space; sim_local: in a box around a
    home pose) one-step and open-loop MSE at step 20 and at the trajectory's end, swish."""
    rows = []
    for experiment, regime in (("sim", "global"), ("sim_local", "local")):
        if not _select(results, experiment=experiment, train_size=size, activation="swish", model_type="D"):
            continue
        horizon = len(_select(results, experiment=experiment, train_size=size, activation="swish")[0]["multistep_q"])
        metrics = dict(ONE_STEP)
        for step in sorted({min(20, horizon), horizon}):
            metrics[f"q{step}"] = lambda row, step=step: row["multistep_q"][step - 1]
            metrics[f"v{step}"] = lambda row, step=step: row["multistep_v"][step - 1]
        row = comparison_row(results, experiment, size, "swish", metrics)
        row.update(regime=regime, metrics=list(metrics), alphas=sorted(
            r["alpha"] for r in _select(results, experiment=experiment, train_size=size, activation="swish",
                                        model_type="DD-auto")))
        rows.append(row)
    return rows


def ratio_text(ratio: dict | None) -> str:
    if not ratio:
        return ""
    if ratio["pairs"] < 2:
        return f"{ratio['ratio']:.3g}x (1 pair)"
    return f"{ratio['ratio']:.3g}x [{ratio['low']:.3g}, {ratio['high']:.3g}] {ratio['verdict']}"


def _figure_path(folder, name):
    return folder / f"{name}.png"


def _save(figure, path):
    import matplotlib.pyplot as plt

    from stdm_drake.files import atomic_path
    with atomic_path(path) as temp:
        figure.savefig(temp, format="png", dpi=100)
    plt.close(figure)


def plot_activations(rows, title, path):
    import matplotlib.pyplot as plt
    figure, axes = plt.subplots(1, 2, figsize=(12, 4))
    x = np.arange(len(rows))
    for axis, quantity, unit in zip(axes, ("q", "v"), ("rad²", "(rad/s)²")):
        axis.bar(x - 0.2, [r[f"{quantity}_naive"] for r in rows], 0.4, label="naive (D)")
        axis.bar(x + 0.2, [r[f"{quantity}_DD"] for r in rows], 0.4, label="derivative, paper alpha (DD)")
        for i, row in enumerate(rows):
            ratio = row[f"{quantity}_DD_ratio"]
            axis.annotate(f"{ratio['ratio']:.2g}x", (i, max(row[f"{quantity}_naive"], row[f"{quantity}_DD"])),
                          ha="center", va="bottom", fontsize=8, fontweight="bold" if ratio["verdict"] != "no clear "
                          "difference" else "normal")
        axis.set(xticks=x, xticklabels=[r["activation"] for r in rows], yscale="log",
                 ylabel=f"one-step test MSE ({unit})",
                 title=f"{title}: {'joint angles' if quantity == 'q' else 'velocities'} (naive/DD, bold: 95 % CI excludes 1)")
        axis.legend()
    figure.tight_layout()
    _save(figure, path)


def plot_sizes(rows, title, xlabel, path):
    import matplotlib.pyplot as plt
    figure, axes = plt.subplots(1, 2, figsize=(11, 4))
    sizes = [r["train_trajectories"] for r in rows]
    for axis, quantity in zip(axes, ("q", "v")):
        for key, label in (("naive", "naive (D)"), ("DD", "paper alpha (DD)"), ("DD-auto", "alpha by validation")):
            if f"{quantity}_{key}" not in rows[0]:
                continue
            axis.errorbar(sizes, [r[f"{quantity}_{key}"] for r in rows], yerr=[r[f"{quantity}_{key}_std"] for r in rows],
                          marker="o", capsize=4, label=label)
        axis.set(xlabel=xlabel, ylabel="one-step test MSE", yscale="log",
                 title=f"{title}: {'joint angles' if quantity == 'q' else 'velocities'} (swish, mean ± std over seeds)")
        axis.legend()
    figure.tight_layout()
    _save(figure, path)


def plot_learning_curves(results, size, path):
    import matplotlib.pyplot as plt
    figure, axis = plt.subplots(figsize=(7, 4.5))
    for model_type, color in (("D", "tab:blue"), ("DD", "tab:orange"), ("DD-auto", "tab:green")):
        for index, run in enumerate(_select(results, experiment="sim", model_type=model_type, activation="swish",
                                            train_size=size)):
            axis.semilogy(run["epoch_axis"], run["val_mse_curve"], color=color, alpha=0.6,
                          label=model_type if index == 0 else None)
    axis.set(xlabel="epoch", ylabel="validation state MSE (standardized)",
             title="validation curves, every seed (paired grids: one initialization per seed)")
    axis.legend()
    figure.tight_layout()
    _save(figure, path)


def plot_multistep(results, horizon, path):
    import matplotlib.pyplot as plt
    figure, axes = plt.subplots(1, 2, figsize=(12, 4))
    for run in _select(results, experiment="multistep"):
        steps = np.arange(1, len(run["multistep_q"]) + 1)[:horizon]
        style = "--" if run["model_type"] in ("DD", "PD", "DED", "PED") else "-"
        for axis, key in zip(axes, ("multistep_q", "multistep_v")):
            mean, std = np.array(run[key])[:horizon], np.array(run[f"{key}_std"])[:horizon]
            line, = axis.semilogy(steps, mean, style, label=run["model_type"])
            axis.fill_between(steps, np.maximum(mean - std, 1e-12), mean + std, color=line.get_color(), alpha=0.1)
    for axis, name in zip(axes, ("joint angles (rad²)", "velocities ((rad/s)²)")):
        axis.set(xlabel="prediction step", ylabel=f"MSE, {name}", title=f"open-loop prediction, {horizon} steps")
        axis.legend(ncol=2, fontsize=8)
    figure.tight_layout()
    _save(figure, path)


class Report:
    """Blocks rendered to Markdown and to a standalone HTML page."""

    def __init__(self, title):
        self.title = title
        self.blocks = []

    def heading(self, text):
        self.blocks.append(("h2", text))

    def text(self, text):
        self.blocks.append(("p", text))

    def table(self, header, rows):
        self.blocks.append(("table", header, rows))

    def image(self, path, caption):
        self.blocks.append(("img", path, caption))

    def markdown(self):
        out = [f"# {self.title}", ""]
        for block in self.blocks:
            if block[0] == "h2":
                out += [f"## {block[1]}", ""]
            elif block[0] == "p":
                out += [block[1], ""]
            elif block[0] == "table":
                out += ["| " + " | ".join(block[1]) + " |", "|" + "---|" * len(block[1])]
                out += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in block[2]] + [""]
            else:
                out += [f"![{block[2]}]({block[1]})", "", f"*{block[2]}*", ""]
        return "\n".join(out)

    def html(self):
        import html
        out = ["<!DOCTYPE html><html><head><meta charset='utf-8'>", f"<title>{html.escape(self.title)}</title>",
               "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}table{border-collapse:collapse}"
               "td,th{border:1px solid #bbb;padding:3px 8px;text-align:right}img{max-width:100%}</style></head><body>",
               f"<h1>{html.escape(self.title)}</h1>"]
        for block in self.blocks:
            if block[0] == "h2":
                out.append(f"<h2>{html.escape(block[1])}</h2>")
            elif block[0] == "p":
                out.append(f"<p>{html.escape(block[1])}</p>")
            elif block[0] == "table":
                out.append("<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in block[1]) + "</tr>")
                out += ["<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>" for row in block[2]]
                out.append("</table>")
            else:
                out.append(f"<figure><img src='{html.escape(block[1])}'><figcaption>{html.escape(block[2])}"
                           "</figcaption></figure>")
        return "\n".join(out + ["</body></html>"])


def _flat(row: dict) -> dict:
    """A table row for CSV: nested ratio dicts become <key>_ratio/_low/_high/_verdict columns, lists are dropped."""
    flat = {}
    for key, value in row.items():
        if isinstance(value, dict):
            flat.update({f"{key}_{inner}" if inner != "ratio" else key: value[inner]
                         for inner in ("ratio", "low", "high", "verdict")})
        elif not isinstance(value, list):
            flat[key] = value
    return flat


def _g(value):
    return f"{value:.3g}"


def verdict(ratio: dict | None, paper_percent) -> str:
    """Ours against the paper's improvement, from the paired 95 % interval of naive/derivative:
    "agrees" (the interval is above 1 and the ratio reaches at least half the paper's gain), "smaller
    gain" (above 1, less than half), "DIFFERS (no clear gain)" (the interval contains 1) or "DIFFERS
    (worse)" (below 1); empty where the paper states no number."""
    if paper_percent is None or paper_percent == "" or not ratio:
        return ""
    if ratio["verdict"] == "hurts":
        return "DIFFERS (worse)"
    if ratio["verdict"] != "helps":
        return "DIFFERS (no clear gain)"
    return "agrees" if 100.0 * (ratio["ratio"] - 1.0) >= 0.5 * float(paper_percent) else "smaller gain"


def verdicts(row: dict, paper_q, paper_v, variant: str = "DD") -> str:
    parts = [f"{name}: {verdict(row.get(f'{name}_{variant}_ratio'), paper)}"
             for name, paper in (("q", paper_q), ("v", paper_v)) if verdict(row.get(f"{name}_{variant}_ratio"), paper)]
    return "; ".join(parts)


def add_activation_section(report, rows, paper_text, paper_percent):
    """paper_percent(activation) -> (q %, v %) the paper states for it, or (None, None)."""
    report.table(["activation", "q naive", "q DD", "q naive/DD (95 % CI)", "v naive", "v DD", "v naive/DD (95 % CI)",
                  "paper", "ours vs paper"],
                 [[r["activation"], _g(r["q_naive"]), _g(r["q_DD"]), ratio_text(r["q_DD_ratio"]),
                   _g(r["v_naive"]), _g(r["v_DD"]), ratio_text(r["v_DD_ratio"]), paper_text,
                   verdicts(r, *paper_percent(r["activation"]))] for r in rows])


def add_size_section(report, rows, paper_improvement, label):
    """Sample efficiency: naive, paper alpha and alpha by validation, paired ratios with intervals.
    paper_improvement(size) -> (q %, v %) or (None, None)."""
    header = [label, "q naive", "q DD", "q naive/DD", "q DD-auto", "q naive/DD-auto", "v naive", "v DD", "v naive/DD",
              "v DD-auto", "v naive/DD-auto", "paper q / v %", "ours (DD) vs paper"]
    lines = []
    for r in rows:
        paper_q, paper_v = paper_improvement(r["train_trajectories"])
        lines.append([r["train_trajectories"]] + [cell for quantity in ("q", "v") for cell in (
            _g(r[f"{quantity}_naive"]), _g(r[f"{quantity}_DD"]), ratio_text(r[f"{quantity}_DD_ratio"]),
            _g(r.get(f"{quantity}_DD-auto", float("nan"))), ratio_text(r.get(f"{quantity}_DD-auto_ratio")))]
            + [f"{paper_q} / {paper_v}" if paper_q is not None else "", verdicts(r, paper_q, paper_v)])
    report.table(header, lines)


def add_coverage_section(report, rows):
    header = ["regime", "metric", "naive", "paper alpha (DD)", "naive/DD (95 % CI)", "alpha by validation",
              "naive/DD-auto (95 % CI)"]
    lines = []
    for r in rows:
        for metric in r["metrics"]:
            unit = "q" if metric.startswith("q") else "v"
            name = (f"one-step {unit}" if metric in ONE_STEP else f"{unit} at step {metric[1:]}")
            lines.append([r["regime"], name, _g(r[f"{metric}_naive"]), _g(r[f"{metric}_DD"]),
                          ratio_text(r[f"{metric}_DD_ratio"]), _g(r.get(f"{metric}_DD-auto", float("nan"))),
                          ratio_text(r.get(f"{metric}_DD-auto_ratio"))])
    report.table(header, lines)
    for r in rows:
        report.text(f"{r['regime']}: alpha chosen by validation per seed: "
                    + ", ".join(f"{alpha:g}" for alpha in r["alphas"]) + ".")


def write_report(folder: pathlib.Path, profile: Profile, excitation, local, tracking, identification, results, sine,
                 mpc_rows, timings: dict) -> pathlib.Path:
    from stdm_drake.inspect import tracking_errors
    figures = folder / "figures"
    report = Report(f"stdm-drake reproduction of Kim, Lee & Ryu (IEEE Access 2022), profile '{profile.name}'")
    report.text("Every number below is computed by this run except the columns labelled 'paper', which quote "
                "the values stated in the paper's text. MSE in rad² (joint angles, q) and (rad/s)² (velocities, v); "
                "improvement = (MSE_naive - MSE_derivative) / MSE_derivative x 100 (the paper's definition). "
                f"Stage times (s): {', '.join(f'{k} {v:.0f}' for k, v in timings.items())}.")

    report.heading("Data")
    errors, identification_errors = tracking_errors(tracking), tracking_errors(identification)
    report.table(["dataset", "trajectories", "steps", "tracking q MSE", "tracking v MSE (measured)", "paper"],
                 [["excitation (V.A)", excitation.num_trajectories, len(excitation.trajectory(0)["tau"]), "", "", ""],
                  ["excitation, local start poses (coverage study)", local.num_trajectories,
                   len(local.trajectory(0)["tau"]), "", "", ""],
                  ["tracked plans (V.B)", tracking.num_trajectories, len(tracking.trajectory(0)["tau"]),
                   _g(errors["true_q"]), _g(errors["measured_v"]),
                   f"q {PAPER['tracking_mse']['q']}, v {PAPER['tracking_mse']['v']}"],
                  ["identification (MPC models)", identification.num_trajectories,
                   len(identification.trajectory(0)["tau"]), _g(identification_errors["true_q"]),
                   _g(identification_errors["measured_v"]), ""]])
    report.text("The identification dataset tracks the same kind of plans with controllers/pid_dither.yaml (white "
                "torque dither, persistent excitation) and controllers/sensor_ideal.yaml (true states): the models "
                "for the closed-loop MPC comparison are trained on it, since closed-loop PID torques alone do not "
                "identify the torque response.")

    largest_sim, largest_real = max(profile.sim_train_sizes), max(profile.real_train_sizes)
    report.heading(f"Simulated UR-10: activations at {largest_sim} training trajectories (Fig. 11)")
    sim_rows = activation_table(results, "sim", largest_sim)
    plot_activations(sim_rows, "simulated UR-10", _figure_path(figures, "fig11_activations_sim"))
    add_activation_section(report, sim_rows, PAPER["sim_activation_improvement"], lambda activation: (200, 200))
    report.image("figures/fig11_activations_sim.png", "Fig. 11: one-step test MSE, naive vs derivative learning")

    report.heading("Simulated UR-10: sample efficiency (Fig. 12)")
    sim_sizes = size_table(results, "sim")
    plot_sizes(sim_sizes, "simulated UR-10", "training trajectories", _figure_path(figures, "fig12_sizes_sim"))
    paper_factor = PAPER["sim_sample_efficiency_factor"]
    add_size_section(report, sim_sizes, lambda size: tuple(100 * (paper_factor[name][size] - 1)
                                                           if size in paper_factor[name] else None
                                                           for name in ("q", "v")), "train traj.")
    report.text("Ratios naive/derivative > 1 mean derivative learning has the lower MSE; each is the geometric mean "
                "over seeds of paired runs (one alpha grid per seed: naive, the paper's alpha and every other alpha "
                "start from the same initialization and see the same minibatches), with its 95 % Student-t interval; "
                "the verdict is 'helps' only if the whole interval is above 1. DD-auto is the grid member with the "
                "lowest validation state MSE (naive included, so it is never worse than naive on validation).")
    report.image("figures/fig12_sizes_sim.png", "Fig. 12: MSE vs number of training trajectories (mean ± std)")
    plot_learning_curves(results, largest_sim, _figure_path(figures, "fig13_learning_curves"))
    report.image("figures/fig13_learning_curves.png",
                 f"Fig. 13: learning curves, swish, {largest_sim} training trajectories, every seed")

    report.heading(f"Tracked plans ('real robot' protocol): activations at {4 * largest_real} training trajectories (Fig. 16)")
    real_rows = activation_table(results, "real", largest_real)
    plot_activations(real_rows, "tracked plans", _figure_path(figures, "fig16_activations_real"))
    paper_real = PAPER["real_swish_improvement_percent"]
    add_activation_section(report, real_rows, f"swish: q +{paper_real['q']}%, v +{paper_real['v']}%",
                           lambda activation: (paper_real["q"], paper_real["v"]) if activation == "swish" else (None, None))
    report.image("figures/fig16_activations_real.png", "Fig. 16: tracked plans, naive vs derivative learning")

    report.heading("Tracked plans: sample efficiency (Fig. 17)")
    real_sizes = size_table(results, "real")
    plot_sizes(real_sizes, "tracked plans", "training trajectories per initial pose", _figure_path(figures, "fig17_sizes_real"))
    paper_percent = PAPER["real_sample_efficiency_percent"]
    add_size_section(report, real_sizes, lambda size: (paper_percent["q"].get(size), paper_percent["v"].get(size)),
                     "train traj. per pose")
    report.image("figures/fig17_sizes_real.png", "Fig. 17: tracked plans, MSE vs training trajectories")

    report.heading(f"Where derivative learning helps: coverage of the training data ({largest_sim} trajectories)")
    coverage = coverage_table(results, largest_sim)
    report.text("Two simulated regimes, same protocol otherwise: 'global' (the excitation data above, start poses "
                "over most of joint space) and 'local' (trajectories/excitation_local.yaml: start poses in a box of "
                "±0.5 rad around a home pose). Swish, paired grids per seed; open-loop errors from each test "
                "trajectory's first state under its recorded torques.")
    add_coverage_section(report, coverage)

    report.heading("Multi-step prediction (Figs. 18, 19)")
    multistep = sorted(_select(results, experiment="multistep"), key=lambda r: MODEL_TYPES.index(r["model_type"]))
    plot_multistep(results, profile.horizon, _figure_path(figures, "fig18_multistep"))
    plot_multistep(results, 20, _figure_path(figures, "fig19_multistep_20"))
    paper_time = PAPER["rollout_seconds_100_steps"]
    report.table(["model", "alpha", f"q MSE at step {profile.horizon}", f"v MSE at step {profile.horizon}",
                  "q MSE at step 20", "v MSE at step 20", "rollout ms (batch 1)", "paper rollout ms (100 steps)"],
                 [[r["model_type"], f"{r['alpha']:g}" + (" (by validation)" if r.get("alpha_selection") else ""),
                   _g(r["multistep_q"][-1]), _g(r["multistep_v"][-1]),
                   _g(r["multistep_q"][min(19, len(r["multistep_q"]) - 1)]),
                   _g(r["multistep_v"][min(19, len(r["multistep_v"]) - 1)]), f"{r['rollout_ms']:.2f}",
                   1e3 * paper_time["ensemble" if "E" in r["model_type"] else "single"]] for r in multistep])
    report.image("figures/fig18_multistep.png", f"Fig. 18: open-loop MSE up to {profile.horizon} steps (mean ± std)")
    report.image("figures/fig19_multistep_20.png", "Fig. 19: the first 20 steps")
    pairs = [(naive, naive + "D" if naive in ("D", "P") else naive[:-1] + "ED") for naive in ("D", "P", "DE", "PE")]
    by_type = {r["model_type"]: r for r in multistep}
    statements = []
    for naive, derivative in pairs:
        if naive in by_type and derivative in by_type and by_type[derivative]["alpha"] == 0:
            statements.append(f"{derivative}: validation chose alpha 0, so it is the naive {naive} model.")
        elif naive in by_type and derivative in by_type:
            parts = []
            for key, label in (("multistep_q", "q"), ("multistep_v", "v")):
                ours, theirs = np.mean(by_type[derivative][key]), np.mean(by_type[naive][key])
                parts.append(f"{label} {_g(ours)} vs {_g(theirs)} ({'lower, as the paper reports' if ours < theirs else 'NOT lower, unlike the paper'})")
            statements.append(f"{derivative} (alpha {by_type[derivative]['alpha']:g}) vs {naive}, MSE averaged over "
                              "the horizon: " + "; ".join(parts) + ". One model each (seed 0): no interval; the "
                              "coverage study above has paired seeds.")
    for line in statements:
        report.text(line)

    report.heading("Sine-sum study (section III.B)")
    from stdm_drake.sine_sum import headline
    top = headline(sine)
    report.text(f"Profile '{sine['profile']}', {len(sine['runs'])} runs in {sine['wall_seconds']:.0f} s; "
                "full figures and tables in sine_sum/ (summary.md). Raw input x as in the paper, cosine "
                f"learning-rate decay over {sine['config']['epochs']} full-batch steps, alpha {top['alpha']:g}"
                + (" chosen by validation." if sine.get("alpha_sweep") else "."))
    report.table(["5 layers, swish", "naive", "derivative", "naive/derivative (paired, 95 % CI)", "paper (derivative)"],
                 [[f"mean of {top['networks']} networks", _g(top["naive_mean_test_mse"]),
                   _g(top["derivative_mean_test_mse"]),
                   f"{top['ratio']:.3g}x [{top['ratio_low']:.3g}, {top['ratio_high']:.3g}] {top['verdict']}",
                   top["paper_derivative"]]])
    from stdm_drake.sine_sum import table1_rows
    report.table(["loss", "activation", "ours (test MSE)", "paper"],
                 [[r["loss"], r["activation"], _g(r["mean_test_mse"]), r["paper"]] for r in table1_rows(sine)])

    report.heading("Closed-loop MPC (plant + iLQR MPC with each prediction model)")
    if mpc_rows:
        types = mpc_rows["types"]
        plans, seeds = types[0]["plans"], max(row["seeds"] for row in types)
        report.text(f"{plans} held-out plans of the identification dataset, {seeds} initializations per learned "
                    "model type (trained on the same split; DD and PED at the paper's alpha, with the derivative "
                    "targets of held torques: Δa/Δt = 0 and accelerations just before each sample). Ratios are "
                    "geometric means over plans (each plan's q MSE a geometric mean over seeds) with 95 % intervals "
                    "over plans; a ratio above 1 means lower tracking error than the compared controller.")
        report.table(["model", "q MSE (rad², mean)", "plant-model MPC / model [95 % CI]", "per seed",
                      "naive twin / model [95 % CI]", "solve mean / p95 (ms)", "limit violations", "fallbacks"],
                     [[r["model"], _g(r["q_mse_rad2"]), ratio_text(r.get("plant_over_model")),
                       ", ".join(f"{x:.3g}" for x in r.get("seed_ratios", [])),
                       ratio_text(r.get("naive_over_derivative")),
                       f"{r['solve_ms_mean']:.2f} / {r['solve_ms_p95']:.2f}", r["limit_violations"], r["fallbacks"]]
                      for r in types])
        report.image("mpc/mpc.png", "MPC tracking error, plant model vs learned models")
        report.text("The paper has no MPC experiment; the plant-as-model MPC is the reference. Per model "
                    "instance: mpc_runs.csv.")

    markdown, page = report.markdown(), report.html()
    write_text_atomic(folder / "report.md", markdown + "\n")
    write_text_atomic(folder / "report.html", page + "\n")
    tables = dict(sim_activations=sim_rows, sim_sizes=sim_sizes, real_activations=real_rows, real_sizes=real_sizes,
                  coverage=coverage,
                  multistep=[{k: v for k, v in r.items() if k not in ("epoch_axis", "val_mse_curve")} for r in multistep],
                  mpc=mpc_rows["types"] if mpc_rows else [], mpc_runs=mpc_rows["runs"] if mpc_rows else [],
                  paper=PAPER, profile=dataclasses.asdict(profile), stage_seconds=timings)
    write_text_atomic(folder / "results.json", json.dumps(dict(tables=tables, runs=results), default=json_default))
    for name in ("sim_activations", "sim_sizes", "real_activations", "real_sizes", "coverage", "mpc", "mpc_runs"):
        rows = [_flat(row) for row in tables[name]]
        if rows:
            columns = list(dict.fromkeys(key for row in rows for key in row))
            write_text_atomic(folder / f"{name}.csv", "\n".join(
                [",".join(columns)] + [",".join(str(row.get(key, "")) for key in columns) for row in rows]) + "\n")
    return folder / "report.html"


# ---- the command -----------------------------------------------------------------------------------

def reproduce(profile: Profile, output: pathlib.Path, seed: int = 0, workers: int = 2, progress: bool = True):
    """Run every stage; returns the report path."""
    from stdm_drake import sine_sum
    output = pathlib.Path(output)
    cache = output / "cache"
    cache.mkdir(parents=True, exist_ok=True)
    timings = {}
    tick = time.perf_counter()
    from stdm_drake.robot import TRAJECTORIES_DIR
    excitation = ensure_dataset("excitation", profile.excitation_count, seed, output / "data", progress)
    local = ensure_dataset("excitation", profile.excitation_count, seed, output / "data", progress,
                           name="excitation_local", options=("--config", str(TRAJECTORIES_DIR / "excitation_local.yaml")))
    tracking = ensure_dataset("tracking", profile.tracking_count, seed, output / "data", progress)
    # the MPC models' data: the same kind of plans, tracked with dithered PID, recorded by an ideal sensor
    identification = ensure_dataset("tracking", profile.identification_count, seed, output / "data", progress,
                                    name="identification", options=identification_options())
    timings["data"] = time.perf_counter() - tick

    tick = time.perf_counter()
    jobs = plan_jobs(profile, excitation, local, tracking, identification)
    results = run_jobs(jobs, cache, workers, progress)
    timings["training"] = time.perf_counter() - tick

    tick = time.perf_counter()
    study_config = sine_sum.QUICK if profile.sine_sum == "quick" else sine_sum.FULL
    sine = reused_sine_sum(output / "sine_sum" / "results.json", study_config)
    if sine is None:
        sine = sine_sum.run_study(study_config, workers=workers, progress=progress)
        sine_sum.write_reports(sine, output / "sine_sum", quick=profile.sine_sum == "quick")
    sine["profile"] = profile.sine_sum
    timings["sine_sum"] = time.perf_counter() - tick

    tick = time.perf_counter()
    mpc_rows = run_mpc(profile, identification, results, cache, output / "mpc", progress, workers)
    timings["mpc"] = time.perf_counter() - tick
    return write_report(output, profile, excitation, local, tracking, identification, results, sine, mpc_rows,
                        timings)


def identification_options() -> tuple:
    """`stdm-drake collect` options of the identification dataset (dithered PID, ideal sensor)."""
    from stdm_drake.robot import CONTROLLERS_DIR
    return ("--controller", str(CONTROLLERS_DIR / "pid_dither.yaml"),
            "--sensor", str(CONTROLLERS_DIR / "sensor_ideal.yaml"))


def reused_sine_sum(path: pathlib.Path, study_config):
    """The stored sine-sum study at `path` if it was computed with exactly `study_config`, else None."""
    if not path.exists():
        return None
    try:
        stored = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    expected = json.loads(json.dumps(dataclasses.asdict(study_config), default=json_default))
    return stored if stored.get("config") == expected and stored.get("runs") else None


def run_mpc(profile, identification, results, cache, folder, progress, workers: int = 2) -> dict:
    """MPC with the plant and every seed of the control experiment's D, DD, PE, PED models on held-out
    plans of the identification dataset, the models split over `workers` processes; returns
    {"runs": per model instance, "types": mpc_statistics}."""
    from stdm_drake.learned_system import LearnedModel
    from stdm_drake.mpc import Reference, held_out_references, plot_results, summarize
    specs = [("plant", None)]
    for model_type in CONTROL_MODEL_TYPES:
        for match in sorted(_select(results, experiment="control", model_type=model_type), key=lambda r: r["seed"]):
            specs.append((f"{model_type} seed {match['seed']}", str(cache / f"{match['key']}.pt")))
    checkpoints = [LearnedModel(path).checkpoint for _, path in specs[1:]]
    references = held_out_references(identification, checkpoints, profile.mpc_plans)
    if profile.mpc_steps is not None:
        references = [(i, Reference(q=r.q[:profile.mpc_steps + 1], v=r.v[:profile.mpc_steps + 1])) for i, r in references]
    # the plant-as-model MPC costs about as much as all learned models together: it gets a worker of its own
    groups = [specs[:1], specs[1:]] if workers > 1 else [specs]
    jobs = [(group, references, identification.sample_period, progress and index == len(groups) - 1)
            for index, group in enumerate(groups)]
    if len(jobs) > 1:
        context = multiprocessing.get_context("spawn")
        with concurrent.futures.ProcessPoolExecutor(len(jobs), mp_context=context) as pool:
            runs = [run for group_runs in pool.map(_mpc_group, jobs) for run in group_runs]
    else:
        runs = _mpc_group(jobs[0])
    plot_results(runs, identification.sample_period, folder / "mpc.png")
    return dict(runs=summarize(runs, identification.sample_period), types=mpc_statistics(runs))


def _mpc_group(arguments) -> list:
    """Closed-loop runs of the models named in `specs` ((name, checkpoint path or None for the plant))."""
    import torch
    torch.set_num_threads(1)
    from stdm_drake.learned_system import LearnedModel
    from stdm_drake.mpc import PlantModel, compare_controllers, load_mpc_config
    specs, references, sample_period, progress = arguments
    models = [PlantModel(sample_period) if path is None else LearnedModel(path, name=name) for name, path in specs]
    return compare_controllers(models, references, load_mpc_config(), progress=progress)


def mpc_statistics(runs) -> list[dict]:
    """Per model type (runs named "TYPE seed S", the plant "plant"): mean q MSE over seeds and plans, the
    ratio of the plant-model MPC's q MSE to this type's with its 95 % interval, and, for the derivative
    twins (DD, PED), the ratio of the naive twin's (D, PE) q MSE to theirs. Pairs are plans: on each plan
    a type's q MSE is the geometric mean over its seeds, so seed-to-seed spread is averaged within a
    plan and the interval reflects plan-to-plan variation; `seed_ratios` gives each seed's own ratio
    (geometric mean over plans) for the spread between initializations."""
    by_type: dict[str, dict[int, dict[int, float]]] = {}
    solve = {}
    for run in runs:
        model_type, _, seed = run.model.partition(" seed ")
        by_type.setdefault(model_type, {}).setdefault(int(seed or 0), {})[run.trajectory] = run.q_mse_rad2
        solve.setdefault(model_type, []).append((run.solve_ms_mean, run.solve_ms_p95, run.limit_violations,
                                                  run.fallbacks))
    plans = sorted(next(iter(by_type.values()))[0])

    def per_plan(model_type):
        seeds = by_type[model_type]
        return np.exp([np.mean([np.log(seeds[seed][plan]) for seed in seeds]) for plan in plans])

    plant = per_plan("plant") if "plant" in by_type else None
    twins = {"DD": "D", "PED": "PE"}
    rows = []
    for model_type, seeds in by_type.items():
        values = per_plan(model_type)
        stats = np.array(solve[model_type])
        row = dict(model=model_type, seeds=len(seeds), plans=len(plans),
                   q_mse_rad2=float(np.mean([q for seed in seeds.values() for q in seed.values()])),
                   solve_ms_mean=float(stats[:, 0].mean()), solve_ms_p95=float(stats[:, 1].max()),
                   limit_violations=int(stats[:, 2].sum()), fallbacks=int(stats[:, 3].sum()))
        if plant is not None and model_type != "plant":
            row["plant_over_model"] = paired_ratio(plant, values).as_dict()
            row["seed_ratios"] = [float(np.exp(np.mean(np.log(plant) - np.log([seeds[seed][p] for p in plans]))))
                                  for seed in sorted(seeds)]
        if twins.get(model_type) in by_type:
            row["naive_over_derivative"] = paired_ratio(per_plan(twins[model_type]), values).as_dict()
        rows.append(row)
    return rows


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="every stage at reduced size (under a minute on 2 cores)")
    parser.add_argument("--output", "-o", type=pathlib.Path, default=pathlib.Path("out/reproduce"),
                        help="report folder (default out/reproduce); datasets and checkpoints there are reused")
    parser.add_argument("--seed", type=int, default=0, help="data collection seed")
    parser.add_argument("--workers", type=int, default=2, help="training processes (default 2)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    if args.workers < 1:
        raise InputError(f"--workers must be >= 1, got {args.workers}")
    profile = QUICK if args.quick else FULL
    started = time.perf_counter()
    path = reproduce(profile, args.output, seed=args.seed, workers=args.workers, progress=not args.quiet)
    print(f"wrote {path} and {path.with_suffix('.md')} in {time.perf_counter() - started:.0f} s")
    return 0
