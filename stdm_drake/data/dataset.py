"""Dataset files: one self-describing HDF5 file per dataset, one group per trajectory.

Layout (format "stdm-drake-dataset", version 2; version 1 files, simulation only, still load):

    /                      attrs: format, format_version, protocol, sample_period (s),
                                  num_trajectories, metadata_json (everything else, see below)
    /trajectories/000000   attrs: group (int; initial-pose index, 0 for excitation and logs)
        q        (T+1, n) rad     joint angles as the learner sees them (measured: noise + filter)
        v        (T+1, n) rad/s   joint velocities as the learner sees them
        tau      (T, m)   N m     action: torques of the m actuated joints over [t_k, t_k+1)
                                  (zero-order hold); m = n unless the robot is underactuated
        tau_next (m,)     N m     action at t_T (the controller's next, not applied; in a log the next
                                  logged torque, or the last one repeated at the log's end): closes the
                                  forward difference of the action rate at the last step
      simulated data (protocols "excitation", "tracking") only:
        q_true, v_true (T+1, n)   the plant's true state at the sample instants
        qdd      (T+1, n) rad/s^2 true acceleration just after t_k (under the torque from t_k on)
        qdd_end  (T, n)   rad/s^2 true acceleration just before t_k+1 (under tau_k)
      the plan: "tracking" always, "logged" when the log has it (all three or none):
        q_planned, v_planned, qdd_planned (T+1, n)
      logged data (protocol "logged", a real robot's log through `stdm-drake import`) only:
        v_smoothed, qdd_smoothed (T+1, n)   Savitzky-Golay derivatives of the measured angles
        qdd_measured (T+1, n)               the same differentiator of the measured velocities

n is the robot's arm-joint count (the UR-10: 6), recorded with the joint names and the robot's config.
metadata_json holds the robot model hash, plant time step, protocol settings (planner,
controller gains, excitation ranges, noise and filter; for logs the import's choices and counts), seed and
package versions. Files are written atomically and deterministically (same content -> same bytes), one
trajectory at a time (`data.writer.DatasetWriter`).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import pathlib

import h5py
import numpy as np

from stdm_drake.data.schema import PROTOCOLS, SIMULATED_PROTOCOLS, attribute_number, check_record, check_trajectory
from stdm_drake.errors import InputError, check_seed
from stdm_drake.outputs import DATASET_FORMAT
from stdm_drake.paths import check_input_file
from stdm_drake.robots.effects import PlantEffects
from stdm_drake.robots.plant import PlantConfig

FORMAT = DATASET_FORMAT
FORMAT_VERSION = 2
READABLE_VERSIONS = (1, 2)
# (the protocols and the arrays each one's trajectories hold: data.schema)
# where the derivative targets (q̇, q̈) come from: the simulation's truth, the tracked plan, a log's measured
# velocities (and their smoothed derivative) or the smoothed measured angles
DERIVATIVE_SOURCES = ("true", "planned", "measured", "smoothed")
ACTION_RATE_SCHEMES = ("forward_difference", "zero_order_hold")


@dataclasses.dataclass(frozen=True, eq=False)
class Trajectory:
    """One trajectory's arrays (float64; names, shapes and units in the module docstring): T steps, n
    joints, m actuated ones. An array its protocol does not hold is None (the simulation's truth in a log,
    the plan in excitation data, the log's derivatives in simulated data)."""
    q: np.ndarray
    v: np.ndarray
    tau: np.ndarray
    tau_next: np.ndarray
    q_true: np.ndarray | None = None
    v_true: np.ndarray | None = None
    qdd: np.ndarray | None = None
    qdd_end: np.ndarray | None = None
    q_planned: np.ndarray | None = None
    v_planned: np.ndarray | None = None
    qdd_planned: np.ndarray | None = None
    v_smoothed: np.ndarray | None = None
    qdd_smoothed: np.ndarray | None = None
    qdd_measured: np.ndarray | None = None

    @classmethod
    def from_arrays(cls, name: str, arrays: dict, protocol: str, sample_period: float | None = None) -> "Trajectory":
        """The trajectory of a mapping name -> array, checked (`check_trajectory`: every array of the
        protocol present, no other, shapes, finite numbers, plausible magnitudes, and steps at the file's
        `sample_period` (s) when given); InputError naming trajectory `name`."""
        check_trajectory(name, arrays, protocol, sample_period)
        return cls(**{key: np.asarray(value, dtype=np.float64) for key, value in arrays.items()})

    def arrays(self) -> dict:
        """Name -> array of the arrays it holds."""
        return {field.name: getattr(self, field.name) for field in dataclasses.fields(self)
                if getattr(self, field.name) is not None}

    @property
    def has_plan(self) -> bool:
        return self.q_planned is not None

    @property
    def is_simulated(self) -> bool:
        """Whether it holds the simulation's true state (q_true, v_true, qdd, qdd_end)."""
        return self.q_true is not None

    @property
    def num_steps(self) -> int:
        """T: the transitions it holds (len(tau))."""
        return len(self.tau)


@dataclasses.dataclass
class Transitions:
    """One-step training pairs, stacked over trajectories (N = sum of T over trajectories).

    state (N, 2n) [q rad, v rad/s] at t_k; action (N, m) N m over [t_k, t_k+1);
    next_state (N, 2n) at t_k+1; state_rate (N, 2n) = [q̇, q̈] at t_k (tangent of the chain rule);
    action_rate (N, m) N m/s; next_state_rate (N, 2n) = [q̇, q̈] at t_k+1 (derivative target);
    trajectory (N,) int index into the dataset; step (N,) int k.
    """
    state: np.ndarray
    action: np.ndarray
    next_state: np.ndarray
    state_rate: np.ndarray
    action_rate: np.ndarray
    next_state_rate: np.ndarray
    trajectory: np.ndarray
    step: np.ndarray
    sample_period: float

    def __len__(self) -> int:
        return len(self.state)


@dataclasses.dataclass
class Split:
    """Trajectory indices of a train / validation / test split."""
    train: np.ndarray
    val: np.ndarray
    test: np.ndarray

    def as_dict(self) -> dict:
        return {name: getattr(self, name).tolist() for name in ("train", "val", "test")}


@dataclasses.dataclass(frozen=True)
class DatasetMetadata:
    """What a dataset file records about how it was collected (its `metadata_json` attribute), typed where
    the library reads it: protocol ("excitation" or "tracking"), sample_period (s), seed, robot_name,
    joint_names (the n arm joints), robot_model_sha256 (of the robot's model file), plant_time_step (s),
    plant_effects (the `robots.effects.PlantEffects` of the simulated plant; None: the description as is).
    `record` is the whole JSON object as written (sections robot, plant, sensor, controller, planner,
    task_space_sampling, excitation, package_versions, ...): `section(name)` reads one. None where the
    file does not record a value."""
    protocol: str
    sample_period: float
    seed: int | None = None
    robot_name: str | None = None
    joint_names: list | None = None
    robot_model_sha256: str | None = None
    plant_time_step: float | None = None
    plant_effects: PlantEffects | None = None
    record: dict = dataclasses.field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def from_record(cls, record: dict) -> "DatasetMetadata":
        """The typed view of a record (checked by `load_dataset`: protocol and sample_period present)."""
        robot, plant = record.get("robot") or {}, record.get("plant") or {}
        names = record.get("joint_names")
        return cls(protocol=record["protocol"], sample_period=float(record["sample_period"]), seed=record.get("seed"),
                   robot_name=robot.get("name"), joint_names=list(names) if names is not None else None,
                   robot_model_sha256=record.get("robot_model_sha256"), plant_time_step=plant.get("time_step"),
                   plant_effects=PlantEffects.from_record(plant["effects"]) if plant.get("effects") else None,
                   record=record)

    def plant_config(self, *, effects: bool = True):
        """The plant these data were simulated on (`robots.plant.PlantConfig.from_record` of the record's plant
        section: the plant step, self-contact, Drake's contact settings, the effects); effects=False: the robot's
        description as it is, simulated as the data were (the nominal plant the physics baseline steps). A file
        that records no plant (an imported log): the default plant."""
        return PlantConfig.from_record(self.record.get("plant"), effects=effects)

    def section(self, name: str) -> dict:
        """One section of the record ({} when absent), e.g. "controller", "planner", "robot"."""
        value = self.record.get(name)
        return dict(value) if isinstance(value, dict) else {}


class Dataset:
    """A loaded, validated dataset: its metadata (DatasetMetadata) plus per-trajectory arrays (float64)."""

    def __init__(self, path: pathlib.Path, metadata: DatasetMetadata, trajectories: list[Trajectory], groups: np.ndarray,
                 sha256: str):
        self.path = pathlib.Path(path)
        self.metadata = metadata
        self._trajectories = trajectories
        self.groups = groups
        self.sha256 = sha256

    @property
    def protocol(self) -> str:
        return self.metadata.protocol

    @property
    def sample_period(self) -> float:
        return self.metadata.sample_period

    @property
    def num_trajectories(self) -> int:
        return len(self._trajectories)

    @property
    def has_plan(self) -> bool:
        """Whether its trajectories hold the plan they tracked (tracking data; a log with the plan)."""
        return self._trajectories[0].has_plan

    @property
    def is_simulated(self) -> bool:
        """Whether it holds the simulation's truth (not a log of a real robot)."""
        return self.protocol in SIMULATED_PROTOCOLS

    @property
    def derivative_sources(self) -> tuple:
        """The derivative sources its arrays give (see DERIVATIVE_SOURCES)."""
        if self.is_simulated:
            return ("true", "planned") if self.has_plan else ("true",)
        return (("planned",) if self.has_plan else ()) + ("measured", "smoothed")

    @property
    def default_derivative_source(self) -> str:
        """Derivative targets the protocol calls for: the plan where there is one (the paper's real-robot
        protocol), else the truth for simulation and the smoothed angles for a log."""
        return "planned" if self.has_plan else "true" if self.is_simulated else "smoothed"

    def trajectory(self, index: int) -> Trajectory:
        """Trajectory `index` (see the module docstring for its arrays' names and shapes)."""
        return self._trajectories[index]

    def transitions(self, indices=None, derivative_source: str | None = None,
                    action_rate: str = "forward_difference") -> Transitions:
        """Stack the one-step transitions of the given trajectories (all by default).

        derivative_source: "true" (the plant's q̇, q̈) or "planned" (the tracked plan's q̇_d,
        q̈_d; tracking data only); default: the protocol's own (`default_derivative_source`).
        action_rate: "forward_difference" (paper eq. 7-8: Δa_k/Δt = (a_k+1 - a_k)/Δt, with
        a_T = tau_next at the last step; targets are the accelerations just after t_k+1) or
        "zero_order_hold" (Δa/Δt = 0, targets just before t_k+1: exact for held torques, true
        source only).
        """
        source = derivative_source or self.default_derivative_source
        if source not in DERIVATIVE_SOURCES:
            raise InputError(f"derivative source must be one of {DERIVATIVE_SOURCES}, got {source!r}")
        if action_rate not in ACTION_RATE_SCHEMES:
            raise InputError(f"action rate scheme must be one of {ACTION_RATE_SCHEMES}, got {action_rate!r}")
        if source not in self.derivative_sources:
            raise InputError(f"{self.path}: derivative source {source!r} is not in this {self.protocol} dataset "
                             f"({'with' if self.has_plan else 'without'} a plan), which gives "
                             f"{', '.join(self.derivative_sources)}")
        if source != "true" and action_rate == "zero_order_hold":
            raise InputError("the zero_order_hold scheme needs true accelerations (derivative source 'true')")
        indices = np.arange(self.num_trajectories) if indices is None else np.asarray(indices, dtype=int)
        if indices.size and (indices.min() < 0 or indices.max() >= self.num_trajectories):
            raise InputError(f"trajectory index out of range 0..{self.num_trajectories - 1}")
        dt = self.sample_period
        parts = []
        for index in indices:
            traj = self._trajectories[index]
            tau_all = np.vstack([traj.tau, traj.tau_next[None]])
            qd, qdd_after = derivative_arrays(traj, source)
            if action_rate == "forward_difference":
                rate = np.diff(tau_all, axis=0) / dt
                target_qdd = qdd_after[1:]
            else:
                rate = np.zeros_like(traj.tau)
                target_qdd = traj.qdd_end
            x = np.hstack([traj.q, traj.v])
            num_steps = traj.num_steps
            parts.append(dict(
                state=x[:-1], action=traj.tau, next_state=x[1:],
                state_rate=np.hstack([qd[:-1], qdd_after[:-1]]), action_rate=rate,
                next_state_rate=np.hstack([qd[1:], target_qdd]),
                trajectory=np.full(num_steps, index), step=np.arange(num_steps)))
        if not parts:
            raise InputError("no trajectories selected")
        stacked = {key: np.concatenate([part[key] for part in parts]) for key in parts[0]}
        return Transitions(sample_period=dt, **stacked)


def derivative_arrays(traj: Trajectory, source: str) -> tuple:
    """(q̇, q̈) of `traj` (each (T+1, n)) from derivative `source` (DERIVATIVE_SOURCES)."""
    return {"true": (traj.v_true, traj.qdd), "planned": (traj.v_planned, traj.qdd_planned),
            "measured": (traj.v, traj.qdd_measured), "smoothed": (traj.v_smoothed, traj.qdd_smoothed)}[source]


def split_trajectories(groups, n_train: int, n_val: int, n_test: int | None, seed: int,
                       per_group: bool) -> Split:
    """Split trajectory indices into train / validation / test, disjoint and reproducible.

    per_group=True: n_* count trajectories *per group* (e.g. per initial pose, as in the paper's
    real-robot protocol: 1/3/5 train, 5 validation, 15 test per pose). The validation and test
    sets do not depend on n_train, so training sets of several sizes share them.
    n_test=None: all remaining trajectories.
    """
    groups = np.asarray(groups, dtype=int)
    rng = np.random.default_rng(seed)
    buckets = [np.flatnonzero(groups == g) for g in np.unique(groups)] if per_group else [np.arange(len(groups))]
    train, val, test = [], [], []
    for bucket in buckets:
        order = rng.permutation(bucket)
        need = n_train + n_val + (n_test or 0)
        if need > len(order):
            where = f"group {groups[bucket[0]]}" if per_group else "the dataset"
            unit = " per group (--per-group on)" if per_group else ""
            raise InputError(f"split needs {need} trajectories from {where} ({n_train} train + {n_val} validation + "
                             f"{n_test or 0} test{unit}: --train/--val/--test), which has {len(order)}")
        val.append(order[:n_val])
        rest = order[n_val:]
        test_count = len(rest) - n_train if n_test is None else n_test
        test.append(rest[len(rest) - test_count:])
        train.append(rest[:n_train])
    return Split(*(np.sort(np.concatenate(part)).astype(int) for part in (train, val, test)))


def check_split_options(train: int | None, val: int | None, test: int | None, split_seed: int,
                        key=lambda name: f"--{name.replace('_', '-')}") -> None:
    """InputError (one line, before any work) unless the split's given sizes are counts (training and validation at
    least 1, test at least 0; None: the default) and its seed a seed; key: an option's name as the message gives it."""
    for name, value, least in (("train", train, 1), ("val", val, 1), ("test", test, 0)):
        if value is not None and value < least:
            raise InputError(f"{key(name)} must be >= {least}, got {value}")
    check_seed(key("split_seed"), split_seed)


SPLIT_ADVICE = "collect more, or give --train, --val and --test"


def default_split_sizes(pool: int, n_train: int | None, n_val: int | None, n_test: int | None,
                        advice: str = SPLIT_ADVICE):
    """Fill unset split sizes from `pool` trajectories (per group with --per-group): 20 % validation, 20 % test,
    the rest training; n_test None: "all the rest". advice: what a pool too small is told (the command's options)."""
    n_val = n_val if n_val is not None else max(1, round(0.2 * pool))
    if n_train is None:
        n_train = pool - n_val - (n_test if n_test is not None else max(1, round(0.2 * pool)))
    if n_train < 1:
        raise InputError(f"{pool} trajector{'y' if pool == 1 else 'ies'} per split unit leave{'s' if pool == 1 else ''} no "
                         f"training trajectory after {n_val} for validation and {pool - n_val - n_train} for test; "
                         + advice)
    return n_train, n_val, n_test


def dataset_split(dataset, settings, advice: str = SPLIT_ADVICE) -> tuple[Split, bool]:
    """(Split, per_group) of `dataset` by `settings` (its train, val, test, split_seed and per_group "on", "off"
    or None: a training's or an identification's): per initial-pose group by default on tracking data, the
    sizes `default_split_sizes` fills in, the split seed's shuffle."""
    per_group = (dataset.protocol == "tracking") if settings.per_group is None else settings.per_group == "on"
    pool = int(np.unique(dataset.groups, return_counts=True)[1].min()) if per_group else dataset.num_trajectories
    n_train, n_val, n_test = default_split_sizes(pool, settings.train, settings.val, settings.test, advice)
    return split_trajectories(dataset.groups, n_train, n_val, n_test, settings.split_seed, per_group), per_group


def file_sha256(path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def check_protocol_attribute(attribute, protocol: str, path) -> None:
    """InputError when the file's root `protocol` attribute (a string, or None when absent) names another
    protocol than its metadata's `protocol` (a hand-edited file: which one holds?)."""
    if attribute is None:
        return
    text = attribute.decode() if isinstance(attribute, bytes) else attribute
    if not isinstance(text, str) or text != protocol:
        raise InputError(f"{path}: protocol attribute {text!r} contradicts the metadata's protocol {protocol!r}")


def load_dataset(path) -> Dataset:
    """Read and validate a dataset file; any problem raises InputError with one clear line."""
    path = check_input_file(path, "dataset", missing=FileNotFoundError)
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != FORMAT:
                raise InputError(f"{path}: not a stdm-drake dataset (format attribute missing or wrong)")
            version = attribute_number(f.attrs.get("format_version", -1), f"{path}: format_version", int)
            if version not in READABLE_VERSIONS:
                raise InputError(f"{path}: dataset format version {version}, this stdm-drake reads versions "
                                 f"{', '.join(map(str, READABLE_VERSIONS))}")
            try:
                metadata = json.loads(f.attrs["metadata_json"])
            except (KeyError, TypeError, json.JSONDecodeError) as error:
                raise InputError(f"{path}: metadata unreadable ({error})") from None
            check_record(metadata, path)
            if metadata["protocol"] not in (PROTOCOLS if version >= 2 else SIMULATED_PROTOCOLS):
                raise InputError(f"{path}: unknown protocol {metadata['protocol']!r} (format version {version})")
            check_protocol_attribute(f.attrs.get("protocol"), metadata["protocol"], path)
            period = attribute_number(f.attrs.get("sample_period", np.nan), f"{path}: sample_period attribute")
            if not (period > 0 and period == float(metadata["sample_period"])):
                raise InputError(f"{path}: sample period {period} missing, non-positive or inconsistent with metadata")
            if not isinstance(f.get("trajectories"), h5py.Group):
                raise InputError(f"{path}: no trajectories group")
            names = sorted(f["trajectories"])
            declared = attribute_number(f.attrs.get("num_trajectories", -1), f"{path}: num_trajectories", int)
            if declared != len(names) or not names:
                raise InputError(f"{path}: header declares {declared} trajectories, file holds {len(names)}")
            trajectories, groups = [], []
            for name in names:
                group = f["trajectories"][name]
                if not isinstance(group, h5py.Group):
                    raise InputError(f"{path}: trajectory {name} is not a group of arrays")
                inner = [key for key in group if not isinstance(group[key], h5py.Dataset)]
                if inner:
                    raise InputError(f"{path}: trajectory {name} holds {inner[0]!r}, which is not an array")
                trajectories.append(Trajectory.from_arrays(name, {key: group[key][()] for key in group},
                                                           metadata["protocol"], period))
                groups.append(attribute_number(group.attrs.get("group", 0), f"{path}: trajectory {name}'s group", int))
            if len({trajectory.has_plan for trajectory in trajectories}) > 1:
                raise InputError(f"{path}: some trajectories hold the plan and others do not")
    except InputError:
        raise
    except (OSError, KeyError, ValueError, RuntimeError) as error:
        first_line = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise InputError(f"{path}: unreadable dataset (truncated or not HDF5?): {first_line}") from None
    return Dataset(path, DatasetMetadata.from_record(metadata), trajectories, np.asarray(groups, dtype=int),
                   file_sha256(path))
