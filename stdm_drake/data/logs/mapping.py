"""What a log does not say about itself: `LogMapping`, a typed YAML file (`stdm-drake import --mapping FILE`),
its fields overridden by the command's options.

    format: rtde_csv                 # or ros2_bag; "" (default): from the file
    torque_source: current           # RTDE: target_moment (default) or current (actual_current); bags: effort
                                     # (default) or current (effort in A, as UR's ROS 2 driver reports it)
    torque_constants: [13.3, 13.3, 13.3, 9.3, 9.3, 9.3]   # N m / A per joint, with torque_source current
    joint_names: [shoulder_pan_joint, ...]   # bags: the log's name of each of the robot's arm joints, in
                                             # the robot's order ([]: the robot's own names)
    joint_states_topic: /joint_states
    controller_state_topic: ""       # "": the bag's JointTrajectoryControllerState topic, if any; none: no plan
    sample_period: 0.0               # s; 0: the log's median period
    gap_factor: 3.0                  # a trajectory ends where no row comes for gap_factor x the log's period
    pause_velocity: 0.01             # rad/s: every joint slower than this ...
    pause_duration: 0.5              # s: ... this long is a pause, left out between two trajectories
    min_duration: 0.5                # s: shorter pieces are dropped (counted)
    max_duration: 10.0               # s: longer pieces are cut (this bounds the import's memory)
    smoothing_window: 21             # samples (odd): the Savitzky-Golay differentiator of the derivative targets
"""
import dataclasses
import typing

from stdm_drake.errors import InputError

FORMATS = ("rtde_csv", "ros2_bag")
# per format, its torque sources (the first the default); "current": the logged currents (RTDE actual_current,
# a bag's effort where the driver reports currents there, as UR's ROS 2 driver does) times torque_constants
TORQUE_SOURCES = {"rtde_csv": ("target_moment", "current"), "ros2_bag": ("effort", "current")}


@dataclasses.dataclass
class LogMapping:
    """See the module docstring for each field, its unit and its default."""
    format: str = ""
    torque_source: str = ""
    torque_constants: typing.List[float] = dataclasses.field(default_factory=list)
    joint_names: typing.List[str] = dataclasses.field(default_factory=list)
    joint_states_topic: str = "/joint_states"
    controller_state_topic: str = ""
    sample_period: float = 0.0
    gap_factor: float = 3.0
    pause_velocity: float = 0.01
    pause_duration: float = 0.5
    min_duration: float = 0.5
    max_duration: float = 10.0
    smoothing_window: int = 21

    def validate(self) -> None:
        """InputError (one line, naming the field) for a value no log can have."""
        if self.format not in ("",) + FORMATS:
            raise InputError(f"format must be one of {FORMATS}, got {self.format!r}")
        known = sorted({source for sources in TORQUE_SOURCES.values() for source in sources})
        if self.torque_source not in ("", *known):
            raise InputError(f"torque_source must be one of {known}, got {self.torque_source!r}")
        if self.format and self.torque_source and self.torque_source not in TORQUE_SOURCES[self.format]:
            raise InputError(f"torque_source {self.torque_source!r} is not in a {self.format} log "
                             f"({', '.join(TORQUE_SOURCES[self.format])})")
        if self.torque_source == "current" and not self.torque_constants:
            raise InputError("torque_source current needs torque_constants (N m / A, one per joint)")
        if any(not (1e-6 <= constant < 1e4) for constant in self.torque_constants):   # (1e-320: no torque at all)
            raise InputError(f"torque_constants must be in [1e-06, 1e4) N m / A, got {self.torque_constants}")
        if len(set(self.joint_names)) != len(self.joint_names):
            raise InputError(f"joint_names must be distinct, got {self.joint_names}")
        for name, low, high in (("sample_period", 0.0, 10.0), ("gap_factor", 1.0, 1e3), ("pause_velocity", 0.0, 10.0),
                                ("pause_duration", 0.0, 1e4), ("min_duration", 0.0, 1e4), ("max_duration", 0.0, 3600.0)):
            value = getattr(self, name)
            if not (low <= value <= high) or (name in ("gap_factor", "max_duration") and value == low):
                raise InputError(f"{name} must be in {'(' if name in ('gap_factor', 'max_duration') else '['}{low:g}, "
                                 f"{high:g}], got {value!r}")
        if self.pause_duration >= self.max_duration:
            raise InputError(f"pause_duration ({self.pause_duration:g} s) must be below max_duration "
                             f"({self.max_duration:g} s)")
        if self.min_duration >= self.max_duration:
            raise InputError(f"min_duration ({self.min_duration:g} s) must be below max_duration "
                             f"({self.max_duration:g} s)")
        if not (5 <= self.smoothing_window <= 1001 and self.smoothing_window % 2 == 1):
            raise InputError(f"smoothing_window must be an odd number of samples in 5..1001, got {self.smoothing_window}")

    def with_format(self, kind: str) -> "LogMapping":
        """This mapping for a log of format `kind`, its torque source defaulted (checked)."""
        mapping = dataclasses.replace(self, format=kind,
                                      torque_source=self.torque_source or TORQUE_SOURCES[kind][0])
        mapping.validate()
        return mapping


BAG_ONLY = ("joint_names", "joint_states_topic", "controller_state_topic")   # what only a ROS 2 bag's import reads


def check_settings_used(mapping: LogMapping, given) -> None:
    """InputError (one line) for a setting given (an option, or a key of the mapping file: `given` names
    them) that the import of this log would ignore, whatever its value: the topics and joint names with a
    log that is not a bag, torque constants without torque_source current. mapping: with its format set
    (`with_format`)."""
    flag = lambda name: f"{name} (--{name.replace('_', '-')})"  # noqa: E731
    if mapping.format != "ros2_bag":
        for name in BAG_ONLY:
            if name in given:
                raise InputError(f"{flag(name)} is for ROS 2 bags; this log is {mapping.format}, so it "
                                 "would be ignored")
    if "torque_constants" in given and mapping.torque_source != "current":
        raise InputError(f"{flag('torque_constants')} convert motor currents (torque_source current); with "
                         f"torque_source {mapping.torque_source} they would be ignored")


def load_mapping(path) -> LogMapping:
    """The LogMapping of a YAML file (InputError with one line for a bad file)."""
    from stdm_drake.config import load_yaml_config   # lazy: pydrake
    return load_yaml_config(path, LogMapping, what="log mapping")
