"""Self-contained Meshcat replays (HTML) of trajectories, with hydroelastic contact shown.

``write_replay(task, X, t, path)`` re-plays the states through a diagram with
MeshcatVisualizer and ContactVisualizer, records an animation and writes ``meshcat.StaticHtml()``
to ``path``: one file that opens in any browser, no server needed. Contact forces (arrows)
animate in the recording; contact surfaces are drawn by the ContactVisualizer as they are at the
frame published last (a Meshcat recording animates transforms, not geometry).
"""

from __future__ import annotations

import logging
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from pydrake.geometry import Meshcat, MeshcatParams

from hydroilqr.io.files import atomic_write
from hydroilqr.model.plant import build_diagram
from hydroilqr.model.scene import view_box

_MESHCAT = None


def meshcat_instance():
    """One Meshcat server per process (each instance holds a port), started on first use: a
    replay file is written through one (Drake's Meshcat has no serverless mode; its
    ``StaticHtml`` is a method of the server), and ``solve --view`` serves one. Its "Meshcat
    listening for connections at ..." INFO line is held back (the live view prints its own
    URL; a replay file needs none); Drake's warnings and errors still show."""
    global _MESHCAT
    if _MESHCAT is None:
        with _drake_info_held_back():
            _MESHCAT = Meshcat(MeshcatParams())
    return _MESHCAT


@contextmanager
def _drake_info_held_back():
    """Drake's logger (Python's ``drake`` logger, which pydrake keeps in step with its C++
    spdlog level) at WARNING or above for the block, then as it was."""
    logger = logging.getLogger("drake")
    level = logger.level
    logger.setLevel(max(logging.WARNING, logger.getEffectiveLevel()))
    try:
        yield
    finally:
        logger.setLevel(level)


def camera_for(task):
    """A camera pose (position, target), each [3]: the task file's ``metric_params.camera``,
    else aimed at the centre of the bodies at the start (and the scene objects smaller than
    a ground, ``model.scene.view_box``), from the front (-y) and a little above, far enough
    back to frame them."""
    cam = task.config.metric_params.get("camera")
    if cam:
        return np.asarray(cam["position"], float), np.asarray(cam["target"], float)
    low, high = view_box(task, task.x0)
    target = (low + high) / 2
    distance = max(1.5, 1.8 * float(np.linalg.norm(high - low)))
    direction = np.array([0.0, -1.0, 0.35]) / np.linalg.norm([0.0, -1.0, 0.35])
    return target + distance * direction, target


def camera_note(task) -> str:
    """A line saying where the replay's camera looks when the task does not set it ('' when
    it does)."""
    if task.config.metric_params.get("camera"):
        return ""
    pos, target = camera_for(task)
    fmt = ", ".join
    return (
        f"replay camera: aimed at [{fmt(f'{v:.3g}' for v in target)}] (the bodies at the "
        f"start) from [{fmt(f'{v:.3g}' for v in pos)}]; metric_params.camera: "
        "{position: [x, y, z], target: [x, y, z]} sets it (hydroilqr replay RUN rewrites a "
        "run's replay.html)"
    )


def write_replay(
    task, trajectories, t: np.ndarray, path: str | Path, fps: float = 30.0, inputs=None
) -> Path:
    """trajectories: X [T, nx] or a list of them (drawn in turn). t: [T] seconds.
    inputs: U [T-1, nu] (or a list, one per trajectory; None: zero input), the actuation each
    frame's contact forces are computed with (a discrete step's forces depend on u_k)."""
    if isinstance(trajectories, np.ndarray):
        trajectories = [trajectories]
    if inputs is None or isinstance(inputs, np.ndarray):
        inputs = [inputs] * len(trajectories)
    meshcat = meshcat_instance()
    meshcat.Delete()
    meshcat.DeleteRecording()
    scene = build_diagram(task.config, meshcat=meshcat)
    diagram, plant = scene.diagram, scene.plant
    context = diagram.CreateDefaultContext()
    plant_context = plant.GetMyMutableContextFromRoot(context)
    actuation = diagram.get_input_port(scene.actuation_port)
    zero = np.zeros(plant.num_actuated_dofs())
    pos, target = camera_for(task)
    meshcat.SetCameraPose(pos, target)
    vis = scene.visualizers[0]
    vis.StartRecording(False)
    T = t[-1] - t[0] if len(t) > 1 else 1.0
    frames = max(2, int(T * fps) + 1)
    offset = 0.0
    for X, U in zip(trajectories, inputs):  # one after another, with a short pause between
        for tf in np.linspace(t[0], t[-1], frames):
            # the state nearest the frame's time (not the next one)
            k = int(np.clip(np.searchsorted(t, tf), 0, len(t) - 1))
            if k > 0 and tf - t[k - 1] < t[k] - tf:
                k -= 1
            u = zero if U is None or len(U) == 0 else U[min(k, len(U) - 1)]
            actuation.FixValue(context, np.asarray(u, dtype=float))
            context.SetTime(float(tf - t[0] + offset))
            plant.SetPositionsAndVelocities(plant_context, X[k])
            try:
                diagram.ForcedPublish(context)
            except RuntimeError:  # a blown-up state (a failed run): show what came before
                break
        offset += T + 0.5
    vis.StopRecording()
    vis.PublishRecording()
    html = meshcat.StaticHtml()
    path = Path(path)
    return atomic_write(path, html)  # a full disk leaves no torn replay
