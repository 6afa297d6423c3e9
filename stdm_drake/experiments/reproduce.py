"""The paper's robot experiments (section V) end to end for a robot, with a report (`stdm-drake reproduce`).

Stages: (1) datasets: excitation (simulated UR-10, V.A) and tracked task-space plans (our stand-in
for the real robot, V.B); (2) training jobs, two worker processes, each checkpoint cached under
`<output>/cache` by a hash of its dataset and settings, so a rerun into the same folder reuses what exists; (3) figures
and tables: activations (Figs. 11, 16), sample efficiency (Figs. 12, 17), learning curves (Fig. 13),
multi-step prediction and rollout time (Figs. 18, 19); the sine-sum study (III.B) and the
closed-loop MPC comparison; (4) `report.md` / `report.html` with the paper's reported values in
clearly labelled "paper" columns and a plain statement wherever ours differ. Raw results go to
`results.json` and CSV files. Every other number is computed by the run.

Modules: `jobs` (profiles, datasets, training jobs), `reproduce_report` (tables, figures, report),
this one (the stages in order and the MPC comparison); the command is `stdm_drake.commands.reproduce`.
"""
import dataclasses
import json
import math
import pathlib
import time

from stdm_drake.cluster import RunnerConfig, job_pool
from stdm_drake.experiments.jobs import (CONTROL_MODEL_TYPES, IDENTIFICATION_SETTINGS, Profile, ensure_dataset,
                                         plan_jobs, run_jobs)
from stdm_drake.experiments.results import select_rows
from stdm_drake.experiments.default_model import default_model_jobs
from stdm_drake.experiments.reproduce_document import write_report
from stdm_drake.experiments.reproduce_report import mpc_statistics
from stdm_drake.files import json_default
from stdm_drake.outputs import mark_output_folder
from stdm_drake.paths import CONTROLLERS_DIR
from stdm_drake.robots.plant import PlantConfig
from stdm_drake.robots.robot import Robot
from stdm_drake.collection.excitation import Excitation
from stdm_drake.experiments import sine_sum
from stdm_drake.learning.learned_model import LearnedModel
from stdm_drake.closed_loop.mpc import Reference, mpc_config_for
from stdm_drake.closed_loop.comparison import (closed_loop_failures, held_out_references, plot_results, summarize,
                                               compare_controllers, spec_models)

def dataset_settings(robot: Robot, plant_effects=None) -> dict:
    """`ensure_dataset` settings of the four datasets for `robot`: the files its config's `defaults` names
    (the UR-10 preset names all four), and for the ones it does not, the same protocols derived from its
    model (excitation ranges from its inertia, start poses over its whole range for "excitation" and
    within +-0.5 rad of home for "excitation_local", tracking poses around home, PID gains and dither
    sized from its inertia); every one collected on the plant with `plant_effects` (None: the robot's
    description as it is). On a plant with effects the identification data's PID gains and dither are
    sized from that plant's inertia (a servo is tuned on the robot it drives; gains sized for the
    description leave a geared wrist held by its friction: docs/reality_gap.md)."""
    excitation, local = robot.default_file("excitation"), robot.default_file("excitation_local")
    controller = None if plant_effects is not None else robot.default_file("identification_controller")
    common = dict(robot=robot, plant_effects=plant_effects)
    return dict(
        excitation=(dict(common, config=excitation) if excitation else
                    dict(common, excitation=Excitation.derived_for(robot, box=math.pi))),
        local=(dict(common, config=local) if local else
               dict(common, excitation=Excitation.derived_for(robot))),
        tracking=dict(common),
        identification=dict(IDENTIFICATION_SETTINGS, **common,
                            controller=controller or CONTROLLERS_DIR / "pid_dither_sized.yaml"))


def reproduce(profile: Profile, output: pathlib.Path, seed: int = 0, workers: int = 2, progress: bool = True,
              *, robot: Robot, runner=None, plant_effects=None):
    """Run every stage for `robot`; returns the report path and the MPC
    stage's failures (`comparison.closed_loop_failures`: closed loops that left the robot's limits or fell
    back). runner: a RunnerConfig for the training jobs (default: the local pool of `workers` processes).
    plant_effects: a checked PlantEffects: every dataset and closed loop on that affected plant, the MPC
    stage's plant model the robot's description (nominal) beside the affected plant ("true-plant")."""
    robot.check_can_track()  # the tracked-plan experiments and MPC need it (before any work)
    settings = dataset_settings(robot, plant_effects)
    output = pathlib.Path(output)
    cache = output / "cache"
    mark_output_folder(output)
    cache.mkdir(parents=True, exist_ok=True)
    timings = {}
    tick = time.perf_counter()
    excitation = ensure_dataset("excitation", profile.excitation_count, seed, output / "data", progress,
                                **settings["excitation"])
    local = ensure_dataset("excitation", profile.excitation_count, seed, output / "data", progress,
                           name="excitation_local", **settings["local"])
    tracking = ensure_dataset("tracking", profile.tracking_count, seed, output / "data", progress,
                              **settings["tracking"])
    # the MPC models' data: the same kind of plans, tracked with dithered PID, recorded by an ideal sensor
    identification = ensure_dataset("tracking", profile.identification_count, seed, output / "data", progress,
                                    name="identification", **settings["identification"])
    timings["data"] = time.perf_counter() - tick

    tick = time.perf_counter()
    jobs = plan_jobs(profile, excitation, local, tracking, identification)
    if robot.config_path is not None:   # the toolbox's own default model beside the paper's black box
        jobs += default_model_jobs(profile, excitation, str(robot.config_path))
    results = run_jobs(jobs, cache, workers, progress, runner=runner)
    timings["training"] = time.perf_counter() - tick

    tick = time.perf_counter()
    study_config = sine_sum.QUICK if profile.sine_sum == "quick" else sine_sum.FULL
    sine = reused_sine_sum(output / "sine_sum" / "results.json", study_config)
    if sine is None:
        sine = sine_sum.run_study(study_config, workers=workers, progress=progress, runner=runner)
        sine_sum.write_reports(sine, output / "sine_sum", quick=profile.sine_sum == "quick")
    sine["profile"] = profile.sine_sum
    timings["sine_sum"] = time.perf_counter() - tick

    tick = time.perf_counter()
    mpc_rows = run_mpc(profile, identification, results, cache, output / "mpc", progress, workers, robot=robot,
                       plant_effects=plant_effects)
    timings["mpc"] = time.perf_counter() - tick
    path = write_report(output, profile, excitation, local, tracking, identification, results, sine, mpc_rows,
                        timings, robot=robot, identification_controller=settings["identification"]["controller"])
    return path, mpc_rows["failures"]


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


def run_mpc(profile, identification, results, cache, folder, progress, workers: int = 2, *,
            robot: Robot, plant_effects=None) -> dict:
    """MPC with the plant and every seed of the control experiment's D, DD, PE, PED models on held-out
    plans of the identification dataset, the models split over `workers` processes, on the plant with
    `plant_effects` (then "plant" is the nominal model and "true-plant" the affected one); returns
    {"runs": per model instance, "types": mpc_statistics, "failures": one line per failed closed loop}."""
    oracle = plant_effects is not None and not plant_effects.beyond_rigid_bodies()   # (no rigid-body model holds those)
    specs = [("plant", None)] + ([("true-plant", "true")] if oracle else [])
    for model_type in CONTROL_MODEL_TYPES:
        for match in sorted(select_rows(results, experiment="control", model_type=model_type), key=lambda r: r.seed):
            specs.append((f"{model_type} seed {match.seed}", str(cache / f"{match.key}.pt")))
    learned = [spec for spec in specs if spec[1] not in (None, "true")]
    checkpoints = [LearnedModel(path, robot=robot).checkpoint for _, path in learned]
    references = held_out_references(identification, checkpoints, profile.mpc_plans)
    if profile.mpc_steps is not None:
        references = [(i, Reference(q=r.q[:profile.mpc_steps + 1], v=r.v[:profile.mpc_steps + 1])) for i, r in references]
    # the plant-as-model MPC costs about as much as all learned models together: it gets a worker of its own
    plants = [spec for spec in specs if spec not in learned]
    groups = [plants, learned] if workers > 1 else [specs]
    plant_config = identification.metadata.plant_config(effects=False)   # the data's plant, as they were simulated
    plant_config.effects = plant_effects
    jobs = [MpcGroup(group, references, identification.sample_period, progress and index == len(groups) - 1, robot,
                     plant_config) for index, group in enumerate(groups)]
    with job_pool(RunnerConfig(workers=len(jobs))) as pool:
        runs = [run for group_runs in pool.map(_mpc_group, jobs) for run in group_runs]
    plot_results(runs, identification.sample_period, folder / "mpc.png")
    return dict(runs=summarize(runs, identification.sample_period), types=mpc_statistics(runs),
                failures=closed_loop_failures(runs))


@dataclasses.dataclass(frozen=True)
class MpcGroup:
    """Closed-loop runs for one worker: the models in `specs` ((name, checkpoint path, None for the nominal
    plant, "true" for the affected plant itself)) on every reference, at `sample_period` s, for `robot`, on
    the plant of `plant_config`; `progress`: show its bar."""
    specs: list
    references: list
    sample_period: float
    progress: bool
    robot: Robot
    plant_config: PlantConfig


def _mpc_group(group: MpcGroup) -> list:
    """The ClosedLoopResults of one MpcGroup."""
    import torch
    torch.set_num_threads(1)
    robot = group.robot
    models = spec_models(group.specs, group.sample_period, group.plant_config, robot=robot)
    return compare_controllers(models, group.references, mpc_config_for(robot), group.plant_config,
                               progress=group.progress, robot=robot)
