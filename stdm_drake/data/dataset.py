"""Dataset files: one self-describing HDF5 file per dataset, one group per trajectory.

Layout (format "stdm-drake-dataset", version 1):

    /                      attrs: format, format_version, protocol, sample_period (s),
                                  num_trajectories, metadata_json (everything else, see below)
    /trajectories/000000   attrs: group (int; initial-pose index, 0 for excitation)
        q        (T+1, n) rad     joint angles as the learner sees them (measured: noise + filter)
        v        (T+1, n) rad/s   joint velocities as the learner sees them
        tau      (T, m)   N m     action: torques of the m actuated joints over [t_k, t_k+1)
                                  (zero-order hold); m = n unless the robot is underactuated
        tau_next (m,)     N m     action the controller computes at t_T (not applied); closes the
                                  forward difference of the action rate at the last step
        q_true, v_true (T+1, n)   the plant's true state at the sample instants
        qdd      (T+1, n) rad/s^2 true acceleration just after t_k (under the torque from t_k on)
        qdd_end  (T, n)   rad/s^2 true acceleration just before t_k+1 (under tau_k)
        q_planned, v_planned, qdd_planned (T+1, n)   tracking protocol only: the plan

n is the robot's arm-joint count (the UR-10: 6), recorded with the joint names and the robot's config.
metadata_json holds the robot model hash, plant time step, protocol settings (planner,
controller gains, excitation ranges, noise and filter), seed and package versions. Files are
written atomically and deterministically (same content -> same bytes).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import pathlib

import h5py
import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.files import atomic_path, json_default
from stdm_drake.outputs import DATASET_FORMAT
from stdm_drake.robots.effects import PlantEffects

FORMAT = DATASET_FORMAT
FORMAT_VERSION = 1
PROTOCOLS = ("excitation", "tracking")
REQUIRED_ARRAYS = ("q", "v", "tau", "tau_next", "q_true", "v_true", "qdd", "qdd_end")
# Bounds no robot's data reaches (rad or m, rad/s, rad/s^2: a continuous joint may wind up many turns,
# a light joint accelerate fast): a value beyond them is a corrupted or foreign file. The robot's own
# limits are checked where the robot is known (data.compatibility.check_dataset_robot).
PLAUSIBLE_MAGNITUDE = {"q": 1e4, "q_true": 1e4, "v": 1e4, "v_true": 1e4, "qdd": 1e7, "qdd_end": 1e7}
PLANNED_ARRAYS = ("q_planned", "v_planned", "qdd_planned")
DERIVATIVE_SOURCES = ("true", "planned")
ACTION_RATE_SCHEMES = ("forward_difference", "zero_order_hold")


@dataclasses.dataclass(frozen=True, eq=False)
class Trajectory:
    """One trajectory's arrays (float64; names, shapes and units in the module docstring): T steps, n
    joints, m actuated ones. The planned arrays exist in tracking data only (None otherwise)."""
    q: np.ndarray
    v: np.ndarray
    tau: np.ndarray
    tau_next: np.ndarray
    q_true: np.ndarray
    v_true: np.ndarray
    qdd: np.ndarray
    qdd_end: np.ndarray
    q_planned: np.ndarray | None = None
    v_planned: np.ndarray | None = None
    qdd_planned: np.ndarray | None = None

    @classmethod
    def from_arrays(cls, name: str, arrays: dict, planned: bool) -> "Trajectory":
        """The trajectory of a mapping name -> array, checked (`_check_trajectory`: every array present,
        no other, shapes, finite numbers, plausible magnitudes); InputError naming trajectory `name`."""
        _check_trajectory(name, arrays, planned)
        return cls(**{key: np.asarray(value, dtype=np.float64) for key, value in arrays.items()})

    def arrays(self) -> dict:
        """Name -> array of the arrays it holds (the planned ones only in tracking data)."""
        return {field.name: getattr(self, field.name) for field in dataclasses.fields(self)
                if getattr(self, field.name) is not None}

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
    def default_derivative_source(self) -> str:
        """Derivative targets the protocol calls for: true for simulation, planned for "real"."""
        return "planned" if self.protocol == "tracking" else "true"

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
        if source == "planned" and self.protocol != "tracking":
            raise InputError(f"{self.path}: planned derivative targets exist only in tracking data, "
                             f"this dataset's protocol is {self.protocol!r}")
        if source == "planned" and action_rate == "zero_order_hold":
            raise InputError("the zero_order_hold scheme needs true accelerations (derivative source 'true')")
        indices = np.arange(self.num_trajectories) if indices is None else np.asarray(indices, dtype=int)
        if indices.size and (indices.min() < 0 or indices.max() >= self.num_trajectories):
            raise InputError(f"trajectory index out of range 0..{self.num_trajectories - 1}")
        dt = self.sample_period
        parts = []
        for index in indices:
            traj = self._trajectories[index]
            tau_all = np.vstack([traj.tau, traj.tau_next[None]])
            if source == "true":
                qd, qdd_after = traj.v_true, traj.qdd
            else:
                qd, qdd_after = traj.v_planned, traj.qdd_planned
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


def _check_trajectory(name: str, traj: dict, planned: bool) -> None:
    """Shapes and finiteness of one trajectory's arrays; raises InputError naming the field."""
    missing = [key for key in REQUIRED_ARRAYS + (PLANNED_ARRAYS if planned else ()) if key not in traj]
    if missing:
        raise InputError(f"trajectory {name}: missing arrays {missing}")
    unknown = sorted(set(traj) - set(REQUIRED_ARRAYS + PLANNED_ARRAYS))
    if unknown:
        raise InputError(f"trajectory {name}: unknown arrays {unknown} (a dataset holds {', '.join(REQUIRED_ARRAYS)}"
                         f" and, tracked, {', '.join(PLANNED_ARRAYS)})")
    num_steps = len(traj["q"]) - 1 if np.ndim(traj["q"]) == 2 else -1  # the samples are the reference
    if num_steps < 2:
        raise InputError(f"trajectory {name}: needs at least 2 steps (3 samples of q), has {num_steps}")
    joints = np.shape(traj["q"])[1] if np.ndim(traj["q"]) == 2 else -1  # the robot's, from its positions
    actions = np.shape(traj["tau"])[1] if np.ndim(traj["tau"]) == 2 else -1  # torques of its actuated joints
    expected = {"tau": (num_steps, actions), "qdd_end": (num_steps, joints), "tau_next": (actions,)}
    for key in traj:
        if not (np.issubdtype(np.asarray(traj[key]).dtype, np.floating)
                or np.issubdtype(np.asarray(traj[key]).dtype, np.integer)):
            raise InputError(f"trajectory {name}: {key} holds {np.asarray(traj[key]).dtype} values, not numbers")
        shape = np.shape(traj[key])
        want = expected.get(key, (num_steps + 1, joints))
        if shape != want:
            raise InputError(f"trajectory {name}: {key} has shape {shape}, expected {want}")
        if not np.all(np.isfinite(traj[key])):
            raise InputError(f"trajectory {name}: {key} contains NaN or inf")
        if key in PLAUSIBLE_MAGNITUDE and np.max(np.abs(traj[key])) > PLAUSIBLE_MAGNITUDE[key]:
            raise InputError(f"trajectory {name}: {key} reaches {np.max(np.abs(traj[key])):.3g}, beyond any joint's "
                             f"range (|{key}| <= {PLAUSIBLE_MAGNITUDE[key]:g}); not robot data")


def write_dataset(path, trajectories: list[Trajectory], groups, metadata: dict) -> pathlib.Path:
    """Validate and write a dataset atomically (temp file in the same folder, then rename).

    trajectories: the Trajectory of each (arrays named as in the module docstring).
    groups: (num_trajectories,) ints. metadata: JSON-serializable dict with at least
    "protocol" and "sample_period" (s). On any error no file (and no temp file) is left.
    """
    path = pathlib.Path(path)
    if metadata.get("protocol") not in PROTOCOLS:
        raise InputError(f"metadata protocol must be one of {PROTOCOLS}, got {metadata.get('protocol')!r}")
    sample_period = float(metadata.get("sample_period", 0.0))
    if not (np.isfinite(sample_period) and sample_period > 0):
        raise InputError(f"metadata sample_period must be a positive number of seconds, got {sample_period}")
    groups = np.asarray(groups, dtype=int)
    if groups.shape != (len(trajectories),):
        raise InputError(f"groups has shape {groups.shape}, expected ({len(trajectories)},)")
    if not trajectories:
        raise InputError("a dataset needs at least one trajectory")
    planned = metadata["protocol"] == "tracking"
    arrays = [traj.arrays() for traj in trajectories]
    for i, traj in enumerate(arrays):
        _check_trajectory(f"{i:06d}", traj, planned)
    metadata_json = json.dumps(metadata, sort_keys=True, default=json_default)
    with atomic_path(path) as temp_name, h5py.File(temp_name, "w", libver=("earliest", "v110"), track_order=False) as f:
        f.attrs["format"] = FORMAT
        f.attrs["format_version"] = FORMAT_VERSION
        f.attrs["protocol"] = metadata["protocol"]
        f.attrs["sample_period"] = sample_period
        f.attrs["num_trajectories"] = len(trajectories)
        f.attrs["metadata_json"] = metadata_json
        root = f.create_group("trajectories")
        for i, traj in enumerate(arrays):
            group = root.create_group(f"{i:06d}")
            group.attrs["group"] = int(groups[i])
            for key in sorted(traj):
                group.create_dataset(key, data=np.asarray(traj[key], dtype=np.float64), track_times=False)
    return path


def file_sha256(path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def load_dataset(path) -> Dataset:
    """Read and validate a dataset file; any problem raises InputError with one clear line."""
    path = pathlib.Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"dataset not found: {path}")
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != FORMAT:
                raise InputError(f"{path}: not a stdm-drake dataset (format attribute missing or wrong)")
            version = int(f.attrs.get("format_version", -1))
            if version != FORMAT_VERSION:
                raise InputError(f"{path}: dataset format version {version}, this stdm-drake reads {FORMAT_VERSION}")
            try:
                metadata = json.loads(f.attrs["metadata_json"])
            except (KeyError, json.JSONDecodeError) as error:
                raise InputError(f"{path}: metadata unreadable ({error})") from None
            for key in ("protocol", "sample_period"):
                if key not in metadata:
                    raise InputError(f"{path}: metadata lacks required field {key!r}")
            if metadata["protocol"] not in PROTOCOLS:
                raise InputError(f"{path}: unknown protocol {metadata['protocol']!r}")
            period = float(f.attrs.get("sample_period", np.nan))
            if not (period > 0 and period == float(metadata["sample_period"])):
                raise InputError(f"{path}: sample period {period} missing, non-positive or inconsistent with metadata")
            if "trajectories" not in f:
                raise InputError(f"{path}: no trajectories group")
            names = sorted(f["trajectories"])
            declared = int(f.attrs.get("num_trajectories", -1))
            if declared != len(names) or not names:
                raise InputError(f"{path}: header declares {declared} trajectories, file holds {len(names)}")
            planned = metadata["protocol"] == "tracking"
            trajectories, groups = [], []
            for name in names:
                group = f["trajectories"][name]
                trajectories.append(Trajectory.from_arrays(name, {key: group[key][()] for key in group}, planned))
                groups.append(int(group.attrs.get("group", 0)))
    except InputError:
        raise
    except (OSError, KeyError, ValueError, RuntimeError) as error:
        first_line = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise InputError(f"{path}: unreadable dataset (truncated or not HDF5?): {first_line}") from None
    return Dataset(path, DatasetMetadata.from_record(metadata), trajectories, np.asarray(groups, dtype=int),
                   file_sha256(path))
