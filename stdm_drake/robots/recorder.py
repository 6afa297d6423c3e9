"""Meshcat recordings of a robot's joint trajectories, live and as standalone HTML pages.

Recordings replay stored joint angles in a visualization-only diagram (plant + scene graph + the
visualizers Drake's `ApplyVisualizationConfig` adds for a `VisualizationConfig`), so what is shown
never feeds back into the simulation that produced it.
With `ghost=True` a second, translucent copy of the robot shows another trajectory beside the robot, e.g. a
learned model's open-loop prediction from the same initial state and actions, or an MPC reference.
"""
import copy
import pathlib
import logging
import time

import numpy as np
from pydrake.geometry import IllustrationProperties, Meshcat, Rgba, RoleAssign
from pydrake.lcm import DrakeLcm
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.systems.framework import DiagramBuilder
from pydrake.visualization import ApplyVisualizationConfig, VisualizationConfig

from stdm_drake.files import write_text_atomic, line_text
from stdm_drake.robots.robot import Robot
from stdm_drake.config import file_keys, load_yaml_config, read_yaml_document, decimal_number
from stdm_drake.errors import InputError
from stdm_drake.outputs import html_marker
from stdm_drake import interrupts

GHOST_COLOR = Rgba(1.0, 0.55, 0.1, 0.35)  # translucent orange
# what a recording shows unless told otherwise: the illustration geometry only (no collision shapes,
# contact forces or inertia ellipsoids); `publish_period` is always the recording's sample period
RECORDING = VisualizationConfig(publish_proximity=False, publish_contacts=False, publish_inertia=False)


def load_visualization_config(path) -> VisualizationConfig:
    """Drake's `VisualizationConfig` from a YAML file (its field names: `publish_proximity: true` shows
    the collision geometry, `default_illustration_color`, `initial_proximity_alpha`, ...); fields left
    out keep the recording's defaults (RECORDING). InputError for a missing or malformed file, or one that sets
    what a recording sets itself (publish_period: the data's sample period; lcm_bus)."""
    document = read_yaml_document(path) if pathlib.Path(path).is_file() else None
    for key in ("default_illustration_color", "default_proximity_color"):   # (Drake's own error names no field)
        rgba = (document.get(key) or {}).get("rgba") if isinstance(document, dict) and isinstance(
            document.get(key), dict) else None
        if rgba is not None and not (isinstance(rgba, list) and len(rgba) in (3, 4)
                                     and all(0.0 <= _colour_value(x) <= 1.0 for x in rgba)):
            raise InputError(f"{path}: {key} rgba must be 3 or 4 numbers in [0, 1] (red, green, blue and an optional "
                             f"opacity), got {rgba}")
    config = load_yaml_config(path, VisualizationConfig, what="visualization config", defaults=RECORDING)
    if "publish_period" in file_keys(path):   # (a NaN one too: held-out run 27)
        raise InputError(f"{path}: publish_period: a recording shows every sample period of the data, so the file's "
                         f"{config.publish_period!r} would be ignored; leave it out")
    if config.lcm_bus != "default":
        raise InputError(f"{path}: lcm_bus: recordings publish to Meshcat only, got {config.lcm_bus!r}")
    if not 0.0 <= config.initial_proximity_alpha <= 1.0:   # (a NaN too: an opacity; held-out run 28)
        raise InputError(f"{path}: initial_proximity_alpha must be an opacity in [0, 1], got "
                         f"{config.initial_proximity_alpha!r}")
    if "default_illustration_color" in file_keys(path) and not config.publish_illustration:
        raise InputError(f"{path}: default_illustration_color colours the illustration geometry, which "
                         "publish_illustration false leaves out, so it would be ignored; leave one of them out")
    if "enable_meshcat_creation" in file_keys(path):
        raise InputError(f"{path}: enable_meshcat_creation: a recording makes its own Meshcat, so the file's "
                         f"{config.enable_meshcat_creation!r} would be ignored; leave it out")
    ignored = [key for key in ("initial_proximity_alpha", "default_proximity_color") if key in file_keys(path)]
    if ignored and not config.publish_proximity:
        raise InputError(f"{path}: {' and '.join(ignored)} {'shape' if len(ignored) > 1 else 'shapes'} the collision "
                         "geometry, which publish_proximity false "
                         "leaves out, so it would be ignored; set publish_proximity: true, or leave it out")
    return config


def _colour_value(item) -> float:
    """A colour channel as Drake's YAML reads it: a number, or a number YAML 1.1 reads as text (`1e300`, no point);
    NaN (outside every range) for a word or another type."""
    if isinstance(item, (int, float)) and not isinstance(item, bool):
        return float(item)
    try:
        return decimal_number(item) if isinstance(item, str) else float("nan")
    except ValueError:
        return float("nan")


def recording_visualization(path, recording: bool, options: str = "--html FILE or --meshcat"):
    """The VisualizationConfig of the YAML at `path` for a recording (None when `path` is None: the recorder's
    default); InputError when `path` is given but nothing is recorded (`recording` False; `options`: what
    records, for the message)."""
    if path is None:
        return None
    if not recording:
        raise InputError(f"--visualization configures the Meshcat recording: give {options} too, or leave it out")
    return load_visualization_config(path)


def check_meshcat_allowed(option: str) -> None:
    """`option` (--html, --meshcat) needs Meshcat's server: refused at once when DRAKE_ALLOW_NETWORK (a list of
    the services Drake may open, separated by ":"; unset or empty: all) leaves Meshcat out."""
    import os
    allowed = os.environ.get("DRAKE_ALLOW_NETWORK", "")
    if allowed and "meshcat" not in allowed.split(":"):
        raise InputError(f"{option} needs Meshcat, which DRAKE_ALLOW_NETWORK={allowed} turns off; set "
                         "DRAKE_ALLOW_NETWORK=meshcat (Meshcat serves on this machine only)")


class TrajectoryRecorder:
    """Appends joint trajectories q (T+1, n) rad, sampled every `sample_period` s, to one
    Meshcat animation that plays them one after another (with `pause` s of rest between).
    visualization: Drake's VisualizationConfig of what is shown (default RECORDING); its
    publish_period is replaced by sample_period and its LCM publishers go to an in-memory bus."""

    def __init__(self, sample_period: float, meshcat: Meshcat | None = None, pause: float = 0.25,
                 ghost: bool = False, *, robot: Robot, visualization: VisualizationConfig | None = None):
        self.meshcat = meshcat or Meshcat()
        self.sample_period = sample_period
        self.pause = pause
        builder = DiagramBuilder()
        self.plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
        self.robot = robot.add_to(self.plant)
        self.ghost = robot.add_to(self.plant, model_name_prefix="ghost") if ghost else None
        self.plant.Finalize()
        if ghost:
            _recolor(self.plant, scene_graph, self.ghost, GHOST_COLOR)
        config = copy.copy(visualization if visualization is not None else RECORDING)
        config.publish_period = sample_period
        # Drake's visualizers for the config; its LCM visualizer (for Meldis) publishes in memory (the
        # diagram keeps a pointer to the bus, so the recorder holds it)
        self.lcm = DrakeLcm("memq://")
        ApplyVisualizationConfig(config, builder, plant=self.plant, scene_graph=scene_graph, meshcat=self.meshcat,
                                 lcm=self.lcm)
        self.diagram = builder.Build()
        self.context = self.diagram.CreateDefaultContext()
        self.plant_context = self.plant.GetMyContextFromRoot(self.context)
        self.diagram.ForcedPublish(self.context)  # creates the geometry in Meshcat
        self.meshcat.SetCameraPose(camera_in_world=[1.6, -1.9, 1.1], target_in_world=[0.4, 0.0, 0.45])
        self.meshcat.StartRecording(frames_per_second=1.0 / sample_period, set_visualizations_while_recording=True)
        self.time = 0.0
        self.num_trajectories = 0

    def add(self, q: np.ndarray, ghost_q: np.ndarray | None = None, realtime: bool = False) -> None:
        """Show and record one trajectory q: (T+1, n) rad, with the ghost following ghost_q
        (same shape; required when the recorder has a ghost; from a non-finite row on, a diverged
        prediction, the ghost stays at its last finite pose). realtime=True paces the live view."""
        q = np.asarray(q)
        if (ghost_q is None) != (self.ghost is None):
            raise ValueError("ghost_q must be given exactly when the recorder was made with ghost=True")
        if ghost_q is not None and np.shape(ghost_q) != q.shape:
            raise ValueError(f"ghost_q has shape {np.shape(ghost_q)}, q has {q.shape}")
        shown = None   # the ghost's last finite pose: a diverged prediction (NaN) stays where it left
        for k, q_k in enumerate(q):
            self.context.SetTime(self.time)
            self.plant.SetPositions(self.plant_context, self.robot, q_k)
            if ghost_q is not None:
                if np.all(np.isfinite(ghost_q[k])) or shown is None:
                    shown = ghost_q[k] if np.all(np.isfinite(ghost_q[k])) else q_k
                self.plant.SetPositions(self.plant_context, self.ghost, shown)
            self.diagram.ForcedPublish(self.context)
            self.time += self.sample_period
            if realtime:
                time.sleep(self.sample_period)
        self.time += self.pause
        self.num_trajectories += 1

    def publish(self) -> None:
        """End recording and send the animation to Meshcat (play it with its Animation controls)."""
        self.meshcat.StopRecording()
        self.meshcat.PublishRecording()

    def write_html(self, path) -> None:
        """Save Meshcat's self-contained HTML page (with the published recording) atomically."""
        write_text_atomic(path, html_marker() + "\n" + self.meshcat.StaticHtml())

    def finish(self, html=None, keep_serving: bool = False, what: str = "") -> None:
        """Publish the recording; write it to `html` if given (printing the path and `what` it
        shows); with keep_serving, keep Meshcat up for a person at a terminal until Ctrl+C."""
        self.publish()
        if html:
            self.write_html(html)
            print(f"wrote {line_text(html)}{f' ({what})' if what else ''}")
        if keep_serving:
            wait_for_interrupt(self.meshcat.web_url())


def _recolor(plant, scene_graph, instance, color: Rgba) -> None:
    """Give every illustration geometry of model `instance` the (translucent) `color`.

    Called before any visualizer exists; Drake warns about role changes regardless, so its log is
    quieted meanwhile.
    """
    logger = logging.getLogger("drake")
    previous = logger.level
    logger.setLevel(logging.ERROR)
    try:
        for body_index in plant.GetBodyIndices(instance):
            for geometry_id in plant.GetVisualGeometriesForBody(plant.get_body(body_index)):
                properties = IllustrationProperties()
                properties.AddProperty("phong", "diffuse", color)
                scene_graph.AssignRole(plant.get_source_id(), geometry_id, properties, RoleAssign.kReplace)
    finally:
        logger.setLevel(previous)


def wait_for_interrupt(url: str) -> None:
    """Keep a Meshcat server up for a person at a terminal until Ctrl+C; return at once otherwise."""
    import signal
    import sys
    if not sys.stdin.isatty():
        return
    print(f"Meshcat stays up at {url}: replay with its Animation controls; Ctrl+C to quit", file=sys.stderr)
    try:
        while True:
            time.sleep(1.0)
    except interrupts.Terminated:
        raise
    except KeyboardInterrupt:
        interrupts.forget(signal.SIGINT)   # Ctrl+C is how this wait ends: the command succeeded
        print("Meshcat closed", file=sys.stderr)
