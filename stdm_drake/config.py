"""Typed YAML configs: dataclass schemas loaded with Drake's `yaml_load_typed`.

Bad files (missing, malformed YAML, unknown keys, wrong types) raise InputError with one line
that names the file.
"""
from __future__ import annotations

import pathlib

from pydrake.common.yaml import yaml_load_typed

from stdm_drake.errors import InputError


def load_yaml_config(path, schema):
    """Load `path` into a new instance of the dataclass `schema` (defaults fill missing keys)."""
    path = pathlib.Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config file not found: {path}")
    try:
        return yaml_load_typed(schema=schema, filename=str(path), defaults=schema())
    except Exception as error:  # yaml parser and Drake's schema checks raise several types
        text = " ".join(str(error).split())
        raise InputError(f"{path}: invalid {schema.__name__} config: {text[:300]}") from None
