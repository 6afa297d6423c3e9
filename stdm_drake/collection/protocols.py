"""Protocol files: `protocol: !Excitation {...}` (trajectories/excitation*.yaml) or `protocol: !Tracking
{sampling: ..., planner: !Quintic ...}` (trajectories/tracking*.yaml), a Union loaded by Drake's
`yaml_load_typed` as manipulation's `Scenario.model_drivers` are: the tag says which protocol the file
holds, so `collect --config FILE` needs no --protocol. Files in the layout before the tags (the
protocol's fields at the top; a planner's `kind:` among its fields) still load, as the protocol the
command asks for, with one warning line saying how to update them."""
import dataclasses
import os
import typing

from stdm_drake.collection.excitation import Excitation
from stdm_drake.collection.plan import Tracking
from stdm_drake.collection.planner_configs import PLANNER_TYPES
from stdm_drake.config import load_yaml_config, read_yaml_document
from stdm_drake.data.schema import SIMULATED_PROTOCOLS as PROTOCOLS   # what collect simulates
from stdm_drake.errors import InputError, warn
from stdm_drake.robots.robot import Robot

ProtocolConfig = typing.Union[Excitation, Tracking]   # a data protocol's settings, tagged in YAML
PROTOCOL_TYPES = {cls.kind: cls for cls in typing.get_args(ProtocolConfig)}   # one per dataset PROTOCOLS
WHAT = {"excitation": "excitation config", "tracking": "tracking spec"}   # how errors name each file


@dataclasses.dataclass
class ProtocolFile:
    """Schema of trajectories/*.yaml: one protocol, tagged."""
    protocol: ProtocolConfig = dataclasses.field(default_factory=Tracking)


def protocol_named_in(path) -> str | None:
    """The protocol a protocol YAML's tag names ("excitation" or "tracking"), or None for a file without a
    `protocol:` key (the layout before the tags) or one that does not read (loading it says why)."""
    document = read_yaml_document(path)
    if not (isinstance(document, dict) and "protocol" in document):
        return None
    return load_protocol(path).kind


def load_protocol(path, kind: str | None = None) -> ProtocolConfig:
    """The protocol config in a protocol YAML; `kind` ("excitation", "tracking"): the protocol asked for,
    InputError when the file holds the other (None: whatever it holds; a file without a tag then needs
    one). Not yet checked against a robot (`load_excitation`, `load_tracking_spec` do that). A file in
    the layout before the tags owes one warning line (`errors.warn`: a command prints it once it has
    succeeded)."""
    if kind is not None and kind not in PROTOCOL_TYPES:
        raise InputError(f"protocol must be one of {PROTOCOLS}, got {kind!r}")
    document = read_yaml_document(path)
    if isinstance(document, dict) and "protocol" in document:
        config = load_yaml_config(path, ProtocolFile, what=WHAT.get(kind, "protocol file")).protocol
        if kind is not None and config.kind != kind:
            raise InputError(f"{path} holds the {config.kind} protocol, not the {kind} protocol")
        return config
    if kind is None:
        raise InputError(f"{path}: a protocol file starts with `protocol: !Excitation` or `protocol: !Tracking`")
    cls = PROTOCOL_TYPES[kind]
    config = load_yaml_config(path, cls, what=WHAT[kind],
                              old_layouts={"planner": (PLANNER_TYPES, "planner: !{}")} if cls is Tracking else None)
    warn(f"stdm-drake: warning: {path} holds the {kind} protocol's fields at the top; write "
         f"`protocol: !{cls.__name__}` with them indented under it")
    return config


def load_excitation(path, *, robot: Robot) -> Excitation:
    """The excitation protocol of a protocol YAML for `robot`: per-joint lists of its length (or one
    value), start poses inside its limits; InputError naming the file otherwise."""
    excitation = load_protocol(path, "excitation")
    try:
        excitation = excitation.for_robot(robot)
        excitation.validate()
        excitation.check_start_poses(robot)
    except InputError as error:
        raise InputError(f"{path}: {error}") from None
    return excitation


def load_tracking_spec(path: str | os.PathLike, *, robot: Robot) -> Tracking:
    """The tracking protocol of a protocol YAML (`protocol: !Tracking` with `sampling` and `planner`
    under it) for `robot`: per-joint lists of its length (or one value), IK seeds of its joints. Files
    in the layouts before the tags (`sampling` and `planner` at the top; `kind:` among the planner's
    fields) still load, with one warning line each saying how to update them.

    Raises InputError, naming the file, on a missing or malformed file, unknown keys, wrong
    types or invalid values, or another protocol.
    """
    spec = load_protocol(path, "tracking")
    for section in ("planner", "sampling"):
        try:
            getattr(spec, section).validate()
            setattr(spec, section, getattr(spec, section).for_robot(robot))
        except InputError as error:
            raise InputError(f"{path}: {section}: {error}") from None
    return spec
