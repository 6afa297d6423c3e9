"""Meshcat views of UR-10 trajectories, live and as standalone HTML recordings.

Recordings replay stored joint angles in a visualization-only diagram (plant + scene graph +
MeshcatVisualizer), so what is shown never feeds back into the simulation that produced it.
With `ghost=True` a second, translucent UR-10 shows another trajectory beside the robot, e.g. a
learned model's open-loop prediction from the same initial state and actions, or an MPC reference.
"""
import logging
import time

import numpy as np
from pydrake.geometry import (IllustrationProperties, Meshcat, MeshcatVisualizer, MeshcatVisualizerParams, Rgba,
                              Role, RoleAssign)
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.systems.framework import DiagramBuilder

from stdm_drake.files import write_text_atomic
from stdm_drake.robot import add_ur10

GHOST_COLOR = Rgba(1.0, 0.55, 0.1, 0.35)  # translucent orange


class TrajectoryRecorder:
    """Appends joint trajectories q (T+1, 6) rad, sampled every `sample_period` s, to one
    Meshcat animation that plays them one after another (with `pause` s of rest between)."""

    def __init__(self, sample_period: float, meshcat: Meshcat | None = None, pause: float = 0.25,
                 ghost: bool = False):
        self.meshcat = meshcat or Meshcat()
        self.sample_period = sample_period
        self.pause = pause
        builder = DiagramBuilder()
        self.plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
        self.robot = add_ur10(self.plant)
        self.ghost = add_ur10(self.plant, model_name_prefix="ghost") if ghost else None
        self.plant.Finalize()
        if ghost:
            _recolor(self.plant, scene_graph, self.ghost, GHOST_COLOR)
        self.visualizer = MeshcatVisualizer.AddToBuilder(
            builder, scene_graph, self.meshcat,
            MeshcatVisualizerParams(role=Role.kIllustration, publish_period=sample_period))
        self.diagram = builder.Build()
        self.context = self.diagram.CreateDefaultContext()
        self.plant_context = self.plant.GetMyContextFromRoot(self.context)
        self.visualizer_context = self.visualizer.GetMyContextFromRoot(self.context)
        self.visualizer.ForcedPublish(self.visualizer_context)  # creates the geometry in Meshcat
        self.meshcat.SetCameraPose(camera_in_world=[1.6, -1.9, 1.1], target_in_world=[0.4, 0.0, 0.45])
        self.visualizer.StartRecording(set_transforms_while_recording=True)
        self.time = 0.0
        self.num_trajectories = 0

    def add(self, q: np.ndarray, ghost_q: np.ndarray | None = None, realtime: bool = False) -> None:
        """Show and record one trajectory q: (T+1, 6) rad, with the ghost following ghost_q
        (same shape; required when the recorder has a ghost). realtime=True paces the live view."""
        q = np.asarray(q)
        if (ghost_q is None) != (self.ghost is None):
            raise ValueError("ghost_q must be given exactly when the recorder was made with ghost=True")
        if ghost_q is not None and np.shape(ghost_q) != q.shape:
            raise ValueError(f"ghost_q has shape {np.shape(ghost_q)}, q has {q.shape}")
        for k, q_k in enumerate(q):
            self.context.SetTime(self.time)
            self.plant.SetPositions(self.plant_context, self.robot, q_k)
            if ghost_q is not None:
                self.plant.SetPositions(self.plant_context, self.ghost, ghost_q[k])
            self.visualizer.ForcedPublish(self.visualizer_context)
            self.time += self.sample_period
            if realtime:
                time.sleep(self.sample_period)
        self.time += self.pause
        self.num_trajectories += 1

    def publish(self) -> None:
        """End recording and send the animation to Meshcat (play it with its Animation controls)."""
        self.visualizer.StopRecording()
        self.visualizer.PublishRecording()

    def write_html(self, path) -> None:
        """Save Meshcat's self-contained HTML page (with the published recording) atomically."""
        write_text_atomic(path, self.meshcat.StaticHtml())

    def finish(self, html=None, keep_serving: bool = False, what: str = "") -> None:
        """Publish the recording; write it to `html` if given (printing the path and `what` it
        shows); with keep_serving, keep Meshcat up for a person at a terminal until Ctrl+C."""
        self.publish()
        if html:
            self.write_html(html)
            print(f"wrote {html}{f' ({what})' if what else ''}")
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
    import sys
    if not sys.stdin.isatty():
        return
    print(f"Meshcat stays up at {url}: replay with its Animation controls; Ctrl+C to quit", file=sys.stderr)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        print("Meshcat closed", file=sys.stderr)


# ---- `stdm-drake view`: the robot and a learned model's open-loop prediction -------------------

def add_arguments(parser) -> None:
    import pathlib
    parser.add_argument("checkpoint", type=pathlib.Path, help="trained model (checkpoint.pt)")
    parser.add_argument("dataset", type=pathlib.Path, help="dataset with the trajectories to replay")
    parser.add_argument("--trajectories", type=int, default=3,
                        help="how many test trajectories (the checkpoint's test split when it was trained on "
                             "this dataset, else the dataset's last ones; default 3)")
    parser.add_argument("--index", type=int, action="append", help="replay these trajectory indices instead")
    parser.add_argument("--html", type=pathlib.Path, help="save the recording as a standalone HTML file")
    parser.add_argument("--meshcat", action="store_true", help="play live in Meshcat (prints the URL)")


def run(args) -> int:
    from stdm_drake.dataset import load_dataset
    from stdm_drake.errors import InputError
    from stdm_drake.learned_system import LearnedModel
    from stdm_drake.predict import rollout
    if not (args.html or args.meshcat):
        raise InputError("nothing to show: give --html FILE and/or --meshcat")
    model = LearnedModel(args.checkpoint)
    dataset = load_dataset(args.dataset)
    if abs(model.sample_period - dataset.sample_period) > 1e-12:
        raise InputError(f"model steps at {model.sample_period} s, the dataset at {dataset.sample_period} s")
    if args.index:
        indices = args.index
    else:
        split = model.checkpoint.metadata.get("split")
        same = model.checkpoint.metadata.get("dataset_sha256") == dataset.sha256
        pool = list(split["test"]) if split and same else list(range(dataset.num_trajectories))[::-1]
        indices = pool[:args.trajectories]
    recorder = TrajectoryRecorder(dataset.sample_period, ghost=True)
    if args.meshcat:
        print(f"Meshcat: {recorder.meshcat.web_url()}")
    for index in indices:
        if not 0 <= index < dataset.num_trajectories:
            raise InputError(f"trajectory index {index} out of range 0..{dataset.num_trajectories - 1}")
        traj = dataset.trajectory(index)
        x0 = np.concatenate([traj["q"][0], traj["v"][0]])
        predicted = rollout(model.engine, x0, traj["tau"]).mean
        ghost_q = np.vstack([traj["q"][:1], predicted[:, :6]])
        error = np.sqrt(np.mean((ghost_q - traj["q"]) ** 2))
        print(f"trajectory {index}: open-loop RMS joint-angle error over {len(traj['tau'])} steps {error:.4g} rad")
        recorder.add(traj["q_true"], ghost_q, realtime=args.meshcat)
    recorder.finish(args.html, keep_serving=args.meshcat,
                    what=f"robot: recorded; translucent orange: {model.name} open-loop prediction")
    return 0
