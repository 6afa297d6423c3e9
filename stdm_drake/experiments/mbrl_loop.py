"""The model-based RL loop (`stdm-drake mbrl`): act with the model's MPC, collect the closed loop's data on the
(affected) plant, refit, for a number of rounds, starting from a small dataset.

Round r (0..rounds) in `output/round<r>/`:
  data.h5       every trajectory so far: the initial data (round 0: tracked by the collection controller, a
                dithered PID by default) and the closed loops of rounds < r, as `collect` writes them
  model/        `train` on data.h5 (one plan per start pose validates, the others train; no test split)
  evaluation.json  the round's model under the MPC on the evaluation plans: q MSE per plan, steps outside
                the limits, fallbacks, solve times
then, for r < rounds, `plans_per_round` new plans (planned with seed plan_seed + r, spread over the start
poses) tracked on the plant by the round's model's MPC (`closed_loop.policy.MpcPolicy`), appended for round r+1.
With `open_loop`, every round r >= 1 also trains the same model on the initial data plus the same plans
tracked by the collection controller instead (`open_loop<r>/`: the same data budget, open-loop collection),
evaluated the same way. `summary.json` holds every round's line; a round whose evaluation.json exists is
not redone, so a stopped loop resumes where it stopped (the same numbers: every draw is seeded).
"""
import dataclasses
import json
import pathlib
import sys
import time

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.files import write_text_atomic
from stdm_drake.interrupts import protected
from stdm_drake.paths import CONTROLLERS_DIR
from stdm_drake.cluster import RunnerConfig, job_pool
from stdm_drake.closed_loop.ancillary_law import check_law_stable
from stdm_drake.closed_loop.policy import MpcPolicy
from stdm_drake.dynamics.model_files import load_model
from stdm_drake.closed_loop.tuning import finite_mse
from stdm_drake.experiments.mbrl_causes import description_model_loops

MAX_ROUNDS = 100


@dataclasses.dataclass
class LoopConfig:
    """The loop's settings. robot: a Robot loaded from its config file; plant_effects: a PlantEffects or None (the
    description as it is); mpc: an MpcConfig (its optimizer acts); model: `train`'s model type, with `train`
    (a dict of further TrainSettings fields); rounds, initial_plans, plans_per_round, evaluation_plans (each spread
    over the start poses); data_seed: the initial data's, plan_seed: round r's plans use plan_seed + r,
    evaluation_seed: the evaluation plans'; seed: the model's training seed; controller and sensor: the
    collection's YAML files (the initial data, and the open-loop comparison); workers: collection processes."""
    output: pathlib.Path
    robot: object
    mpc: object
    plant_effects: object = None
    model: str = "D"
    train: dict = dataclasses.field(default_factory=dict)
    rounds: int = 5
    initial_plans: int = 8
    plans_per_round: int = 8
    evaluation_plans: int = 8
    data_seed: int = 100
    plan_seed: int = 1000
    evaluation_seed: int = 2000
    seed: int = 0
    controller: pathlib.Path | None = None
    sensor: pathlib.Path | None = None
    open_loop: bool = False
    workers: int = 1

    def validate(self) -> None:
        """InputError (one line) for counts the loop cannot run, before any work."""
        if not 1 <= self.rounds <= MAX_ROUNDS:
            raise InputError(f"--rounds must be in 1..{MAX_ROUNDS}, got {self.rounds}")
        from stdm_drake.collection.collect import MAX_COUNT   # lazy: pydrake, h5py
        for name in ("initial_plans", "plans_per_round", "evaluation_plans"):
            if not 1 <= getattr(self, name) <= MAX_COUNT:
                raise InputError(f"--{name.replace('_', '-')} must be in 1..{MAX_COUNT} (collect's limit), got "
                                 f"{getattr(self, name)}")
        if self.initial_plans + self.rounds * self.plans_per_round > MAX_COUNT:
            raise InputError(f"the loop's dataset would hold {self.initial_plans + self.rounds * self.plans_per_round} "
                             f"plans (--initial-plans + --rounds x --plans-per-round), beyond collect's {MAX_COUNT}")
        for name in ("data_seed", "plan_seed", "evaluation_seed", "seed"):
            top = 2 ** 63 - 1 - (self.rounds if name == "plan_seed" else 0)   # (round r plans with plan_seed + r)
            if not 0 <= getattr(self, name) <= top:
                raise InputError(f"--{name.replace('_', '-')} must be in 0..{top}, got {getattr(self, name)}")
        from stdm_drake.learning.models import GREY_BOX_TYPES   # lazy: torch
        from stdm_drake.learning.settings import TrainSettings   # lazy: torch, pydrake, h5py
        if str(self.model).upper() in GREY_BOX_TYPES:
            raise InputError(f"--model {self.model}: a grey box needs an identified robot (train --physics), which the "
                             "loop does not refit; use D, P, DE, PE or their derivative-trained twins")
        settings = TrainSettings(model=self.model, seeds=[self.seed], **self.train)
        settings.validate(given=frozenset(("model", *self.train)))
        self.mpc.validate()
        optimizer = self.mpc.optimizer
        if getattr(optimizer, "framework", "numpy") == "torch" and (settings.predicts, settings.inputs) != ("state", "raw"):
            raise InputError(f"mpc optimizer framework torch runs the paper's black box only (train predicts: state, "
                             f"inputs: raw); --model {self.model} here is structured: use framework numpy")
        request = collection(self, self.initial_plans, self.data_seed)
        if hasattr(optimizer, "feedback_kp"):   # (a sampler's law at the data's period, which the model will have)
            check_law_stable(optimizer, request.settings.sample_period)
        sampling = request.tracking_spec.sampling
        poses, capacity = len(sampling.initial_poses), len(sampling.initial_poses) * sampling.num_final_per_initial
        for name in ("initial_plans", "plans_per_round", "evaluation_plans"):   # (collect's own check, before round 0)
            if getattr(self, name) > capacity:
                raise InputError(f"--{name.replace('_', '-')} {getattr(self, name)}: the plans' specification yields "
                                 f"{poses} start poses x {sampling.num_final_per_initial} final poses = {capacity} plans")
        if self.initial_plans < 2 * poses:
            raise InputError(f"--initial-plans {self.initial_plans}: the robot's plans start from {poses} poses, and "
                             f"training validates on {poses} of the plans: give at least {2 * poses}")
        members = settings.ensemble_size if "E" in settings.model else 1
        if getattr(optimizer, "propagation", "mean") != "mean" and optimizer.particles % members:
            raise InputError(f"mpc optimizer particles ({optimizer.particles}) must be a multiple of the model's {members} "
                             "ensemble members")
        if getattr(optimizer, "propagation", "mean") != "mean" and members == 1 and not settings.model.startswith("P"):
            raise InputError(f"mpc optimizer propagation {optimizer.propagation} with {optimizer.particles} particles "
                             f"samples an ensemble's members, and --model {self.model} has one deterministic member; "
                             "use propagation: mean")
        from stdm_drake.learning.settings import MAX_TOTAL_EPOCHS   # lazy: torch, pydrake, h5py
        fits = (self.rounds + 1) * (2 if self.open_loop else 1)   # (a model per round, and the open-loop twin's)
        if settings.epochs * fits > MAX_TOTAL_EPOCHS:
            raise InputError(f"--epochs {settings.epochs:,} for each of the loop's {fits} trainings (--rounds "
                             f"{self.rounds}{' with --open-loop' if self.open_loop else ''}) are "
                             f"{settings.epochs * fits:,} epochs, more than the {MAX_TOTAL_EPOCHS:,} one run may train")


def collection(config: LoopConfig, count: int, seed: int):
    """The tracking `CollectionRequest` of `count` plans of `seed` on the loop's plant (its controller and sensor)."""
    from stdm_drake.collection.collect import collection_request   # lazy: pydrake, h5py
    from stdm_drake.experiments.jobs import IDENTIFICATION_SETTINGS   # lazy: torch, pydrake, h5py
    return collection_request("tracking", count=count, seed=seed, robot=config.robot,
                              controller=config.controller or CONTROLLERS_DIR / "pid_dither_sized.yaml",
                              sensor=config.sensor or IDENTIFICATION_SETTINGS["sensor"],
                              plant_effects=config.plant_effects, workers=config.workers)


def planned(request):
    """(plans, groups) of a tracking request (`collect.plan_tracking`, in this process)."""
    from stdm_drake.collection.collect import init_station_worker, plan_tracking   # lazy: pydrake, h5py
    with job_pool(RunnerConfig(workers=1), initializer=init_station_worker, initargs=(request.settings,)) as pool:
        return plan_tracking(request, pool)


def track_with_mpc(station, model, plans, config: LoopConfig, seed: int) -> tuple[list, list, dict]:
    """The trajectories (dataset arrays) of `plans` tracked on the station's plant by the MPC of `model`, their
    start poses' indices, and counts. A closed loop that leaves the robot's limits is cut at its last sample
    inside them (a robot's safety stop: what it recorded up to there is kept; fewer than 2 periods, nothing)."""
    from stdm_drake.closed_loop.mpc import Reference   # lazy: pydrake
    from stdm_drake.robots.control import JointSensor   # lazy: pydrake
    trajectories, kept, stopped, fallbacks, steps = [], [], 0, 0, 0
    limits = station.limits
    for index, plan in enumerate(plans):
        policy = MpcPolicy(model, Reference(q=plan.q, v=plan.qd), config.mpc, config.robot)
        rng = np.random.default_rng([seed, index])
        traj = station.run(plan.q[0], len(plan.q) - 1, policy.control, JointSensor(station.settings.sensor, rng), rng)
        traj.update(q_planned=plan.q, v_planned=plan.qd, qdd_planned=plan.qdd)
        fallbacks += policy.fallbacks
        q, v = traj["q_true"], traj["v_true"]
        outside = np.flatnonzero(((q < limits.position_lower) | (q > limits.position_upper)
                                  | (np.abs(v) > limits.velocity) | ~np.isfinite(q) | ~np.isfinite(v)).any(axis=1))
        if len(outside):
            stopped += 1
            traj = cut(traj, int(outside[0]) - 1)
            if traj is None:
                continue
        steps += len(traj["tau"])
        trajectories.append(traj)
        kept.append(index)
    return trajectories, kept, dict(plans=len(plans), kept=len(trajectories), safety_stops=stopped,
                                    fallbacks=fallbacks, steps=steps)


def cut(traj: dict, last: int) -> dict | None:
    """The trajectory's samples 0..last (periods 0..last-1; tau_next the torque of period `last`), or None for
    fewer than 2 periods."""
    if last < 2:
        return None
    samples = {key: value[:last + 1] for key, value in traj.items() if key not in ("tau", "qdd_end", "tau_next")}
    return dict(samples, tau=traj["tau"][:last], qdd_end=traj["qdd_end"][:last], tau_next=traj["tau"][last])


def write_trajectories(path: pathlib.Path, trajectories: list, groups: list, metadata: dict) -> None:
    """A dataset of `trajectories` (Trajectory) with `metadata` (its count set), unless it exists."""
    from stdm_drake.data.writer import write_dataset   # lazy: pydrake, h5py
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        write_dataset(path, trajectories, groups, dict(metadata, num_trajectories=len(trajectories)))


def train_round(config: LoopConfig, data_path: pathlib.Path, folder: pathlib.Path) -> tuple[pathlib.Path, dict]:
    """`train` of the loop's model on a round's data (as many plans as there are start poses validate, drawn by the
    split seed, the others train); returns the checkpoint and the validation verdict against the physics-free
    baselines."""
    from stdm_drake.data.dataset import load_dataset   # lazy: pydrake, h5py
    from stdm_drake.learning.settings import TrainSettings   # lazy: torch, pydrake, h5py
    from stdm_drake.learning.train_job import TrainJob, train_job   # lazy: torch, pydrake, h5py
    checkpoint = folder / f"seed{config.seed}" / "checkpoint.pt"
    summary_path = folder / "summary.json"
    if not summary_path.exists():
        groups = load_dataset(data_path).groups
        validation = len(np.unique(groups))
        if len(groups) < 2 * validation:
            raise InputError(f"{data_path}: {len(groups)} plans for {validation} start poses; the initial data need at "
                             "least 2 per pose (--initial-plans)")
        given = dict(model=config.model, seeds=[config.seed], train=len(groups) - validation, val=validation, test=0,
                     per_group="off", **config.train)
        train_job(TrainJob(dataset=data_path, output=folder, settings=TrainSettings(**given),
                           robot=config.robot.config_path, resume=checkpoint.exists(), force=True, progress=False,
                           given=frozenset(given)))
    summary = json.loads(summary_path.read_text())
    return checkpoint, validation_verdict(summary["seeds"][str(config.seed)])


def validation_verdict(entry: dict) -> dict:
    """The model's line of `train`'s validation comparison with the physics-free baselines (a summary.json entry)."""
    for value in entry.values():
        if isinstance(value, dict) and "models" in value:
            first = value["models"][0]   # (train's names: the ratios to the Euler step and to 'v unchanged')
            names = dict(ratio_q="ratio_to_euler_q", ratio_v="ratio_to_velocity_unchanged_v", verdict="verdict")
            return {key: first[name] for key, name in names.items() if name in first}
    return {}


def evaluate(config: LoopConfig, checkpoint: pathlib.Path, references: list, plant_config) -> dict:
    """The round's model under the loop's MPC on the evaluation references: per plan q MSE (rad²), steps outside
    the limits, fallbacks, mean solve ms."""
    from stdm_drake.closed_loop.comparison import compare_controllers   # lazy: pydrake
    model = load_model(checkpoint, config.robot, name=config.model, for_control=True)
    results = compare_controllers([model], references, config.mpc, plant_config, progress=False, robot=config.robot)
    mse = [result.q_mse_rad2 for result in results]
    return dict(q_mse_per_plan=mse,   # (a diverged plan counts as tuning.DIVERGED_Q_MSE in the geometric mean)
                q_mse_geometric_mean=float(np.exp(np.mean(np.log([max(finite_mse(value), 1e-300) for value in mse])))),
                steps_outside_limits=int(sum(result.limit_violations for result in results)),
                fallbacks=int(sum(result.fallbacks for result in results)),
                solve_ms_mean=float(np.mean([result.solve_ms_mean for result in results])))


def run_loop(config: LoopConfig, references: list | None = None, say=print, progress: bool = False) -> dict:
    """The loop of `config` (module docstring); references: the evaluation's (index, mpc.Reference) pairs (None:
    `evaluation_plans` plans of `evaluation_seed`); progress: a bar of the rounds on stderr. Returns the summary
    (also in output/summary.json)."""
    from tqdm import tqdm
    from stdm_drake.closed_loop.mpc import Reference   # lazy: pydrake
    from stdm_drake.collection.collect import collect, collection_metadata   # lazy: pydrake, h5py
    from stdm_drake.data.dataset import Trajectory, load_dataset   # lazy: pydrake, h5py
    from stdm_drake.robots.station import Station   # lazy: pydrake
    config.validate()
    started = time.perf_counter()
    output = pathlib.Path(config.output)
    check_loop_folder(output, config.rounds)
    initial_request = collection(config, config.initial_plans, config.data_seed)
    if references is None:
        plans, _ = planned(collection(config, config.evaluation_plans, config.evaluation_seed))
        references = [(index, Reference(q=plan.q, v=plan.qd)) for index, plan in enumerate(plans)]
    check_same_loop(output, config, references)
    metadata = collection_metadata(initial_request)
    initial_path = output / "round0" / "data.h5"
    if not initial_path.exists():
        trajectories, groups, metadata = collect(initial_request, progress=False)
        with protected():   # (a signal in the write is raised once the summary names the round: held-out run 13)
            write_trajectories(initial_path, trajectories, groups,
                               dict(metadata, mbrl_loop=dict(round=0, mpc_trajectories=0)))
            write_summary(output, config, references, [], started, pending=0)
    station = Station(initial_request.settings)
    plant_config = initial_request.settings.plant
    rows = []
    bar = tqdm(total=config.rounds + 1, desc="mbrl rounds", unit="round", disable=not progress, file=sys.stderr)
    for round_index in range(config.rounds + 1):
        if round_index:
            bar.update()
        folder = output / f"round{round_index}"
        data_path = folder / "data.h5"
        checkpoint, learned = train_round(config, data_path, folder / "model")
        evaluation_path = folder / "evaluation.json"
        if not evaluation_path.exists():
            write_text_atomic(evaluation_path, json.dumps(evaluate(config, checkpoint, references, plant_config)))
        data = load_dataset(data_path)
        row = dict(round=round_index, trajectories=data.num_trajectories, learned=learned,
                   **json.loads(evaluation_path.read_text()))
        if config.open_loop and round_index > 0:
            row["open_loop"] = open_loop_round(config, round_index, references, plant_config, station, metadata)
        rows.append(row)
        say(f"mbrl round {round_index}: {data.num_trajectories} trajectories, closed-loop q MSE "
            f"{row['q_mse_geometric_mean']:.3g} rad² (geometric mean over {len(references)} plans), "
            f"{row['steps_outside_limits']} steps outside the limits"
            + (f"; open-loop data: {row['open_loop']['q_mse_geometric_mean']:.3g}" if "open_loop" in row else ""))
        if round_index == config.rounds:
            break
        plans, groups = planned(collection(config, config.plans_per_round, config.plan_seed + round_index))
        following = output / f"round{round_index + 1}" / "data.h5"
        if not following.exists():
            model = load_model(checkpoint, config.robot, name=config.model, for_control=True)
            tracked, kept, counts = track_with_mpc(station, model, plans, config, config.plan_seed + round_index)
            old = [data.trajectory(index) for index in range(data.num_trajectories)]
            # (once this run has collected a round's data: a run stopped later still names every round folder, the
            # new one as pending, also when the signal lands in the write; a resumed run that collects nothing
            # leaves the summary as it was until the end)
            with protected():
                write_text_atomic(folder / "collection.json", json.dumps(counts))
                write_trajectories(following, old + [Trajectory(**traj) for traj in tracked],
                                   list(data.groups) + [groups[index] for index in kept],
                                   dict(metadata, mbrl_loop=dict(round=round_index + 1, mpc=config.mpc.record(),
                                                                 mpc_trajectories=len(old) + len(tracked)
                                                                 - config.initial_plans)))
                row["collection"] = json.loads(json.dumps(counts))
                write_summary(output, config, references, rows, started, pending=round_index + 1)
        row["collection"] = json.loads((folder / "collection.json").read_text())
    bar.update()
    bar.close()
    if rows and rows[-1]["steps_outside_limits"]:   # (a plant no torque holds: named with the failure)
        unholdable, why = station.gravity_beyond(np.vstack([reference.q for _, reference in references]))
        if unholdable:
            rows[-1]["gravity"] = why
        elif str((rows[-1].get("learned") or {}).get("verdict", "learned")).startswith("learned"):
            # (held-out run 37: a model train judged learned left the limits, no cause named)
            rows[-1]["description_model"] = description_model_loops(config, references, station)
    return write_summary(output, config, references, rows, started)


def write_summary(output: pathlib.Path, config: LoopConfig, references: list, rows: list, started: float,
                  pending: int | None = None) -> dict:
    """Write the loop's summary.json of the rounds so far (`rows`) and return it; pending: the round whose data
    are collected (its folder holds data.h5) but not yet trained on, recorded as `pending_round`."""
    summary = dict(config=loop_record(config), evaluation_plans=[index for index, _ in references], rounds=rows,
                   seconds=round(time.perf_counter() - started, 1))
    if pending is not None:
        summary["pending_round"] = dict(round=pending, data=f"round{pending}/data.h5")
    write_text_atomic(output / "summary.json", json.dumps(summary, indent=1))
    return summary


def loop_record(config: LoopConfig) -> dict:
    """What fixes a loop's rounds (a rerun into the same folder must have the same; the round count may grow)."""
    effects = config.plant_effects.record() if config.plant_effects is not None else None
    return dict(robot=config.robot.model_sha256(), plant_effects=effects, model=config.model, train=config.train,
                initial_plans=config.initial_plans, plans_per_round=config.plans_per_round, seed=config.seed,
                data_seed=config.data_seed, plan_seed=config.plan_seed, mpc=config.mpc.record(),
                controller=str(config.controller), sensor=str(config.sensor))


def check_loop_folder(output: pathlib.Path, rounds: int) -> None:
    """InputError (one line, before any work) for an output that would change a loop's files: a folder inside a
    loop's folder (one holding loop.json: its round folders), or a rerun with fewer rounds than the folder holds
    (summary.json would then name fewer rounds than the round folders beside it)."""
    output = pathlib.Path(output)
    for parent in output.resolve().parents:   # (resolved: a link into a loop's folder is inside it)
        if (parent / "loop.json").is_file():
            raise InputError(f"-o/--output {output} is inside the loop in {parent}, whose rounds it would change; "
                             "give a folder outside it")
    held = [int(folder.name[5:]) for folder in output.glob("round*") if folder.name[5:].isdigit()]
    if held and max(held) > rounds:
        raise InputError(f"{output} holds rounds 0..{max(held)} of its loop; resume it with --rounds {max(held)} or "
                         "more, or give another -o/--output")


def check_same_loop(output: pathlib.Path, config: LoopConfig, references: list) -> None:
    """Record the loop's settings and evaluation plans in output/loop.json on its first run; InputError when a rerun
    into the folder differs (its rounds would mix two loops)."""
    record = json.loads(json.dumps(dict(loop_record(config), evaluation=[np.round(reference.q, 9).tolist()
                                                                          for _, reference in references])))
    path = output / "loop.json"
    if path.exists():
        previous = json.loads(path.read_text())
        changed = sorted(key for key in set(record) | set(previous) if record.get(key) != previous.get(key))
        if changed:
            raise InputError(f"{output} holds a loop of other settings ({', '.join(changed)} differ); give another "
                             "-o/--output, or the same settings to resume it")
        return
    output.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(record))


def open_loop_round(config: LoopConfig, round_index: int, references: list, plant_config, station, metadata) -> dict:
    """The same budget collected open loop: the initial data plus rounds 0..round_index-1's plans tracked by the
    collection controller, trained and evaluated as the loop's rounds."""
    from stdm_drake.collection.collect import tracking_trajectory   # lazy: pydrake, h5py
    from stdm_drake.data.dataset import Trajectory, load_dataset   # lazy: pydrake, h5py
    folder = pathlib.Path(config.output) / f"open_loop{round_index}"
    data_path = folder / "data.h5"
    if not data_path.exists():
        initial = load_dataset(pathlib.Path(config.output) / "round0" / "data.h5")
        trajectories = [initial.trajectory(index) for index in range(initial.num_trajectories)]
        groups = list(initial.groups)
        for previous in range(round_index):
            seed = config.plan_seed + previous
            plans, plan_groups = planned(collection(config, config.plans_per_round, seed))
            for index, plan in enumerate(plans):
                traj = tracking_trajectory(station, plan, np.random.default_rng([seed, index]))
                trajectories.append(Trajectory(**traj))
            groups += list(plan_groups)
        write_trajectories(data_path, trajectories, groups, dict(metadata, mbrl_loop=dict(open_loop=round_index)))
    checkpoint, learned = train_round(config, data_path, folder / "model")
    evaluation_path = folder / "evaluation.json"
    if not evaluation_path.exists():
        write_text_atomic(evaluation_path, json.dumps(evaluate(config, checkpoint, references, plant_config)))
    return dict(trajectories=load_dataset(data_path).num_trajectories, learned=learned,
                **json.loads(evaluation_path.read_text()))
