"""What a dataset file may hold (its layout: `data.dataset`'s docstring): the protocols, the arrays each
protocol's trajectories hold, and the checks every file passes on its way in or out (`check_trajectory`,
`check_record`, `attribute_number`), each an InputError with one line naming what is wrong."""
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

def required_arrays(protocol: str, planned: bool = False) -> tuple:
    """The arrays every trajectory of `protocol` holds (planned: a log with the plan)."""
    if protocol == "logged":
        return RECORDED_ARRAYS + LOG_ARRAYS + (PLANNED_ARRAYS if planned else ())
    return RECORDED_ARRAYS + SIMULATION_ARRAYS + (PLANNED_ARRAYS if protocol == "tracking" else ())


def check_trajectory(name: str, traj: dict, protocol: str) -> None:
    """Shapes and finiteness of one trajectory's arrays; raises InputError naming the field."""
    planned = protocol == "tracking" or (protocol == "logged" and any(key in traj for key in PLANNED_ARRAYS))
    expected_arrays = required_arrays(protocol, planned)
    missing = [key for key in expected_arrays if key not in traj]
    if missing:
        raise InputError(f"trajectory {name}: missing arrays {missing}")
    unknown = sorted(set(traj) - set(expected_arrays))
    if unknown:
        raise InputError(f"trajectory {name}: arrays {unknown} do not belong to {protocol} data (it holds "
                         f"{', '.join(expected_arrays)})")
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


def attribute_number(value, what: str, kind=float):
    """A scalar attribute or metadata value as `kind` (InputError naming `what` for an array, string or list)."""
    if isinstance(value, (bool, np.bool_)) or np.ndim(value) != 0:
        raise InputError(f"{what} must be one number, got {np.asarray(value).tolist()!r}")
    try:
        number = kind(value)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a number, got {value!r}") from None
    if kind is int and number != value:
        raise InputError(f"{what} must be a whole number, got {value!r}")
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
