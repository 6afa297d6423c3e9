"""The identified robot: a typed YAML file (`identify -o identified.yaml`) and the model it makes.

The file holds the identified parameters as `PlantEffects` of the robot's description (each moving
link's inertia, every joint's damping, Coulomb friction and reflected rotor inertia) and where they
came from (`Identification`: robot, dataset, split, derivative source, the fit's settings and test
error). `IdentifiedRobot.model` is the description's discrete plant with those parameters (a
`PlantModel`): one step is the simulation's own (in `mpc`, `PlantModel.for_control`: the same parameters
in RK4 steps with exact Jacobians), so it serves `evaluate`, `view`, `mpc` and the LeafSystem like any
model. Like a checkpoint it knows its
dataset (`trained_on`, `split_indices`, `check_fits`): held-out plans stay held out.
"""
import dataclasses
import pathlib

import numpy as np

from stdm_drake.data.schema import check_split
from stdm_drake.errors import InputError
from stdm_drake.outputs import IDENTIFIED_MARKER
from stdm_drake.robots.effects import PlantEffects, RigidInertia
from stdm_drake.robots.plant import PlantConfig
from stdm_drake.robots.plant_effects_check import check_plant_effects
from stdm_drake.dynamics.physics import PlantModel
from stdm_drake.config import load_yaml_config

IDENTIFIED_SUFFIXES = (".yaml", ".yml")
HEADER = (f"{IDENTIFIED_MARKER}: the robot's description with these parameters\n"
          "# (effects: link inertias, joint damping, Coulomb friction, reflected rotor inertia) is the model; use it\n"
          "# as a model with evaluate, view and mpc --model NAME=FILE (docs/guides/identification.md).\n")


@dataclasses.dataclass
class Identification:
    """Where an identified robot came from.

    robot, robot_model_sha256: the robot config's name and its description file's SHA-256; dataset,
    dataset_sha256: the data; sample_period, plant_time_step: s (the model steps the plant at
    plant_time_step over each sample period); derivative_source: "true" (the simulation's accelerations)
    or "smoothed" (Savitzky-Golay of the measured angles, smoothing_window samples); split: trajectory
    indices "train" (fitted), "val" (chose the settings), "test"; coulomb_velocity_scale (rad/s) and
    regularization: the settings chosen on "val"; test_torque_error: RMS torque error / RMS torque on
    "test" (NaN without test trajectories)."""
    robot: str = ""
    robot_model_sha256: str = ""
    dataset: str = ""
    dataset_sha256: str = ""
    sample_period: float = 0.0
    plant_time_step: float = 0.0
    derivative_source: str = "true"
    smoothing_window: int = 0
    split: dict[str, list[int]] = dataclasses.field(default_factory=dict)
    coulomb_velocity_scale: float = 0.0
    regularization: float = 0.0
    test_torque_error: float = float("nan")


@dataclasses.dataclass
class IdentifiedRobot:
    """An identified robot file: `effects` (the identified parameters) and `identification`."""
    effects: PlantEffects = dataclasses.field(default_factory=PlantEffects)
    identification: Identification = dataclasses.field(default_factory=Identification)
    path = None   # the file it was loaded from (not a field of the file)

    def validate(self) -> None:
        self.effects.validate()
        record = self.identification
        if not (np.isfinite(record.sample_period) and record.sample_period > 0):
            raise InputError(f"identification sample_period must be > 0 s, got {record.sample_period}")
        if not (np.isfinite(record.plant_time_step) and 0 < record.plant_time_step <= record.sample_period):
            raise InputError(f"identification plant_time_step must be in (0, sample_period], got {record.plant_time_step}")
        if not self.effects.link_inertia:
            raise InputError("an identified robot needs effects.link_inertia (the identified links)")
        check_split(record.split, "identification")

    # -- like a checkpoint: which dataset and split ---------------------------------------------------------
    def trained_on(self, dataset) -> bool:
        """Whether `dataset` is the file this robot was identified from (same SHA-256)."""
        return bool(self.identification.dataset_sha256) and self.identification.dataset_sha256 == dataset.sha256

    def split_indices(self, dataset, part: str) -> list[int] | None:
        """Trajectory indices of the identification's `part` ("train", "val", "test") of `dataset`; None when
        it was identified from another dataset."""
        if not self.trained_on(dataset):
            return None
        return check_split(self.identification.split, f"{self.path or 'identified robot'}: identification",
                           dataset.num_trajectories)[part]

    def check_fits(self, dataset) -> None:
        """InputError unless `dataset` is of the same robot description and sample period."""
        record, where = self.identification, self.path or "identified robot"
        if abs(record.sample_period - dataset.sample_period) > 1e-12:
            raise InputError(f"{where}: identified at {record.sample_period} s, {dataset.path} is at "
                             f"{dataset.sample_period} s")
        theirs = dataset.metadata.robot_model_sha256
        if theirs is not None and theirs != record.robot_model_sha256:
            raise InputError(f"{where}: identified on another robot description than {dataset.path}'s")

    def check_robot(self, robot) -> None:
        """InputError unless `robot`'s description is the identified one and the parameters fit it."""
        where = self.path or "identified robot"
        if robot is None or self.identification.robot_model_sha256 != robot.model_sha256():
            raise InputError(f"{where}: identified on another robot description than "
                             f"{robot.model_path.name if robot else 'the one given'} (robot {robot.name if robot else '?'}); "
                             "pass its config with --robot")
        try:
            check_plant_effects(self.effects, robot, self.identification.plant_time_step)
        except InputError as error:
            raise InputError(f"{where}: {error}") from None

    def describe(self, name: str) -> str:
        """One line on the model named `name` of this identified robot: what was identified from what."""
        record = self.identification
        return (f"model {name}: identified rigid-body model of {record.robot} from {pathlib.Path(record.dataset).name}"
                f" ({record.derivative_source} derivatives, Coulomb velocity scale {record.coulomb_velocity_scale:g} "
                f"rad/s; test torque error {record.test_torque_error:.3g})")

    def model(self, robot, name: str = "identified"):
        """The identified robot as a `PlantModel` of `robot` (its description must be the identified one)."""
        record = self.identification
        self.check_robot(robot)
        return PlantModel(record.sample_period, PlantConfig.discrete(record.plant_time_step, effects=self.effects),
                          robot=robot, name=name, source=self)


def identified_model(identified: IdentifiedRobot, robot, *, name: str | None = None, for_control: bool = False,
                     check_robot: bool = True):
    """An identified robot's model (the "identified robot" kind of `dynamics.model_files`): the description's
    plant with the identified parameters (`IdentifiedRobot.model`), its RK4 twin for control. It needs
    `robot` and always checks it (check_robot is accepted for the checkpoint kind's callers)."""
    if robot is None:
        raise InputError(f"{identified.path}: an identified robot needs its robot (--robot)")
    model = identified.model(robot, name=name or "identified")
    return model.for_control() if for_control else model


def is_identified_file(path) -> bool:
    """Whether `path` names an identified robot (a YAML file) rather than a checkpoint."""
    return pathlib.Path(path).suffix.lower() in IDENTIFIED_SUFFIXES


def load_identified(path) -> IdentifiedRobot:
    """The IdentifiedRobot of a file `identify` wrote (InputError with one line otherwise)."""
    identified = load_yaml_config(path, IdentifiedRobot, what="identified robot")
    identified.path = pathlib.Path(path)
    return identified


def identified_text(identified: IdentifiedRobot) -> str:
    """The file's text: a comment header and the typed YAML of `effects` and `identification`."""
    from pydrake.common.yaml import yaml_dump_typed
    content = IdentifiedRobot(effects=identified.effects, identification=identified.identification)
    return HEADER + yaml_dump_typed(content)


def link_inertia(parameters: np.ndarray) -> RigidInertia:
    """The RigidInertia (about the centre of mass) of one link's 10 parameters [m, m c, I about the origin]."""
    mass = float(parameters[0])
    com = np.asarray(parameters[1:4], dtype=float) / mass
    ixx, iyy, izz, ixy, ixz, iyz = parameters[4:10]
    about_origin = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]], dtype=float)
    central = about_origin - mass * (com @ com * np.eye(3) - np.outer(com, com))
    return RigidInertia(mass=mass, center_of_mass=com.tolist(),
                        inertia=[central[0, 0], central[1, 1], central[2, 2], central[0, 1], central[0, 2],
                                 central[1, 2]])
