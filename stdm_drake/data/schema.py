"""What a dataset file may hold (its layout: `data.dataset`'s docstring): the protocols, the arrays each
protocol's trajectories hold, and the checks every file passes on its way in or out (`check_trajectory`,
`check_record`, `attribute_number`), each an InputError with one line naming what is wrong; and the check
of a split of a dataset's trajectories that a checkpoint or an identified robot records (`check_split`)."""
import collections

import numpy as np

from stdm_drake.errors import InputError

SIMULATED_PROTOCOLS = ("excitation", "tracking")
PROTOCOLS = SIMULATED_PROTOCOLS + ("logged",)
RECORDED_ARRAYS = ("q", "v", "tau", "tau_next")
SIMULATION_ARRAYS = ("q_true", "v_true", "qdd", "qdd_end")
PLANNED_ARRAYS = ("q_planned", "v_planned", "qdd_planned")
LOG_ARRAYS = ("v_smoothed", "qdd_smoothed", "qdd_measured")
# Bounds no robot's data reaches (rad or m, rad/s, rad/s^2: a continuous joint may wind up many turns,
# a light joint accelerate fast): a value beyond them is a corrupted or foreign file. The robot's own
# limits are checked where the robot is known (data.compatibility.check_dataset_robot).
PLAUSIBLE_MAGNITUDE = {"q": 1e4, "q_true": 1e4, "v": 1e4, "v_true": 1e4, "qdd": 1e7, "qdd_end": 1e7,
                       "v_smoothed": 1e4, "qdd_smoothed": 1e7, "qdd_measured": 1e7}
ACTION_ARRAYS = ("tau", "tau_next")
# A trajectory whose velocities explain its position steps at a period further than this factor from the
# file's sample period was recorded at another period (data of 0.02 s in a file of 0.01 s: a factor 2).
PERIOD_FACTOR = 1.5
SPLIT_PARTS = ("train", "val", "test")


def required_arrays(protocol: str, planned: bool = False) -> tuple:
    """The arrays every trajectory of `protocol` holds (planned: a log with the plan)."""
    if protocol == "logged":
        return RECORDED_ARRAYS + LOG_ARRAYS + (PLANNED_ARRAYS if planned else ())
    return RECORDED_ARRAYS + SIMULATION_ARRAYS + (PLANNED_ARRAYS if protocol == "tracking" else ())


def check_trajectory(name: str, traj: dict, protocol: str, sample_period: float | None = None) -> None:
    """Shapes and finiteness of one trajectory's arrays, and (given the file's `sample_period`, s) that its
    velocities step its positions at that period (`check_period`); raises InputError naming the field."""
    planned = protocol == "tracking" or (protocol == "logged" and any(key in traj for key in PLANNED_ARRAYS))
    expected_arrays = required_arrays(protocol, planned)
    missing = [key for key in expected_arrays if key not in traj]
    if missing:
        raise InputError(f"trajectory {name}: missing arrays {missing}")
    unknown = sorted(set(traj) - set(expected_arrays))
    if unknown:
        raise InputError(f"trajectory {name}: arrays {unknown} do not belong to {protocol} data (it holds "
                         f"{', '.join(expected_arrays)})")
    num_steps, joints = state_shape(traj, expected_arrays)
    if joints < 0:
        raise InputError(f"trajectory {name}: its state arrays are not tables of samples (T+1, n joints): "
                         + ", ".join(f"{key} {np.shape(traj[key])}" for key in ("q", "v") if key in traj))
    if num_steps < 2:
        raise InputError(f"trajectory {name}: needs at least 3 samples (2 steps), has {num_steps + 1}")
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
    if sample_period is not None:
        check_period(name, traj, sample_period)


def state_shape(traj: dict, keys) -> tuple[int, int]:
    """(T, n) of a trajectory: the shape (T+1, n) most of its state-shaped arrays (all but tau, tau_next,
    qdd_end) share, so that the one array of another shape is the one named, q among them; (-1, -1)
    when none is two-dimensional."""
    shapes = collections.Counter(np.shape(traj[key]) for key in keys
                                 if key not in ACTION_ARRAYS + ("qdd_end",) and np.ndim(traj[key]) == 2)
    if not shapes:
        return -1, -1
    (rows, joints), _ = shapes.most_common(1)[0]
    return rows - 1, joints


def implied_period(q: np.ndarray, v: np.ndarray) -> float | None:
    """The sample period (s) at which velocities v (T+1, n) explain the steps of positions q (T+1, n) by the
    trapezoid rule, a least-squares fit over every step and joint; None when they hardly move or the fit
    explains less than 90% of the steps (noise, a continuous joint's wrap), so nothing can be said."""
    steps, mean = np.diff(q, axis=0), 0.5 * (v[1:] + v[:-1])
    scale = float(np.sum(mean * mean))
    if scale == 0.0:
        return None
    period = float(np.sum(steps * mean)) / scale
    if np.sum((steps - period * mean) ** 2) > 0.1 * np.sum(steps * steps):
        return None
    return period


def check_period(name: str, traj: dict, sample_period: float) -> None:
    """InputError when trajectory `name`'s velocities step its positions at a period more than PERIOD_FACTOR
    from the file's `sample_period` (s): a trajectory recorded at another period (the file holds no time
    stamps; the simulation's true state where the file has it, else the measured one)."""
    q, v = (traj["q_true"], traj["v_true"]) if "q_true" in traj else (traj["q"], traj["v"])
    period = implied_period(np.asarray(q, dtype=float), np.asarray(v, dtype=float))
    if period is not None and not sample_period / PERIOD_FACTOR <= period <= sample_period * PERIOD_FACTOR:
        raise InputError(f"trajectory {name}: its velocities step its positions at about {period:.2g} s, the file's "
                         f"sample_period is {sample_period:g} s; a trajectory recorded at another period")


def attribute_number(value, what: str, kind=float):
    """A scalar attribute or metadata value as `kind` (InputError naming `what` for an array, string or list)."""
    if isinstance(value, (bool, np.bool_)) or np.ndim(value) != 0:
        raise InputError(f"{what} must be one number, got {np.asarray(value).tolist()!r}")
    if isinstance(value, (str, bytes, np.str_, np.bytes_)):   # (float("0.01") would take a hand-typed string)
        raise InputError(f"{what} must be a number, got the text {value!r}")
    try:
        number = kind(value)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a number, got {value!r}") from None
    if kind is int and number != value:
        raise InputError(f"{what} must be a whole number, got {np.asarray(value).item()!r}")
    return number


def check_record(record, path) -> dict:
    """The metadata record of a dataset file checked for the types the library reads (a mapping; protocol a
    string; sample_period a positive number; robot, plant sections mappings; joint_names a list of strings)."""
    if not isinstance(record, dict):
        raise InputError(f"{path}: metadata must be a JSON object, got {type(record).__name__}")
    for key in ("protocol", "sample_period"):
        if key not in record:
            raise InputError(f"{path}: metadata lacks required field {key!r}")
    if not isinstance(record["protocol"], str):
        raise InputError(f"{path}: metadata protocol must be a string, got {record['protocol']!r}")
    attribute_number(record["sample_period"], f"{path}: metadata sample_period")
    for section in ("robot", "plant", "sensor", "controller", "planner", "import"):
        if record.get(section) is not None and not isinstance(record[section], dict):
            raise InputError(f"{path}: metadata {section} must be a mapping, got {record[section]!r}")
    names = record.get("joint_names")
    if names is not None and not (isinstance(names, list) and all(isinstance(name, str) for name in names)):
        raise InputError(f"{path}: metadata joint_names must be a list of names, got {names!r}")
    return record


def check_split(split, where: str, num_trajectories: int | None = None) -> dict:
    """A recorded split of a dataset's trajectories (a checkpoint's or an identified robot's: "train",
    "val", "test" -> indices) as part -> list of int (every part, [] when absent), checked: whole numbers
    >= 0, none twice (in one part or two), each below `num_trajectories` (the dataset's, when known).
    InputError naming `where` otherwise (an index out of range would select another trajectory or none,
    a negative one count from the end: a training plan taken for a held-out one)."""
    if not isinstance(split, dict) or set(split) - set(SPLIT_PARTS):
        raise InputError(f"{where}: split must map {', '.join(SPLIT_PARTS)} to trajectory indices, got {split!r}")
    parts, seen = {}, {}
    for part in SPLIT_PARTS:
        indices = split.get(part) or []
        if not isinstance(indices, (list, tuple)):
            raise InputError(f"{where}: split {part} must be a list of trajectory indices, got {indices!r}")
        parts[part] = [attribute_number(index, f"{where}: split {part} index", int) for index in indices]
        for index in parts[part]:
            if index < 0:
                raise InputError(f"{where}: split {part} names trajectory {index}; trajectory indices are >= 0")
            if num_trajectories is not None and index >= num_trajectories:
                raise InputError(f"{where}: split {part} names trajectory {index}, the dataset has {num_trajectories} "
                                 f"(0..{num_trajectories - 1})")
            if index in seen:
                raise InputError(f"{where}: split names trajectory {index} twice ({seen[index]} and {part}); a split's "
                                 "parts are disjoint")
            seen[index] = part
    return parts
