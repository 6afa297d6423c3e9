"""Model files: the one way from a file on disk to a `DynamicsModel`, for every command, study and tool.

    load_model_file(path)          the file's record (a `Checkpoint` that `train` wrote, an
                                   `IdentifiedRobot` that `identify` wrote, ...), which knows its dataset
    load_model(source, robot)      the model of a path or of a loaded record

The kinds of model file are registered in one place, `MODEL_FILE_KINDS` below, by the names of their
functions (the dynamics layer imports none of the stages that implement them; the structure test checks
that every name resolves). A package outside the toolbox adds a kind through the entry-point group
"stdm_drake.model_files", each entry a `ModelFileKind`; those are tried before the built-in ones.
A new kind of model file is one `ModelFileKind` with its three functions.
"""
from __future__ import annotations

import dataclasses
import importlib
import importlib.metadata
import pathlib

ENTRY_POINT_GROUP = "stdm_drake.model_files"


@dataclasses.dataclass(frozen=True)
class ModelFileKind:
    """One kind of model file, by the "module:name" names of its record type and its three functions.

    record                     the type `load` returns
    recognizes(path) -> bool   whether a path is this kind's (by suffix or content; None: any file, the
                               fallback kind)
    load(path) -> record       the file's record; one-line `InputError` on a file of another kind
    model(record, robot, *, name, for_control, **options) -> DynamicsModel
                               the record's model of `robot` (None where the kind needs none), named
                               `name` (None: the kind's own name); for_control: the variant meant for an
                               MPC's prediction model (exact Jacobians in microseconds) rather than the
                               evaluation's reference
    """
    name: str
    record: str
    recognizes: str | None
    load: str
    model: str

    def function(self, role: str):
        """The object that field `role` names, imported."""
        module, _, attribute = getattr(self, role).partition(":")
        return getattr(importlib.import_module(module), attribute)


MODEL_FILE_KINDS: tuple[ModelFileKind, ...] = (
    ModelFileKind("identified robot", record="stdm_drake.identification.identified:IdentifiedRobot",
                  recognizes="stdm_drake.identification.identified:is_identified_file",
                  load="stdm_drake.identification.identified:load_identified",
                  model="stdm_drake.identification.identified:identified_model"),
    ModelFileKind("checkpoint", record="stdm_drake.learning.checkpoint:Checkpoint", recognizes=None, load="stdm_drake.learning.checkpoint:load_checkpoint",
                  model="stdm_drake.learning.learned_model:checkpoint_model"),
)


def model_file_kinds() -> tuple[ModelFileKind, ...]:
    """The registered kinds in the order they are tried: entry points first, then the built-in ones."""
    added = tuple(entry.load() for entry in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP))
    return added + MODEL_FILE_KINDS


def kind_of(path) -> ModelFileKind:
    """The kind of model file that `path` is (the fallback kind when no other recognizes it)."""
    for kind in model_file_kinds():
        if kind.recognizes is None or kind.function("recognizes")(pathlib.Path(path)):
            return kind
    raise AssertionError("MODEL_FILE_KINDS ends with a fallback kind")


def load_model_file(path):
    """The record of the model file at `path` (InputError in one line where it is not a model file,
    FileNotFoundError where it is missing)."""
    return kind_of(path).function("load")(path)


def load_model(source, robot=None, *, name: str | None = None, for_control: bool = False, **options):
    """The `DynamicsModel` of a model file: `source` a path, or a record `load_model_file` returned.

    robot: the `robots.robot.Robot` the model predicts (checked against the file; an identified robot
    needs it); name: the model's name in tables and plots (None: the kind's own, e.g. the checkpoint's
    model type); for_control: the MPC's variant (see `ModelFileKind`); options: passed to the kind's
    model function (a checkpoint's `LearnedModel` options). The model keeps its record as
    `model.checkpoint`."""
    if isinstance(source, (str, pathlib.Path)):
        kind = kind_of(source)
        record = kind.function("load")(source)
    else:
        record = source
        kinds = [kind for kind in model_file_kinds() if isinstance(record, kind.function("record"))]
        if not kinds:
            raise TypeError(f"not a model file's record: {type(record).__name__}")
        kind = kinds[0]
    return kind.function("model")(record, robot, name=name, for_control=for_control, **options)
