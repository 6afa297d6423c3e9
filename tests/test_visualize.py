"""Meshcat recordings: the standalone HTML renders the robot and its ghost in headless Chromium."""
import shutil
import subprocess

import numpy as np
import pytest

from presets import UR10
from stdm_drake.robots.recorder import TrajectoryRecorder, load_visualization_config

CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--window-size=900,600", "--virtual-time-budget=8000"]


def chromium():
    path = shutil.which("chromium")
    if path is None:
        pytest.fail("Debian's chromium is needed for the rendering test: apt-get install chromium (.ci/run does)")
    return path


def rendered_pixels(recorder: TrajectoryRecorder, folder) -> np.ndarray:
    """The recorder's standalone HTML page as headless Chromium draws it: RGB floats in [0, 1] (600, 900, 3)."""
    import matplotlib.image
    recorder.publish()
    html, screenshot = folder / "run.html", folder / "shot.png"
    recorder.write_html(html)
    # (headless Chromium now and then hangs on a loaded machine, before or after writing its screenshot: a hung
    # browser is retried once with a fresh profile; the page and the pixels are checked as ever)
    for attempt in range(2):
        try:
            subprocess.run([chromium(), *CHROMIUM_FLAGS, f"--user-data-dir={folder / f'profile{attempt}'}",
                            f"--screenshot={screenshot}", html.as_uri()], check=True, capture_output=True, timeout=90)
            break
        except subprocess.TimeoutExpired:
            if screenshot.is_file() and screenshot.stat().st_size > 0:
                break
            if attempt:
                raise
    return matplotlib.image.imread(screenshot)[..., :3]


@pytest.mark.slow
def test_ghost_recording_renders_in_chromium(tmp_path):
    q = np.array([0.0, -1.6, 1.7, -1.7, -1.57, 0.0]) + np.linspace(0, 0.3, 31)[:, None] * [1, 0, 0, 0, 0, 0]
    recorder = TrajectoryRecorder(0.01, ghost=True, robot=UR10)
    recorder.add(q, q + [0.8, 0, 0, 0, 0, 0])
    pixels = rendered_pixels(recorder, tmp_path)
    red, green, blue = pixels[..., 0], pixels[..., 1], pixels[..., 2]
    assert pixels.std() > 0.02  # not a blank page
    robot_blue = np.count_nonzero((blue > red + 0.25) & (blue > green + 0.1))
    ghost_orange = np.count_nonzero((red > blue + 0.2) & (red > green + 0.05))
    assert robot_blue > 100, "the robot's blue links are not visible"
    assert ghost_orange > 100, "the translucent orange ghost is not visible"


def test_recorder_checks_its_inputs():
    recorder = TrajectoryRecorder(0.01, robot=UR10)
    with pytest.raises(ValueError, match="ghost_q must be given exactly"):
        recorder.add(np.zeros((3, 6)), np.zeros((3, 6)))
    with_ghost = TrajectoryRecorder(0.01, ghost=True, robot=UR10)
    with pytest.raises(ValueError, match="shape"):
        with_ghost.add(np.zeros((3, 6)), np.zeros((2, 6)))


def test_a_visualization_config_chooses_what_the_recording_shows(tmp_path):
    """Drake's VisualizationConfig from YAML: the default recording shows the illustration geometry
    only; `publish_proximity: true` adds the collision geometry."""
    (tmp_path / "collision.yaml").write_text("publish_proximity: true\ninitial_proximity_alpha: 0.3\n")
    config = load_visualization_config(tmp_path / "collision.yaml")
    assert config.publish_proximity and config.initial_proximity_alpha == 0.3 and not config.publish_inertia
    for visualization, shows_collision in ((None, False), (config, True)):
        recorder = TrajectoryRecorder(0.01, robot=UR10, visualization=visualization)
        recorder.add(np.zeros((3, UR10.num_joints)))
        assert recorder.meshcat.HasPath("/drake/illustration")
        assert recorder.meshcat.HasPath("/drake/proximity") == shows_collision
        assert not recorder.meshcat.HasPath("/drake/inertia")


def test_view_reports_open_loop_errors_at_steps_beside_the_physics_free_rollouts():
    """The view's line: errors at steps 1 / 10 / 50 and the last, beside "stays put" and "v unchanged",
    and the step from which the model is further off than staying put."""
    from stdm_drake.report import open_loop_error_line
    t = np.arange(201)[:, None] * 0.01
    q = np.hstack([0.5 * t, np.sin(t)])                      # (201, 2): v0 = (0.5, 1.0)
    predicted = q.copy()
    predicted[120:] += 10.0                                  # a model that holds for 119 steps, then diverges
    line = open_loop_error_line("DD", q, np.array([0.5, 1.0]), predicted, 0.01)
    assert line.startswith("open-loop RMS joint-angle error (rad) at steps 1 / 10 / 50 / 200: DD 0 / 0 / 0 / 10; ")
    stays = [np.sqrt(np.mean(q[k] ** 2)) for k in (1, 10, 50, 200)]        # q_0 = 0
    assert "stays put " + " / ".join(f"{value:.3g}" for value in stays) + ";" in line
    unchanged = [np.sqrt(np.mean((q[k] - k * 0.01 * np.array([0.5, 1.0])) ** 2)) for k in (1, 10, 50, 200)]
    assert "v unchanged " + " / ".join(f"{value:.3g}" for value in unchanged) + ";" in line
    assert line.endswith("DD further off than staying put from step 120 on")
    early = q.copy()
    early[1:3] += 10.0                                       # off at steps 1 and 2 only (the newcomer pass's case)
    assert open_loop_error_line("DD", q, np.array([0.5, 1.0]), early, 0.01).endswith(
        "DD further off than staying put first at step 1 (on 2 of 200 steps)")
    exact = open_loop_error_line("DD", q[:6], np.array([0.5, 1.0]), q[:6], 0.01)
    assert "at steps 1 / 5:" in exact and exact.endswith("DD closer than staying put throughout")
