"""The reality-gap experiment (docs/reality_gap.md): learned models against the nominal model on an
affected UR-10 plant. Part 1 (closed loop): D and DD models (`train`'s defaults) on dithered-PID tracking
data of the plant with models/ur10_effects.yaml; MPC with the nominal plant, the true plant and each
learned model on the test plans, the offset-free observer on and off; the torque Jacobian of each model
against the true plant's. Part 2 (open loop per effect): the same per plant with friction only, rotor
inertia only, payload only and all effects. `tools/reality_gap.py` is its command line.
"""
import dataclasses
import math
import pathlib

import numpy as np

from stdm_drake.paths import MODELS_DIR

TYPES = ("D", "DD")
EFFECTS_PRESET = MODELS_DIR / "ur10_effects.yaml"
# (plans, per-pose train / val / test, seeds, max epochs) of the two parts, full and --quick
FULL = dict(closed=(100, 18, 2, 5, 5, 300), open=(40, 7, 1, 2, 3, 300), mpc_steps=None)
QUICK = dict(closed=(12, 1, 1, 1, 2, 5), open=(12, 1, 1, 1, 1, 5), mpc_steps=15)


def effect_plants(preset, robot, time_step: float = 0.001):
    """The per-effect plants of part 2: name -> PlantEffects (each with one of the preset's effects).
    Without the rotor inertia the wrists' Coulomb friction is too stiff for the explicit friction term at
    the plant step: the friction-only plant raises a joint's velocity scale to 2 h F_c / M_eff (M_eff: the
    joint's effective inertia at home) where the preset's is smaller (a gain of 0.5)."""
    from stdm_drake.robots.effects import PlantEffects
    from stdm_drake.robots.plant import Dynamics
    n = robot.num_joints
    coulomb = preset.joint_values("coulomb_friction", n)
    stable = 2.0 * time_step * coulomb / Dynamics(robot).effective_inertia(robot.home)
    scale = np.maximum(preset.joint_values("coulomb_velocity_scale", n), stable)
    friction = PlantEffects(source=preset.source, viscous_friction=preset.viscous_friction,
                            coulomb_friction=preset.coulomb_friction, coulomb_velocity_scale=scale.tolist())
    rotor = PlantEffects(source=preset.source, rotor_inertia=preset.rotor_inertia, gear_ratio=preset.gear_ratio)
    payload = PlantEffects(source=preset.source, payload=preset.payload)
    return {"friction": friction, "rotor inertia": rotor, "payload": payload, "all": preset}


def dataset(folder: pathlib.Path, name: str, effects, plans: int, seed: int):
    """The dithered-PID tracking dataset of the affected plant (collected once, reused when its settings agree)."""
    from stdm_drake.experiments.jobs import IDENTIFICATION_SETTINGS, ensure_dataset
    from stdm_drake.robots.robot import UR10_CONFIG
    return ensure_dataset("tracking", plans, seed, folder, progress=False, name=name.replace(" ", "_"),
                          robot=UR10_CONFIG, plant_effects=effects, workers=2, **IDENTIFICATION_SETTINGS)


def train(dataset_path: str, model_type: str, split: tuple, seeds: int, epochs: int, folder: str) -> str:
    """`stdm-drake train` of one model type, every seed (in a pool worker); the run folder. A folder
    whose every seed's checkpoint exists is reused."""
    from stdm_drake.cli import main
    folder = pathlib.Path(folder)
    if all((folder / f"seed{seed}" / "checkpoint.pt").exists() for seed in range(seeds)):
        return str(folder)
    train_count, val_count, test_count = split
    code = main(["train", dataset_path, "--model", model_type, "--train", str(train_count), "--val", str(val_count),
                 "--test", str(test_count), "--per-group", "on", "--derivative-source", "true",
                 "--action-rate", "zero_order_hold", "--epochs", str(epochs), "--seeds", *map(str, range(seeds)),
                 "--quiet", "--force", "-o", str(folder)])
    if code != 0:
        raise RuntimeError(f"train {model_type} on {dataset_path} failed ({code})")
    return str(folder)


def closed_loop_group(specs: list, dataset_path: str, checkpoints: list, plans: int, steps, observer: bool) -> list:
    """MPC runs (ClosedLoopResult dicts) of the models in `specs` ((name, checkpoint path; None: the nominal
    plant; "true": the affected plant)) on the test plans, on the affected plant the dataset records."""
    import torch
    torch.set_num_threads(1)
    from stdm_drake.closed_loop.comparison import compare_controllers, held_out_references
    from stdm_drake.closed_loop.mpc import Reference, mpc_config_for
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.learning.checkpoint import load_checkpoint
    from stdm_drake.learning.learned_model import LearnedModel
    from stdm_drake.learning.physics import PlantModel
    from stdm_drake.robots.plant import PlantConfig
    from stdm_drake.robots.robot import UR10_CONFIG, load_robot
    robot = load_robot(UR10_CONFIG)
    data = load_dataset(dataset_path)
    plant = PlantConfig.discrete(data.metadata.plant_time_step, effects=data.metadata.plant_effects)
    references = held_out_references(data, [load_checkpoint(path) for path in checkpoints], plans)
    if steps is not None:
        references = [(i, Reference(q=r.q[:steps + 1], v=r.v[:steps + 1])) for i, r in references]
    config = mpc_config_for(robot)
    if not observer:
        config = dataclasses.replace(config, disturbance_gain=0.0)
    models = []
    for name, path in specs:
        if path is None:
            models.append(PlantModel(data.sample_period, robot=robot))
        elif path == "true":
            models.append(PlantModel(data.sample_period, plant, robot=robot))
        else:
            models.append(LearnedModel(path, name=name, robot=robot))
    results = compare_controllers(models, references, config, plant, progress=False, robot=robot)
    return [dict(dataclasses.asdict(result), observer=observer) for result in results]


def seed_interval(log_ratios: list) -> dict:
    """Geometric mean of per-seed ratios (given as logs) with a Student-t 95 % interval over the seeds."""
    from scipy import stats
    values = np.asarray(log_ratios, dtype=float)
    mean = float(values.mean())
    if len(values) < 2:
        return dict(ratio=math.exp(mean), low=0.0, high=math.inf, seeds=len(values))
    half = float(stats.t.ppf(0.975, len(values) - 1) * values.std(ddof=1) / math.sqrt(len(values)))
    return dict(ratio=math.exp(mean), low=math.exp(mean - half), high=math.exp(mean + half), seeds=len(values))


def closed_loop_summary(runs: list, seeds: int) -> list:
    """Per observer setting and model type: the seed-level ratio nominal MPC q MSE / the type's (each seed
    a geometric mean over plans), violations, fallbacks and per-step solve times; the plants beside them."""
    rows = []
    for observer in (True, False):
        mine = [run for run in runs if run["observer"] == observer]
        if not mine:
            continue
        nominal = {run["trajectory"]: run["q_mse_rad2"] for run in mine if run["model"] == "plant"}
        names = ["plant", "true-plant"] + [f"{t} seed {s}" for t in TYPES for s in range(seeds)]
        per_model = {}
        for name in names:
            model_runs = [run for run in mine if run["model"] == name]
            if model_runs:
                per_model[name] = model_runs
        for label in ["plant", "true-plant", *TYPES]:
            members = [name for name in per_model if name == label or name.startswith(f"{label} seed ")]
            if not members:
                continue
            logs = [float(np.mean([math.log(nominal[run["trajectory"]] / run["q_mse_rad2"]) for run in per_model[name]]))
                    for name in members]
            runs_of = [run for name in members for run in per_model[name]]
            rows.append(dict(observer=observer, model=label, models=len(members), plans=len(per_model[members[0]]),
                             q_mse=float(np.exp(np.mean([math.log(run["q_mse_rad2"]) for run in runs_of]))),
                             nominal_over_model=seed_interval(logs) if label in TYPES else
                             dict(ratio=math.exp(logs[0])),
                             limit_violations=int(sum(run["limit_violations"] for run in runs_of)),
                             fallbacks=int(sum(run["fallbacks"] for run in runs_of)),
                             solve_ms_mean=float(np.mean([run["solve_ms_mean"] for run in runs_of]))))
    return rows


def torque_jacobian_errors(dataset_path: str, folders: dict, seeds: int, count: int = 200) -> list:
    """Relative Frobenius error ||B_model - B_true|| / ||B_true|| (median over `count` test transitions) of
    the nominal plant and every learned model, B = d x_{k+1} / d u_k, the torque Jacobian iLQR uses."""
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.learning.learned_model import LearnedModel
    from stdm_drake.learning.physics import PlantModel
    from stdm_drake.robots.plant import PlantConfig
    from stdm_drake.robots.robot import UR10_CONFIG, load_robot
    robot = load_robot(UR10_CONFIG)
    data = load_dataset(dataset_path)
    first = LearnedModel(pathlib.Path(folders[TYPES[0]]) / "seed0" / "checkpoint.pt", robot=robot)
    test = first.checkpoint.split_indices(data, "test")
    transitions = data.transitions(list(test))
    rows = np.random.default_rng(0).choice(len(transitions.state), size=min(count, len(transitions.state)),
                                           replace=False)
    x, u = transitions.state[rows], transitions.action[rows]
    truth = PlantModel(data.sample_period, PlantConfig.discrete(data.metadata.plant_time_step,
                                                                effects=data.metadata.plant_effects), robot=robot)
    _, b_true = truth.jacobians(x, u)
    norms = np.linalg.norm(b_true, axis=(1, 2))

    def error(model) -> float:
        _, b = model.jacobians(x, u)
        return float(np.median(np.linalg.norm(b - b_true, axis=(1, 2)) / norms))

    result = [dict(model="plant", relative_error=error(PlantModel(data.sample_period, robot=robot)))]
    for model_type, folder in folders.items():
        values = [error(LearnedModel(pathlib.Path(folder) / f"seed{seed}" / "checkpoint.pt", robot=robot))
                  for seed in range(seeds)]
        result.append(dict(model=model_type, relative_error=float(np.median(values)), per_seed=values))
    return result


def open_loop_rows(name: str, dataset_path: str, folders: dict, seeds: int) -> list:
    """Part 2 for one plant: test errors of the nominal plant, the physics-free baselines and each learned
    type (mean over seeds; a learned type 'captures' the effect at a horizon when every seed beats the
    nominal model there)."""
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.learning.evaluate import compare_with_baselines, physics_baselines, trajectory_rollout_data
    from stdm_drake.learning.learned_model import LearnedModel
    from stdm_drake.robots.robot import UR10_CONFIG, load_robot
    robot = load_robot(UR10_CONFIG)
    data = load_dataset(dataset_path)
    learned = {model_type: [LearnedModel(pathlib.Path(folder) / f"seed{seed}" / "checkpoint.pt", robot=robot)
                            for seed in range(seeds)] for model_type, folder in folders.items()}
    test = learned[TYPES[0]][0].checkpoint.split_indices(data, "test")
    baselines = physics_baselines(data.sample_period, robot.state_dim, robot.action_dim, robot=robot)
    models = baselines + [model for models in learned.values() for model in models]
    errors = compare_with_baselines(models, data.transitions(list(test)), trajectory_rollout_data(data, test, 100))
    horizon = errors[0].multi_step.horizon

    def figures(found) -> dict:
        q = found.multi_step.angle_mse
        return dict(one_step_q=found.one_step.angle_mse, one_step_v=found.one_step.velocity_mse,
                    open_loop_q_20=float(q[min(20, horizon) - 1]), open_loop_q_end=float(q[-1]))

    by_name = {row.name: row for row in errors[:len(baselines)]}
    nominal = figures(by_name["plant"])
    stays = figures(by_name["stays put"])   # one step: the Euler step's; open loop: staying put
    physics_free = figures(by_name["Euler step"]) | {key: stays[key] for key in ("open_loop_q_20", "open_loop_q_end")}
    rows = [dict(plant=name, model="nominal plant", **nominal),
            dict(plant=name, model="Euler step / v unchanged / stays put", **physics_free)]
    position = len(baselines)
    for model_type, models in learned.items():
        found = [figures(row) for row in errors[position:position + len(models)]]
        verdicts = [row.verdict for row in errors[position:position + len(models)]]
        position += len(models)
        mean = {key: float(np.mean([f[key] for f in found])) for key in found[0]}
        captures = {key: all(f[key] < nominal[key] for f in found) for key in ("one_step_q", "open_loop_q_20",
                                                                              "open_loop_q_end")}
        rows.append(dict(plant=name, model=model_type, **mean, seeds=len(models), learned=verdicts,
                         beats_nominal_every_seed=captures))
    return rows
