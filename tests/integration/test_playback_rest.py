"""Playback's resting gap is a headline only when both sides rest in the scene (issue 54,
item 2): an extension of the plan that does not come to rest, or a body carried out of the
scene (through the ground, kilometres away), is reported as such, with no gap against it."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from hydroilqr import Task, solve
from hydroilqr.control.playback import PlaybackSettings, playback
from hydroilqr.model.scene import left_scene, scene_box
from tests.integration.test_model_names import NUDGE


def test_left_scene_is_beyond_the_scene_box_by_its_diagonal():
    box = (np.array([-2.0, -2.0, -3.0]), np.array([2.0, 2.0, 0.0]))  # diagonal 6.4 m
    assert not left_scene(box, np.array([0.3, 0.2, -3.1]))
    assert not left_scene(box, np.array([0.0, 0.0, -9.0]))  # 6 m below
    assert left_scene(box, np.array([8.3, 0.7, -55.0]))


def _swing(steps: int):
    """The acrobot's elbow driven at a constant -10 N·m: the lower link sweeps the cube along;
    the plan is the guess itself (no iteration)."""
    spec = copy.deepcopy(NUDGE)
    spec["num_steps"] = steps
    task = Task.from_dict(spec)
    sol = solve(task, U0=np.full((steps, 1), -10.0), settings={"max_iterations": 0})
    return task, sol


@pytest.mark.parametrize(("steps", "rest_max"), [(60, 3.0), (60, 0.02), (100, 3.0)])
def test_no_resting_gap_against_an_unsettled_or_departed_object(steps, rest_max):
    """Whichever way each case goes (the truth's contact decides whether the cube is flung
    off), the resting gap is reported exactly when both sides rest inside the scene."""
    task, sol = _swing(steps)
    r = playback(task, sol, PlaybackSettings(policy="ilqr", rest_max=rest_max))
    ob = r.metrics["object"]
    box = scene_box(task, sol.X[0])
    gone = [left_scene(box, np.asarray(r.hold.X_settle[-1, list(r.obj.coords)])),
            left_scene(box, np.asarray(r.hold.X[-1, list(r.obj.coords)]))]  # fmt: skip
    unusable = any(gone) or not r.hold.rested_plan
    if rest_max < 0.1:  # 20 ms: too short for the extension to see 0.2 s of rest
        assert not r.hold.rested_plan
    assert (ob["resting_gap"] is None) == unusable
    assert (r.metrics["resting_gap_m"] is None) == unusable
    warned = [w for w in r.metrics["warnings"] if w.startswith("no resting gap")]
    assert bool(warned) == unusable
    if unusable:
        assert ob["no_resting_gap"] in warned[0]
        assert ("out of the scene" in warned[0]) == any(gone)
