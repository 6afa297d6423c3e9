"""Typed YAML configs: dataclass schemas loaded with Drake's `yaml_load_typed`.

Bad files (missing, malformed YAML, unknown keys, wrong types, not a mapping) raise InputError
with one line that names the file.
"""
import pathlib

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
    return config
