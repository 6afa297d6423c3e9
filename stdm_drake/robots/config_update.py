"""`robot init --update`: a robot config YAML that `robot init` wrote, brought up to date with its description
(after the description or the YAML was edited), keeping the user's edits.

`robot init` marks, on each value's own line, the values it derived or chose, with the value itself:

    effort_limits:
      joint_1: 438.0  # derived: 438.0
    home: [0.725, 0.208, 0.565]  # chosen: [0.725, 0.208, 0.565]

`--update` keeps every field the YAML sets, except the marked values the user has not changed (the value still
equals its mark): those are derived or chosen again, as a fresh `robot init` would. A value the user edited
keeps its edit (and loses its mark); a field the user added is kept as it is.
"""
from __future__ import annotations

import copy
import re

import yaml

from stdm_drake.errors import InputError

LIMIT_FIELDS = ("position_limits", "velocity_limits", "effort_limits")
MARKED_LINE = re.compile(r"^(?P<indent>[ ]*)(?P<key>[^\s:#][^:#]*?):[ ]*(?P<value>[^#]*?)[ ]*#[ ]*"
                         r"(?P<kind>derived|chosen): (?P<mark>.*?)[ ]*$")


def mark(value) -> str:
    """The text of `value` on a YAML line and in its mark (one flow-style line)."""
    return yaml.safe_dump(value, default_flow_style=True, width=10_000, sort_keys=False).strip().removesuffix(
        "...").strip()


def kept_fields(text: str, fields: dict) -> dict:
    """The fields of a robot config YAML (`fields`: its top-level mapping, `text`: its text) that `--update` keeps:
    every one, less the marked values whose value still equals its mark (a limit's joint entry; `home`: the link
    pairs in contact in every configuration tried are then added to the kept `disabled_collisions`)."""
    kept = copy.deepcopy(fields)
    section = None
    for line in text.splitlines():
        if line and not line.startswith((" ", "#")):
            section = line.split(":", 1)[0].strip()
        found = MARKED_LINE.match(line)
        if found is None:
            continue
        try:
            value, marked = yaml.safe_load(found["value"]), yaml.safe_load(found["mark"])
        except yaml.YAMLError:
            continue   # (a mark the user broke: the value is the user's)
        if value != marked:
            continue
        key = found["key"].strip()
        if found["indent"] and section in LIMIT_FIELDS and isinstance(kept.get(section), dict):
            kept[section].pop(key, None)
        elif not found["indent"] and key == "home":
            kept.pop("home", None)
    return {field: value for field, value in kept.items() if value not in ({}, None)}


def read_for_update(path) -> dict:
    """kept_fields of the robot config YAML at `path`, read first as a RobotConfig (its one-line errors: an unknown
    key, a value of the wrong type); the config's own checks run on the updated config."""
    from stdm_drake.config import load_yaml_config, read_yaml_document   # lazy: pydrake
    from stdm_drake.robots.robot import RobotConfig   # lazy: pydrake
    load_yaml_config(path, RobotConfig, what="robot config", validate=False)
    document = read_yaml_document(path)
    if not isinstance(document, dict):
        raise InputError(f"{path}: --update reads a robot config YAML (a mapping of its fields), which this is not")
    return kept_fields(path.read_text(), document)
