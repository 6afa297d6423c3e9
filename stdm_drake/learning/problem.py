"""The training problem of one model type on one dataset split: the network's config, the training and
validation pairs and the checkpoint metadata (`training_problem`), the default split sizes. It is the
programmatic entry point that `stdm-drake train`, `reproduce` and the tools share; `fit_model` /
`train_alpha_grid` (`learning.alpha_selection`) then train it."""
from __future__ import annotations

import dataclasses

import torch

from stdm_drake.errors import InputError
from stdm_drake.learning.checkpoint import CheckpointMetadata
from stdm_drake.learning.models import DEFAULT_ENSEMBLE_SIZE, parse_model_type
from stdm_drake.learning.trainable import DEFAULT_NETWORK, network_class
from stdm_drake.learning.regression import RegressionData
from stdm_drake.learning.structure import PAPER, ModelStructure
from stdm_drake.data.inspect import plan_mismatch
from stdm_drake import __version__


# A plan whose accelerations are further than this from the recorded ones (relative RMS difference, mean over
# joints: `data.inspect.plan_mismatch`) is not a default derivative target. Measured on the shipped protocols
# (docs/learning.md, "A default that learns"): tracked plans 0.18-0.44 per joint (UR-10 and Panda), the
# identification protocol's dithered torque 0.95-1.0.
PLAN_MISMATCH_LIMIT = 0.5


@dataclasses.dataclass
class SourceChoice:
    """The derivative sources `train` chooses among by validation when none is given (`candidate_sources`),
    in order of preference, and the plan's measured mismatch (`data.inspect.plan_mismatch`; None without a
    plan)."""
    sources: tuple
    mismatch: dict | None

    def plan_left_out(self) -> bool:
        """Whether the dataset's plan was left out for being too far from the recorded motion."""
        return self.mismatch is not None and "planned" not in self.sources

    def describe(self) -> str:
        """One clause: which sources and why."""
        if self.mismatch is None:
            return f"derivative targets: {self.sources[0]} (the only default source of these data)"
        measured = (f"the plan's accelerations are {self.mismatch['acceleration']:.2f} (relative RMS) from the "
                    f"recorded ones ({self.mismatch['recorded']})")
        if self.plan_left_out():
            return (f"derivative targets: {self.sources[0]}; the plan is left out: {measured}, more than "
                    f"{PLAN_MISMATCH_LIMIT:g}")
        return f"derivative targets chosen by validation from {', '.join(self.sources)} ({measured})"


def candidate_sources(dataset, indices) -> SourceChoice:
    """The derivative sources a default `train` tries on `dataset` (trajectories `indices`: training and
    validation only, never the test split): the plan (the paper's real-robot protocol) where the data have one
    and its accelerations are within PLAN_MISMATCH_LIMIT of the recorded motion, then the recorded motion's own
    (the simulation's truth, or a log's smoothed angles)."""
    mismatch = plan_mismatch(dataset, indices)
    if mismatch is None:
        return SourceChoice(sources=(dataset.default_derivative_source,), mismatch=None)
    recorded = (mismatch["recorded"],)
    plan = ("planned",) if mismatch["acceleration"] <= PLAN_MISMATCH_LIMIT else ()
    return SourceChoice(sources=plan + recorded, mismatch=mismatch)


@dataclasses.dataclass
class TrainingProblem:
    """One model type on one dataset split: the network to fit (`model_config`), the training and
    validation pairs (raw units), and the checkpoint metadata that records where they came from. With
    several derivative sources `train` and `val` are dicts source -> RegressionData (the same transitions,
    each source's derivative targets; `fit_model` chooses among them by validation)."""
    model_config: object   # the network kind's config record
    train: RegressionData | dict
    val: RegressionData | dict
    metadata: CheckpointMetadata

    @property
    def transitions(self) -> int:
        """Training transitions (pairs)."""
        return len(next(iter(self.train.values())) if isinstance(self.train, dict) else self.train)


def training_problem(dataset, split, *, model_type: str = "DD", activation: str = "swish", hidden_width: int = 100,
                     hidden_layers: int = 3, ensemble_size: int = DEFAULT_ENSEMBLE_SIZE, delta: bool = True,
                     derivative_source: str | None = None, action_rate: str = "forward_difference",
                     structure: ModelStructure = PAPER, robot=None, network: str = DEFAULT_NETWORK,
                     **metadata_fields) -> TrainingProblem:
    """The TrainingProblem of `model_type` ("D" ... "PED"; it decides probabilistic heads and whether
    the ensemble size applies) on `dataset` (a loaded Dataset) with `split` (a Split or {"train",
    "val", "test"} -> trajectory indices). State and action sizes come from the data; derivative
    targets from `derivative_source` (None: the dataset's default) and `action_rate`; what the network
    predicts and sees from `structure` (default the paper's; `robot` is the nominal model of
    nominal-acceleration inputs, required by them). derivative_source: one source, or a tuple of several:
    then train and val are dicts source -> RegressionData and the metadata names the first (`fit_model`
    records the chosen one). network: the registered network kind (`trainable.NETWORK_KINDS`), which takes
    activation, hidden_width and hidden_layers as far as it has them."""
    kind = parse_model_type(model_type)
    sources = tuple(derivative_source) if isinstance(derivative_source, (tuple, list)) else None
    source = sources[0] if sources else (derivative_source or dataset.default_derivative_source)
    parts = split.as_dict() if hasattr(split, "as_dict") else split
    features = None
    if structure.uses_nominal_model:
        if robot is None:
            raise InputError(f"model inputs {structure.inputs!r} need the robot's nominal model; pass its robot")
        features = structure.nominal_features(robot, dataset.sample_period)

    def pairs(indices, source=source) -> RegressionData:
        transitions = dataset.transitions(list(indices), derivative_source=source, action_rate=action_rate)
        return structure.regression_data(transitions, features)

    if sources and len(sources) > 1:
        base = pairs
        pairs = lambda indices: {name: base(indices, name) for name in sources}  # noqa: E731

    train, val = pairs(parts["train"]), pairs(parts["val"])
    first = dataset.trajectory(0)
    state_dim, action_dim = 2 * first.q.shape[1], first.tau.shape[1]
    input_dim, output_dim = structure.network_sizes(state_dim, action_dim)
    config = network_class(network).problem_config(
        input_dim=input_dim, output_dim=output_dim, residual=delta, ensemble_size=ensemble_size if kind.ensemble else 1,
        probabilistic=kind.probabilistic, start_at_residual=structure.grey_box and delta,   # a grey box starts as its plant
        options=dict(activation=activation, hidden_width=hidden_width, hidden_layers=hidden_layers))
    metadata = dataset_metadata(dataset, parts, model_type=model_type, derivative_source=source,
                                action_rate=action_rate,
                                structure=None if structure == PAPER else structure.as_dict(), **metadata_fields)
    return TrainingProblem(model_config=config, train=train, val=val, metadata=metadata)


def dataset_metadata(dataset, split, *, model_type: str, derivative_source: str, action_rate: str,
                     **fields) -> CheckpointMetadata:
    """Checkpoint metadata of a model trained on `dataset` (a loaded Dataset) with `split` (a Split or
    {"train", "val", "test"} -> indices); `fields`: further CheckpointMetadata fields."""
    parts = split.as_dict() if hasattr(split, "as_dict") else split
    return CheckpointMetadata(model_type=model_type, dataset_path=str(dataset.path), dataset_sha256=dataset.sha256,
                              protocol=dataset.protocol, sample_period=dataset.sample_period,
                              split={key: [int(i) for i in value] for key, value in parts.items()},
                              derivative_source=derivative_source, action_rate=action_rate,
                              torch_version=torch.__version__, stdm_drake_version=__version__,
                              robot_name=dataset.metadata.robot_name,
                              robot_model_sha256=dataset.metadata.robot_model_sha256,
                              joint_names=dataset.metadata.joint_names,
                              plant_effects=(dataset.metadata.plant_effects.record()
                                             if dataset.metadata.plant_effects is not None else None), **fields)
