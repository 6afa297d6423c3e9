"""Meshcat views of UR-10 trajectories, live and as standalone HTML recordings.

Recordings replay stored joint angles in a visualization-only diagram (plant + scene graph +
MeshcatVisualizer), so what is shown never feeds back into the simulation that produced it.
"""
import time

import numpy as np
from pydrake.geometry import Meshcat, MeshcatVisualizer, MeshcatVisualizerParams, Role
from pydrake.systems.framework import DiagramBuilder

from stdm_drake.files import write_text_atomic
from stdm_drake.robot import PlantConfig, make_plant


class TrajectoryRecorder:
    """Appends joint trajectories q (T+1, 6) rad, sampled every `sample_period` s, to one
    Meshcat animation that plays them one after another (with `pause` s of rest between)."""

    def __init__(self, sample_period: float, meshcat: Meshcat | None = None, pause: float = 0.25):
        self.meshcat = meshcat or Meshcat()
        self.sample_period = sample_period
        self.pause = pause
        builder = DiagramBuilder()
        self.plant, scene_graph = make_plant(PlantConfig(time_step=0.0), builder=builder)
        self.visualizer = MeshcatVisualizer.AddToBuilder(
            builder, scene_graph, self.meshcat,
            MeshcatVisualizerParams(role=Role.kIllustration, publish_period=sample_period))
        self.diagram = builder.Build()
        self.context = self.diagram.CreateDefaultContext()
        self.plant_context = self.plant.GetMyContextFromRoot(self.context)
        self.visualizer_context = self.visualizer.GetMyContextFromRoot(self.context)
        self.visualizer.StartRecording(set_transforms_while_recording=True)
        self.time = 0.0
        self.num_trajectories = 0

    def add(self, q: np.ndarray, realtime: bool = False) -> None:
        """Show and record one trajectory q: (T+1, 6) rad; realtime=True paces the live view."""
        for q_k in np.asarray(q):
            self.context.SetTime(self.time)
            self.plant.SetPositions(self.plant_context, q_k)
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
        pass
