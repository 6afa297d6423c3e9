"""Typed YAML configs: dataclass schemas loaded with Drake's `yaml_load_typed`.

Bad files (missing, malformed YAML, unknown keys, wrong types, not a mapping, values the schema's
`validate()` rejects) raise InputError with one line that names the file.
"""
import pathlib

import numpy as np

from pydrake.common.yaml import yaml_load_typed

from stdm_drake.errors import InputError


def one_line(error: BaseException) -> str:
    """An exception's message squeezed onto one line (its type name if it has none)."""
    return " ".join(str(error).split()) or type(error).__name__


def load_yaml_config(path, schema, what: str = "config"):
    """Load `path` into a new instance of the dataclass `schema`; keys left out keep their defaults.

    what: how errors name the file's contents, e.g. "tracking spec".
    """
    path = pathlib.Path(path)
    if not path.is_file():
        raise InputError(f"{what} not found: {path}")
    try:
        config = yaml_load_typed(schema=schema, filename=str(path), defaults=schema())
    except Exception as error:  # the YAML parser and Drake's schema checks raise several types
        raise InputError(f"{path}: malformed {what}: {one_line(error)}") from None
    if not isinstance(config, schema):
        raise InputError(f"{path}: malformed {what}: expected a mapping of {schema.__name__} fields")
    if hasattr(config, "validate"):
        try:
            config.validate()
        except InputError as error:
            raise InputError(f"{path}: {error}") from None
    return config


def check_joint_vector(label: str, values, *, count: int | None = None, nonnegative: bool = False) -> np.ndarray:
    """`values` (one per joint, or one for every joint) as a float array, or InputError unless they are
    finite (non-negative) numbers. count: the robot's joints: the result is (count,), a single value
    broadcast; None (config files checked before the robot is known): any non-empty length."""
    array = np.atleast_1d(np.asarray(values, dtype=float))
    kind = "finite non-negative" if nonnegative else "finite"
    if array.ndim != 1 or not array.size or not np.all(np.isfinite(array)) or (nonnegative and np.any(array < 0)):
        raise InputError(f"{label} must be {kind} numbers (one per joint, or one for all), got {values}")
    if count is not None:
        if array.size not in (1, count):
            raise InputError(f"{label} has {array.size} values; the robot has {count} joints (give {count}, or one "
                             "for all)")
        array = np.broadcast_to(array, (count,)).copy()
    return array


def require(condition: bool, message: str, value) -> None:
    """InputError "<message>, got <value>" unless `condition` holds (config validation)."""
    if not condition:
        raise InputError(f"{message}, got {value!r}")
