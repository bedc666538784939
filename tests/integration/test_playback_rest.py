"""Playback's resting gap is a headline only when both sides rest in the scene (issue 54,
item 2): a body carried out of the scene (through the ground, metres away) leaves no gap at
all; an extension of the plan that does not come to rest is said so, and its gap (against
where it was at --rest-max) is kept as data but is no headline."""

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
    off), the gap is dropped exactly when a side leaves the scene, and caveated exactly when
    the extension did not come to rest."""
    task, sol = _swing(steps)
    r = playback(task, sol, PlaybackSettings(policy="ilqr", rest_max=rest_max))
    ob = r.metrics["object"]
    box = scene_box(task, sol.X[0])
    gone = [left_scene(box, np.asarray(r.hold.X_settle[-1, list(r.obj.coords)])),
            left_scene(box, np.asarray(r.hold.X[-1, list(r.obj.coords)]))]  # fmt: skip
    if rest_max < 0.1:  # 20 ms: too short for the extension to see 0.2 s of rest
        assert not r.hold.rested_plan
    # out of the scene: no gap at all; an extension still moving: the gap is kept as data,
    # with its caveat, and is no headline
    assert (ob["resting_gap"] is None) == any(gone)
    assert (r.metrics["resting_gap_m"] is None) == any(gone)
    dropped = [w for w in r.metrics["warnings"] if w.startswith("no resting gap")]
    caveat = [w for w in r.metrics["warnings"] if w.startswith("resting gap not the measure")]
    assert bool(dropped) == any(gone)
    if any(gone):
        assert ob["no_resting_gap"] in dropped[0] and "out of the scene" in dropped[0]
    assert bool(caveat) == (not any(gone) and not r.hold.rested_plan)
    if caveat:
        assert ob["resting_gap_caveat"] in caveat[0] and "did not come to rest" in caveat[0]
