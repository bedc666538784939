"""Where a task's scene lies: the box of its bodies and scene objects (playback's test of an
object gone out of the scene) and the box a replay's camera frames by default."""

from __future__ import annotations

import numpy as np
from pydrake.multibody.tree import BodyIndex

#: Scene objects larger than this (m, their largest extent) are left out of the camera's box:
#: a ground or a table top would push the view far from the robot.
VIEW_OBJECT_MAX = 2.0


def body_origins(task, x0: np.ndarray) -> np.ndarray:
    """[B, 3] the origins of every body but the world at state x0."""
    dyn = task.dynamics
    plant, ctx = dyn.plant, dyn.plant_context
    plant.SetPositionsAndVelocities(ctx, x0)
    return np.array(
        [
            np.asarray(plant.EvalBodyPoseInWorld(ctx, plant.get_body(BodyIndex(i))).translation())
            for i in range(1, plant.num_bodies())
        ]
        or [np.zeros(3)]
    )


def _half_extent(o) -> np.ndarray:
    if o.shape == "box":
        return np.asarray(o.size, float) / 2
    if o.shape == "sphere":
        return np.full(3, float(o.radius))
    if o.shape == "cylinder":
        return np.array([o.radius, o.radius, o.length / 2], float)
    return np.zeros(3)  # a half space: its origin


def scene_box(task, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) corners [3] of the scene: every body's origin at x0 and every scene object
    (its pose ± its half extent; a half space counts its origin)."""
    points = list(body_origins(task, x0))
    for o in task.config.scene:
        half = _half_extent(o)
        points += [np.asarray(o.xyz, float) - half, np.asarray(o.xyz, float) + half]
    P = np.array(points)
    return P.min(axis=0), P.max(axis=0)


def view_box(task, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) corners [3] a replay frames: the bodies' origins at x0 and the scene
    objects no larger than VIEW_OBJECT_MAX (not the ground)."""
    points = list(body_origins(task, x0))
    for o in task.config.scene:
        half = _half_extent(o)
        if o.shape != "halfspace" and 2 * float(np.max(half)) <= VIEW_OBJECT_MAX:
            points += [np.asarray(o.xyz, float) - half, np.asarray(o.xyz, float) + half]
    P = np.array(points)
    return P.min(axis=0), P.max(axis=0)


def left_scene(box: tuple[np.ndarray, np.ndarray], p: np.ndarray) -> bool:
    """``p`` [3] lies farther outside the scene ``box`` than the box's diagonal (at least
    1 m): a body that fell through the ground or flew off."""
    low, high = box
    outside = np.linalg.norm(np.maximum(0.0, np.maximum(low - p, p - high)))
    return bool(outside > max(1.0, float(np.linalg.norm(high - low))))
