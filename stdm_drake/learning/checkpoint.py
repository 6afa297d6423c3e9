"""Checkpoints: one file per trained model (weights, architecture, normalizers, training settings,
learning curves, typed metadata), written atomically and read with torch.load(weights_only=True);
and the one check of whether a checkpoint fits a dataset."""
from __future__ import annotations

import dataclasses
import typing
import io
import json
import math
import pathlib

import torch

from stdm_drake.data.schema import check_split
from stdm_drake.errors import InputError
from stdm_drake.files import atomic_path, json_default
from stdm_drake.learning.trainable import DEFAULT_NETWORK, TrainableModel, network_class
from stdm_drake.learning.settings import TrainingConfig
from stdm_drake.learning.structure import ModelStructure
from stdm_drake.paths import check_input_file

CHECKPOINT_FORMAT = "stdm-drake-model"
CHECKPOINT_VERSION = 2  # 2: derivative loss scaled by the state spread (alpha as in eq. 9), no rate normalizer
HISTORY_COLUMNS = ("epoch", "train_loss", "train_state_loss", "train_derivative_loss",
                   "val_loss", "val_state_loss", "val_derivative_loss", "val_mse", "seconds")


@dataclasses.dataclass
class CheckpointMetadata:
    """What a checkpoint records about how it was made. Every field is optional: a model fitted to
    arrays (not a dataset file) has no dataset fields.

    model_type: "D", "PED", ...; dataset_path, dataset_sha256: the training dataset file and its hash;
    protocol: "excitation" or "tracking"; sample_period: s per model step (the dataset's);
    split: {"train", "val", "test"} -> trajectory indices of that dataset; split_seed, per_group:
    how the split was drawn; derivative_source ("true"/"planned") and action_rate
    ("forward_difference"/"zero_order_hold"): how the derivative targets were formed; threads,
    torch_version, stdm_drake_version: the software that trained it; alpha_selection: the alpha grid's
    validation curve when alpha was chosen by validation (`AlphaSelection.as_dict`); robot_name,
    robot_model_sha256, joint_names: the robot of the training dataset; plant_effects: the effects of
    the plant that produced it (`PlantEffects.record`; absent: the robot's description as it is).
    """
    model_type: str | None = None
    dataset_path: str | None = None
    dataset_sha256: str | None = None
    protocol: str | None = None
    sample_period: float | None = None
    split: dict | None = None
    split_seed: int | None = None
    per_group: bool | None = None
    derivative_source: str | None = None
    action_rate: str | None = None
    threads: int | None = None
    torch_version: str | None = None
    stdm_drake_version: str | None = None
    alpha_selection: dict | None = None
    robot_name: str | None = None
    robot_model_sha256: str | None = None
    joint_names: list | None = None
    structure: dict | None = None
    plant_effects: dict | None = None

    @classmethod
    def from_dict(cls, values: dict) -> "CheckpointMetadata":
        """From the stored dict; unknown keys raise InputError."""
        unknown = sorted(set(values) - {field.name for field in dataclasses.fields(cls)})
        if unknown:
            raise InputError(f"unknown checkpoint metadata fields {unknown}")
        return cls(**values)

    def as_dict(self) -> dict:
        """The fields that are set, as plain JSON values."""
        values = {key: value for key, value in dataclasses.asdict(self).items() if value is not None}
        return json.loads(json.dumps(values, default=json_default))


@dataclasses.dataclass
class Checkpoint:
    """A loaded checkpoint: the model (best weights) and what was stored beside it."""
    path: pathlib.Path
    model: TrainableModel
    model_config: typing.Any   # the network kind's config record (`TrainableModel.config_type`)
    training_config: TrainingConfig | None
    metadata: CheckpointMetadata
    history: dict
    resume: dict | None

    @property
    def structure(self) -> ModelStructure:
        """What the network predicts and sees (the paper's structure for checkpoints that record none)."""
        return ModelStructure.from_dict(self.metadata.structure)

    @property
    def model_sizes(self) -> tuple[int, int]:
        """(state_dim, action_dim) of the model the network serves: (2n, m)."""
        return self.structure.model_sizes(self.model_config.input_dim, self.model_config.output_dim)

    def trained_on(self, dataset) -> bool:
        """Whether `dataset` (a loaded Dataset) is the file this model was trained on (same SHA-256)."""
        return self.metadata.dataset_sha256 is not None and self.metadata.dataset_sha256 == dataset.sha256

    def check_sizes(self, *, state_dim: int | None = None, action_dim: int | None = None) -> None:
        """InputError unless the model's STDM sizes equal the given ones (None: any)."""
        mine = self.model_sizes
        wanted = (state_dim if state_dim is not None else mine[0], action_dim if action_dim is not None else mine[1])
        if mine != wanted:
            raise InputError(f"{self.path}: model has state dim {mine[0]} and action dim "
                             f"{mine[1]}, expected state dim {wanted[0]} and action dim {wanted[1]}")

    @property
    def sample_period(self) -> float:
        """The period (s) the model steps at, as its metadata records it; InputError when it records none
        (a model fitted to arrays, not to a dataset file: what its step is cannot be known) or one <= 0."""
        period = self.metadata.sample_period
        if period is None:
            raise InputError(f"{self.path}: checkpoint metadata has no sample_period (train it on a dataset file)")
        if isinstance(period, bool) or not (isinstance(period, (int, float)) and math.isfinite(period) and period > 0):
            raise InputError(f"{self.path}: checkpoint metadata has an invalid sample_period {period!r}")
        return float(period)

    def check_fits(self, dataset) -> None:
        """InputError unless the model can predict `dataset`'s transitions: the state (2 x joints) and
        action (joints) sizes match, the robot is the same (when both record it), and the model steps at
        the dataset's sample period (which it must record: `sample_period`)."""
        first = dataset.trajectory(0)
        self.check_sizes(state_dim=2 * first.q.shape[1], action_dim=first.tau.shape[1])
        recorded = dataset.metadata
        for field, what in (("robot_model_sha256", "robot model"), ("joint_names", "joints")):
            mine, theirs = getattr(self.metadata, field), getattr(recorded, field)
            if mine is not None and theirs is not None and mine != theirs:
                raise InputError(f"{self.path}: trained on another robot than {dataset.path} ({what} differ: "
                                 f"{self.metadata.robot_name or '?'} vs {recorded.robot_name or '?'})")
        period = self.sample_period
        if abs(period - dataset.sample_period) > 1e-12:
            raise InputError(f"{self.path}: model steps at {period} s, {dataset.path} at {dataset.sample_period} s")

    def split_indices(self, dataset, part: str) -> list[int] | None:
        """Trajectory indices of the model's `part` ("train", "val", "test") split of `dataset`, or None
        when it was not trained on this dataset (so its split does not apply)."""
        if not self.trained_on(dataset) or self.metadata.split is None:
            return None
        return check_split(self.metadata.split, f"{self.path}: checkpoint", dataset.num_trajectories)[part]


def _metadata(metadata: CheckpointMetadata | dict | None) -> CheckpointMetadata:
    if isinstance(metadata, CheckpointMetadata):
        return metadata
    return CheckpointMetadata.from_dict(dict(metadata or {}))


def save_checkpoint(path, model: TrainableModel, *, training_config: TrainingConfig | None = None,
                    history: dict | None = None, metadata: CheckpointMetadata | dict | None = None,
                    resume_state: dict | None = None) -> pathlib.Path:
    """Write one file (atomically) holding weights, architecture, normalizers, options and metadata.

    Only tensors and plain Python values are stored, so it loads with torch.load(weights_only=True).
    """
    content = {
        "format": CHECKPOINT_FORMAT,
        "format_version": CHECKPOINT_VERSION,
        "network": model.kind,
        "model_config": model.config_record(),
        "weights": {name: value.detach().cpu().clone() for name, value in model.state_dict().items()},
        "training_config": dataclasses.asdict(training_config) if training_config is not None else None,
        "history": {column: [float(v) for v in values] for column, values in (history or {}).items()},
        "metadata": _metadata(metadata).as_dict(),
        "resume": resume_state,
    }
    path = pathlib.Path(path)
    buffer = io.BytesIO()   # serialized first: a full disk is then Python's OSError (one line), not torch's
    torch.save(content, buffer)
    with atomic_path(path) as temp:
        temp.write_bytes(buffer.getbuffer())
    return path


def load_checkpoint(path) -> Checkpoint:
    """Read and validate a checkpoint; any problem raises InputError (FileNotFoundError if missing)."""
    path = check_input_file(path, "checkpoint", missing=FileNotFoundError)
    with open(path, "rb") as f:
        magic = f.read(8)
    if not magic.startswith(b"PK\x03\x04"):  # torch.save writes a zip archive
        kind = " (it is an HDF5 file: a dataset?)" if magic == b"\x89HDF\r\n\x1a\n" else ""
        raise InputError(f"{path}: not a readable stdm-drake checkpoint: not a PyTorch checkpoint file{kind}")
    try:
        content = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # truncated zip, disallowed pickle content, ...
        detail = " ".join(str(error).split()).split(". ")[0] or type(error).__name__  # first sentence only
        raise InputError(f"{path}: not a readable stdm-drake checkpoint (truncated or corrupt?): {detail}") from None
    if not isinstance(content, dict) or content.get("format") != CHECKPOINT_FORMAT:
        raise InputError(f"{path}: not a stdm-drake model checkpoint (format field missing or wrong)")
    if content.get("format_version") != CHECKPOINT_VERSION:
        hint = (" (written before the derivative loss took the paper's alpha scaling: retrain it)"
                if content.get("format_version") == 1 else "")
        raise InputError(f"{path}: checkpoint format version {content.get('format_version')}, "
                         f"this stdm-drake reads {CHECKPOINT_VERSION}{hint}")
    try:
        network = network_class(content.get("network", DEFAULT_NETWORK))   # (files before kinds: the MLP)
        model_config = network.config_type.from_dict(dict(content["model_config"]))
        training = content.get("training_config")
        training_config = TrainingConfig(**training) if training is not None else None
        model = network(model_config)
        model.load_state_dict(content["weights"])
        metadata = CheckpointMetadata.from_dict(dict(content.get("metadata") or {}))
        ModelStructure.from_dict(metadata.structure).model_sizes(model_config.input_dim, model_config.output_dim)
    except InputError as error:
        raise InputError(f"{path}: {error}") from None
    except (KeyError, TypeError, RuntimeError, ValueError) as error:
        detail = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise InputError(f"{path}: inconsistent checkpoint contents: {detail}") from None
    if metadata.split is not None:
        check_split(metadata.split, f"{path}: checkpoint")
    if not all(torch.isfinite(value).all() for value in model.state_dict().values()):
        raise InputError(f"{path}: checkpoint weights contain NaN or inf")
    spreads = {name: value for name, value in model.state_dict().items() if name.endswith("normalizer.std")}
    for name, value in spreads.items():
        if not bool((value > 0).all()):
            raise InputError(f"{path}: checkpoint {name} has a zero or negative spread (its predictions would be NaN)")
    model.eval()
    return Checkpoint(path=path, model=model, model_config=model_config, training_config=training_config,
                      metadata=metadata, history=dict(content.get("history") or {}),
                      resume=content.get("resume"))


def load_model(path, *, state_dim: int | None = None, action_dim: int | None = None) -> Checkpoint:
    """load_checkpoint plus a check of the STDM sizes the caller expects (InputError on mismatch)."""
    checkpoint = load_checkpoint(path)
    checkpoint.check_sizes(state_dim=state_dim, action_dim=action_dim)
    return checkpoint
