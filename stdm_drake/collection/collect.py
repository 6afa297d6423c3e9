"""Collect a robot's datasets in Drake under the paper's two data protocols (`stdm-drake collect` is
`stdm_drake.commands.collect`).

- excitation (paper V.A.2, eq. 10; `stdm_drake.collection.excitation`): per-joint random sine torques
  A sin(f t + phi) + B added to gravity compensation; the action recorded is the total torque applied.
- tracking (paper V.B.1): task-space plans from `stdm_drake.collection.plan`, tracked by a joint-space
  controller (`stdm_drake.robots.control`, in the station `stdm_drake.robots.station`) on measured
  (noisy, filtered) states; the plan's q̇_d, q̈_d are recorded as the "real robot" derivative targets.

Every trajectory is simulated sample by sample: at t_k the controller sees the measurement y_k,
returns a_k, and a_k is held while the discrete plant integrates to t_k+1 at its own step, so
x_k+1 is exactly a function of (x_k, a_k). Trajectory i draws its randomness from
numpy.random.default_rng([seed, i]), so a dataset does not depend on how many worker processes
collected it.

The requests of both protocols, the jobs the pool runs and the dataset metadata that records their
settings live together because they change together (a setting not recorded here would make
`reproduce` reuse a dataset collected differently).
"""

import dataclasses
import os
import sys

import numpy as np

from stdm_drake.cluster import RunnerConfig, check_workers, job_pool
from stdm_drake.collection.excitation import Excitation, excitation_trajectory
from stdm_drake.collection.plan import Tracking, derived_tracking_spec, sample_task_plans
from stdm_drake.collection.protocols import PROTOCOLS, load_excitation, load_tracking_spec, protocol_named_in
from stdm_drake.config import load_yaml_config
from stdm_drake.data.dataset import Trajectory
from stdm_drake.data.writer import package_versions
from stdm_drake.errors import InputError, PlanningError, check_seed, warn
from stdm_drake import files
from stdm_drake.paths import CONTROLLERS_DIR
from stdm_drake.robots.control import JointSensor, SensorConfig, friction_bound_joints, load_controller_config
from stdm_drake.robots.plant import DEFAULT_PLANT_TIME_STEP, PlantConfig, SelfCollisionChecker
from stdm_drake.robots.plant_effects_check import plant_effects_for
from stdm_drake.robots.robot import Robot, load_robot
from stdm_drake.robots.station import DEFAULT_SAMPLE_PERIOD, Station, StationConfig, loop_settings
from stdm_drake.robots.kinematics import RobotKinematics

DEFAULT_CONTROLLER = CONTROLLERS_DIR / "inverse_dynamics.yaml"
DEFAULT_SENSOR = CONTROLLERS_DIR / "sensor.yaml"
PAPER_COUNTS = {"excitation": 200, "tracking": 100}
MAX_COUNT = 100_000   # trajectories per collection: more is a run of days (and its arrays do not fit in memory)
# plant steps per collection: MAX_COUNT trajectories of the default 1 s at the default 1 ms plant step, a few hours
# on 2 cores (about 15x real time per core); a finer plant step or longer trajectories must come with fewer of them
MAX_PLANT_STEPS = 100_000_000


@dataclasses.dataclass
class PlanSamples:
    """A plan sampled at the data rate: q (T+1, n) rad, qd (T+1, n) rad/s, qdd (T+1, n) rad/s^2."""
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray


def tracking_trajectory(rig: Station, plan: PlanSamples, rng: np.random.Generator) -> dict:
    """Track one planned trajectory from rest at its start with the configured controller."""
    controller = rig.controller
    controller.reset()

    dither = controller.dither_std

    def control(k, t, q, v):
        torque = controller.torque(q, v, plan.q[k], plan.qd[k], plan.qdd[k])
        return torque + dither * rng.standard_normal(len(dither)) if dither.any() else torque

    traj = rig.run(plan.q[0], len(plan.q) - 1, control, JointSensor(rig.settings.sensor, rng), rng)
    reason = rig.limit_violation(traj, 0.0, 1.0, check_self_collision=False)
    if reason is not None:
        named = loop_settings(rig.settings)
        unholdable, cause = rig.gravity_beyond(plan.q, joint_name=reason.split()[0])   # (run 34: only gains named)
        raise PlanningError(f"tracking left the limits ({reason}); " + (cause if unholdable else (
            f"{cause}; " if cause else "") + "check the controller gains" + (" and " + ", ".join(named) if named else "")))
    traj.update(q_planned=plan.q, v_planned=plan.qd, qdd_planned=plan.qdd)
    return traj


# A tracked joint is far from its plan when its angle's mean squared error over the dataset exceeds this (rad²:
# 0.57 degrees RMS; the shipped arms track at 1e-7 to 1e-6, the chattering damped joints of issue 42 at 5e-4 to
# 2e-3). Acceleration spikes alone are no sign: under a held torque a light joint with strong damping (the UR-10's
# wrist_3 with 10 N m s/rad) jumps to 400 rad/s² at each torque step and settles within 0.2 ms, tracking its plan
# at 1e-7 rad². Dithered data leave the plan by design and are not checked.
TRACKING_MSE_WARNING = 1e-4


def tracking_mse(trajectories: list) -> np.ndarray:
    """Per joint (n,), rad²: the mean squared error of the true angle q_true from the plan q_planned ((T, n)
    each) over every step of tracked `trajectories`."""
    error = np.concatenate([traj.q_true - traj.q_planned for traj in trajectories])
    return np.mean(error**2, axis=0)


def tracking_warning(trajectories: list, joint_names, settings=()) -> str | None:
    """One warning line naming the joints whose `tracking_mse` exceeds TRACKING_MSE_WARNING over tracked
    `trajectories`, or None (settings: `loop_settings`' phrases, named beside the gains). Exit 0 does not mean usable
    data: this says when it is not."""
    mse = tracking_mse(trajectories)
    far = [f"{name} ({value:.2g} rad²)" for name, value in zip(joint_names, mse) if value > TRACKING_MSE_WARNING]
    if not far:
        return None
    return (f"stdm-drake: warning: the tracked data are far from the plans on {len(far)} joint(s), angle MSE "
            f"{'; '.join(far)} against {TRACKING_MSE_WARNING:g} rad²; the controller does not follow this plant "
            f"(gains{''.join(', ' + phrase for phrase in settings)}, effort limits, or damping and friction it does not "
            "know): see docs/guides/robots.md, 'Tracking quality'")


# ---- worker processes -------------------------------------------------------------------------

_WORKER_RIG: Station | None = None


def init_station_worker(settings: StationConfig) -> None:
    """Set up a collection worker process: its own Station of `settings`, used by the jobs it runs."""
    global _WORKER_RIG
    _WORKER_RIG = Station(settings)


@dataclasses.dataclass(frozen=True)
class TrajectoryJob:
    """One trajectory for a collection worker: trajectory `index` of the dataset of `seed` under
    `protocol`, with its payload (the Excitation, or the PlanSamples to track)."""
    protocol: str
    index: int
    seed: int
    payload: Excitation | PlanSamples


def _collect_one(job: TrajectoryJob) -> dict:
    rng = np.random.default_rng([job.seed, job.index])
    if job.protocol == "excitation":
        return excitation_trajectory(_WORKER_RIG, job.payload, rng)
    return tracking_trajectory(_WORKER_RIG, job.payload, rng)


@dataclasses.dataclass
class CollectionRequest:
    """One dataset to collect: its protocol's settings are `excitation` or `tracking_spec`."""
    protocol: str
    count: int
    seed: int
    settings: StationConfig
    excitation: Excitation | None = None
    tracking_spec: Tracking | None = None
    workers: int | None = 1   # None: `default_workers` of the job's plant steps


@dataclasses.dataclass(frozen=True)
class PoseJob:
    """The plans of one initial pose for a collection worker: `count` plans from pose `pose_index` of
    `spec`, sampled at `sample_period` s, for the dataset of `seed`."""
    spec: Tracking
    pose_index: int
    count: int
    seed: int
    sample_period: float


def _plan_pose(job: PoseJob) -> list[PlanSamples]:
    """Plan `job.count` trajectories from one initial pose, with that pose's own random stream.

    Pose p draws from numpy.random.default_rng([seed, 2**31, p]); plan k of a pose does not
    depend on how many plans are requested after it.
    """

    sampling, pose_index = job.spec.sampling, job.pose_index
    one_pose = dataclasses.replace(sampling, initial_poses=[sampling.initial_poses[pose_index]],
                                   num_final_per_initial=job.count)
    rng = np.random.default_rng([job.seed, 2**31, pose_index])
    kinematics = RobotKinematics(_WORKER_RIG.dynamics.plant, robot=_WORKER_RIG.robot)
    sampled = sample_task_plans(kinematics, one_pose, job.spec.planner, job.sample_period, rng,
                                is_collision_free=_WORKER_RIG.collision_checker.is_collision_free,
                                first_index=pose_index)
    return [PlanSamples(q=plan.q, qd=plan.qd, qdd=plan.qdd) for _, plan in sampled]


def plan_tracking(request: "CollectionRequest", pool) -> tuple[list[PlanSamples], list[int]]:
    """Plans for `request.count` tracking trajectories, spread evenly over the initial poses,
    ordered by pose: returns (plans, groups). pool: a `cluster.job_pool` whose workers hold a Station."""
    sampling = request.tracking_spec.sampling
    if request.count > len(sampling.initial_poses) * sampling.num_final_per_initial:
        raise InputError(f"tracking spec yields {len(sampling.initial_poses)} poses x "
                         f"{sampling.num_final_per_initial} final poses, {request.count} requested")
    counts = plans_per_pose(request.count, len(sampling.initial_poses))
    jobs = [PoseJob(request.tracking_spec, pose, n, request.seed, request.settings.sample_period)
            for pose, n in enumerate(counts) if n]
    plans, groups = [], []
    for job, pose_plans in zip(jobs, pool.map(_plan_pose, jobs)):
        plans += pose_plans
        groups += [job.pose_index] * len(pose_plans)
    return plans, groups


def plans_per_pose(count: int, num_poses: int) -> list[int]:
    """How many trajectories each initial pose gets: as even as possible, earlier poses first."""
    return [count // num_poses + (1 if pose < count % num_poses else 0) for pose in range(num_poses)]


# Arrays of n columns a collected trajectory holds per sample, at most (the state and its truth, torques,
# accelerations, the plan): what a dataset's size is estimated from before the simulation starts.
ARRAYS_PER_SAMPLE = 12


def payload_samples(payload) -> int:
    """The samples of the trajectory a payload plans: an Excitation's num_steps + 1, a PlanSamples' T + 1."""
    return payload.num_steps + 1 if isinstance(payload, Excitation) else len(payload.q)


def estimated_dataset_bytes(payloads, num_joints: int) -> int:
    """Bytes that trajectories of `payloads` (an Excitation or a PlanSamples each: `payload_samples`) take in memory
    and in the dataset file, at most."""
    return sum(map(payload_samples, payloads)) * num_joints * 8 * ARRAYS_PER_SAMPLE


# Two worker processes from this many plant steps of simulation (sample periods x plant steps per period) on: below
# it the second process's start-up (imports, its Station) outweighs the work it takes over (`tools/
# bench_collect_workers.py`, BENCHMARKS.md: 16 tracked plans, 16,000 plant steps, faster with 1 worker; 50
# excitation trajectories, 25,000 steps, about even; 48 plans and more faster with 2).
DEFAULT_WORKERS_PLANT_STEPS = 25_000


def default_workers(plant_steps: int) -> int:
    """`collect`'s worker processes where none are asked for: min(2, cores) for a job of at least
    DEFAULT_WORKERS_PLANT_STEPS plant steps, else 1."""
    return min(2, os.cpu_count() or 1) if plant_steps >= DEFAULT_WORKERS_PLANT_STEPS else 1


def check_plant_steps(count: int, periods: int, settings) -> None:
    """InputError (one line, with the estimate) where simulating `count` trajectories of `periods` sample periods in
    all takes more than MAX_PLANT_STEPS plant steps (sample periods x the plant steps per sample period): checked
    from the protocol's settings before anything is planned, and again from the plans."""
    substeps = settings.substeps()
    steps = periods * substeps
    if steps > MAX_PLANT_STEPS:
        raise InputError(f"{count} trajectories of {periods / count:.0f} samples, {substeps} "
                         f"plant steps each, would take {steps:.3g} plant steps, more than {MAX_PLANT_STEPS:.0e} (hours "
                         "of simulation); collect fewer (--count) or shorter ones, or at a coarser --plant-time-step")


def collect(request: CollectionRequest, progress: bool = True, on_trajectory=None,
            check_size=None) -> tuple[list[Trajectory], list[int], dict]:
    """Simulate `request.count` trajectories; returns (trajectories, groups, metadata).

    on_trajectory(traj): called with each finished trajectory, in order (e.g. to show it in Meshcat).
    check_size(bytes): called with `estimated_dataset_bytes` once the trajectories are planned, before any is
    simulated (to refuse a dataset that would not fit in memory or on disk).
    """
    from tqdm import tqdm

    if request.protocol not in PROTOCOLS:
        raise InputError(f"protocol must be one of {PROTOCOLS}, got {request.protocol!r}")
    if request.count < 1:
        raise InputError(f"count must be >= 1, got {request.count}")
    settings = request.settings
    settings.substeps()
    settings.sensor.validate()
    if request.protocol == "tracking":   # (excitation has no tracking controller)
        settings.controller.validate()
        check_plant_steps(request.count, request.count * request.tracking_spec.sampling.num_steps, settings)
    bar = None   # (started once every plan is found and the sizes checked: a refusal before it is its one line)
    trajectories, excitation_parameters = [], []

    def finished(arrays: dict) -> None:
        if "excitation" in arrays:   # eq. (10)'s draw: recorded in the metadata, not as an array
            excitation_parameters.append(arrays.pop("excitation").tolist())
        traj = Trajectory(**arrays)
        trajectories.append(traj)
        if on_trajectory is not None:
            on_trajectory(traj)
        bar.update()

    workers = request.workers
    if workers is None:
        samples = (request.tracking_spec.sampling.num_steps if request.protocol == "tracking"
                   else request.excitation.num_steps)
        workers = default_workers(request.count * samples * settings.substeps())
    workers = max(1, min(workers, request.count))
    # in this process (1 worker) or in `workers` spawned processes that each build their own Station
    with job_pool(RunnerConfig(workers=workers), initializer=init_station_worker, initargs=(settings,)) as pool:
        if request.protocol == "excitation":
            request.excitation.validate()
            payloads, groups = [request.excitation] * request.count, [0] * request.count
        else:
            payloads, groups = plan_tracking(request, pool)
        check_plant_steps(len(payloads), sum(payload_samples(payload) - 1 for payload in payloads), settings)
        size = estimated_dataset_bytes(payloads, settings.robot.num_joints)
        available = files.available_memory()
        if available is not None and size > available:
            raise InputError(f"{request.count} trajectories would take about {files.size_text(size)} of memory, "
                             f"{files.size_text(available)} is available; collect fewer (--count) or shorter ones")
        if check_size is not None:
            check_size(size)
        bar = tqdm(total=request.count, desc=f"collect {request.protocol}", unit="traj", disable=not progress,
                   file=sys.stderr)
        jobs = [TrajectoryJob(request.protocol, i, request.seed, payload) for i, payload in enumerate(payloads)]
        for traj in pool.map(_collect_one, jobs, chunksize=max(1, len(jobs) // (4 * workers))):
            finished(traj)
        bar.close()
    metadata = collection_metadata(request)
    if request.protocol == "excitation":
        metadata["excitation_parameters"] = excitation_parameters
    return trajectories, groups, metadata


def collection_metadata(request: CollectionRequest) -> dict:
    """What a dataset file records about how it was collected (JSON-ready; per-trajectory excitation
    parameters are added by `collect`)."""
    settings = request.settings
    metadata = dict(
        protocol=request.protocol, sample_period=settings.sample_period, seed=request.seed,
        num_trajectories=request.count, robot_model_sha256=settings.robot.model_sha256(),
        joint_names=list(settings.robot.joint_names), robot=dataclasses.asdict(settings.robot.config),
        robot_inertia_substitutions=dict(settings.robot.inertia_substitutions),   # (link: what Drake simulates)
        plant=settings.plant.record(), sensor=dataclasses.asdict(settings.sensor), package_versions=package_versions(),
        torque_hold="zero-order hold over each sample period; plant integrates at plant.time_step")
    if request.protocol == "excitation":
        metadata["excitation"] = dataclasses.asdict(request.excitation)
        m = settings.robot.action_dim
        metadata["excitation_parameters_columns"] = (f"amplitude ({m}) N m, frequency ({m}) rad/s, offset ({m}) N m, "
                                                     f"phase ({m}) rad")
    else:
        metadata["controller"] = settings.controller.record()
        metadata["planner"] = request.tracking_spec.planner.record()
        metadata["task_space_sampling"] = dataclasses.asdict(request.tracking_spec.sampling)
    return metadata


# ---- requests ----------------------------------------------------------------------------------


def collection_request(protocol: str | None = None, *, count: int | None = None, seed: int = 0, config=None,
                       controller=None, sensor=None, sample_period: float = DEFAULT_SAMPLE_PERIOD,
                       plant_time_step: float = DEFAULT_PLANT_TIME_STEP, robot,
                       workers: int | None = None,
                       excitation: Excitation | None = None, plant_effects=None) -> CollectionRequest:
    """What `stdm-drake collect` does with these settings (its options as keywords; config, controller,
    sensor: YAML paths, None for the defaults (a controller only with the tracking protocol: the
    excitation protocol applies its torques directly); robot: a Robot or its config's path; excitation: an
    Excitation to use instead of a file; plant_effects: a PlantEffects or its YAML path, None for the
    robot's description as it is). protocol: "excitation" or "tracking"; None: the one the
    config file's tag names, else tracking. Reads every config file and checks it against the robot, so
    errors come before any simulation starts."""
    if protocol is None:
        protocol = (protocol_named_in(config) if config is not None else None) or "tracking"
    if protocol not in PROTOCOLS:
        raise InputError(f"protocol must be one of {PROTOCOLS}, got {protocol!r}")
    if controller is not None and protocol == "excitation":
        raise InputError(f"--controller {controller}: the excitation protocol applies its torques directly, without a "
                         "controller; give --controller with --protocol tracking")
    controller = controller or DEFAULT_CONTROLLER
    sensor_config = SensorConfig()
    sensor_path = sensor or (DEFAULT_SENSOR if protocol == "tracking" else None)
    if sensor_path is not None:
        sensor_config = load_yaml_config(sensor_path, SensorConfig, what="sensor config")
    robot = robot if isinstance(robot, Robot) else load_robot(robot)
    SelfCollisionChecker(robot)  # a model that does not load, or a home in self-collision, fails before any worker
    # the protocol file: --config, else the one the robot's config names, else derived from the robot
    config_path = config or robot.default_file(protocol)
    effects = plant_effects_for(plant_effects, robot, plant_time_step, sample_period)
    settings = StationConfig(sample_period=sample_period, plant=PlantConfig.discrete(plant_time_step, effects=effects),
                             sensor=sensor_config, controller=load_controller_config(controller), robot=robot)
    settings.substeps()  # the sample period and the plant step, before any work
    if protocol == "tracking":
        robot.check_can_track()
        sized = bool(settings.controller.sizing())   # gains from the plant's inertia (then filled in)
        try:  # per-joint lists of the robot's length, or one value for all
            settings.controller = settings.controller.for_robot(robot, effects)
        except InputError as error:
            raise InputError(f"{controller}: {error}") from None
        stuck = friction_bound_joints(settings.controller, robot, effects)
        if stuck:
            warn(f"stdm-drake: warning: the tracking controller of {controller} barely moves {len(stuck)} joint(s) "
                 f"of the affected plant ({'; '.join(stuck)})" + ("" if sized else
                 "; a controller sized by bandwidth (controllers/pid_dither_sized.yaml) takes its gains from the "
                 "affected plant's inertia"))
    if count is not None and not 1 <= count <= MAX_COUNT:
        raise InputError(f"--count must be in 1..{MAX_COUNT}, got {count}")
    if workers is not None:
        check_workers(workers)
    check_seed("--seed", seed)
    request = CollectionRequest(protocol=protocol, count=PAPER_COUNTS[protocol] if count is None else count, seed=seed,
                                settings=settings, workers=workers)
    if protocol == "excitation":
        if excitation is not None:
            request.excitation = excitation.for_robot(robot)
        elif config_path is None:
            request.excitation = Excitation.derived_for(robot)
        else:
            request.excitation = load_excitation(config_path, robot=robot)
        try:
            request.excitation.check_sampled(sample_period)
        except InputError as error:
            raise InputError(f"{config_path}: {error}" if config_path is not None else str(error)) from None
        return request
    else:
        if config_path is None:
            request.tracking_spec = derived_tracking_spec(robot, sample_period=sample_period)
        else:
            request.tracking_spec = load_tracking_spec(config_path, robot=robot)
    return request
