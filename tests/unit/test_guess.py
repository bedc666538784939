"""Position guesses (``initial_guess: {waypoints | target}``, model/guess.py): the tracking
rollout on the task's own plant follows the path, its controls replay to the same states,
and bad paths are one-line errors naming the key."""

from __future__ import annotations

import numpy as np
import pytest

from hydroilqr import Task, cli
from hydroilqr.model.guess import position_guess
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.guess import PositionGuess

# The finger of finger-wheel moves in a horizontal plane (no gravity work); this path brushes
# the wheel at the end.
WAYPOINTS = [
    "initial_guess={waypoints: [{t: 0.5, finger_shoulder: 0.4}, {t: 1.0, finger_elbow: 1.0}]}",
    "num_steps=30",
]


def test_the_tracking_rollout_follows_the_waypoints_and_replays_to_its_states():
    task = Task.load("finger-wheel", WAYPOINTS)
    assert isinstance(task.config.initial_guess, PositionGuess)
    out = position_guess(task, task.steps)
    dt = task.config.plant.time_step
    shoulder = task.dynamics.layout.block("finger_shoulder").coords[0]
    elbow = task.dynamics.layout.block("finger_elbow").coords[0]
    # the reference: from the start (0, pi/2) to shoulder 0.4 at 0.5 s, elbow 1.0 at 1.0 s
    assert out.Q_ref[round(0.5 / dt)] == pytest.approx([0.4, np.pi / 2])
    assert out.Q_ref[-1] == pytest.approx([0.4, 1.0])  # held after the last waypoint
    # it follows: an error closes by half per step, so it lags by about a step's motion
    assert out.tracking_error().max() < 0.1
    assert out.X[-1, shoulder] == pytest.approx(0.4, abs=0.01)
    assert out.X[-1, elbow] == pytest.approx(1.0, abs=0.01)
    assert np.all(np.abs(out.U) <= task.dynamics.effort_limits + 1e-12)
    # the guess is the rollout's controls: replayed open loop they give the same states
    U = task.initial_guess(task.steps)
    assert np.array_equal(U, out.U)
    assert np.allclose(task.dynamics.rollout(task.x0, U), out.X, atol=1e-9)


def test_a_later_window_follows_the_same_path_from_its_start_time():
    """A receding-horizon window (or an MPC tail) asks for the guess from a state at step k:
    from the rollout's own state at k it continues the same controls."""
    task = Task.load("finger-wheel", WAYPOINTS)
    whole = position_guess(task, task.steps)
    tail = task.initial_guess(5, whole.X[10], start=10)
    assert np.allclose(tail, whole.U[10:15], atol=1e-9)


def test_a_target_and_a_period():
    task = Task.load("finger-wheel", ["initial_guess={target: {finger_shoulder: 0.3}}"])
    out = position_guess(task, task.steps)
    assert out.Q_ref[-1, 0] == pytest.approx(0.3)  # reached at the end, linearly
    assert out.Q_ref[task.steps // 2, 0] == pytest.approx(0.15)
    periodic = Task.load(
        "finger-wheel",
        ["initial_guess={waypoints: [{t: 0.2, finger_shoulder: 0.3}], period: 0.4}"],
    )
    ref = position_guess(periodic, periodic.steps).Q_ref[:, 0]
    dt = periodic.config.plant.time_step
    assert ref[round(0.4 / dt)] == pytest.approx(0.0)  # back to the start value
    assert ref[round(0.6 / dt)] == pytest.approx(0.3)  # and again


@pytest.mark.parametrize(
    "guess, words",
    [
        ("{waypoints: [{t: 0.5, finger_shoulder: 1}], target: {finger_elbow: 1}}", "or target"),
        ("{}", "give waypoints"),
        ("{waypoints: [{t: 0.5, finger_shoulder: 1}, {t: 0.5, finger_elbow: 1}]}", "after"),
        ("{waypoints: [{finger_shoulder: 1}]}", "waypoints[0].t"),
        ("{waypoints: [{t: 0.5}]}", "names no block"),
        ("{waypoints: [{t: 0.5, finger_shoulder: 1}], period: 0.5}", "before period"),
        ("{target: {t: 1, finger_shoulder: 1}}", "has no time"),
    ],
)
def test_bad_paths_are_refused_when_loaded(guess, words):
    with pytest.raises(ConfigError, match="initial_guess") as e:
        Task.load("finger-wheel", [f"initial_guess={guess}"])
    assert words in str(e.value)


@pytest.mark.parametrize(
    "name, words", [("nonsense", "unknown state block"), ("finger_elbow.v", "positions")]
)
def test_bad_names_are_refused_when_the_plant_is_built(name, words):
    task = Task.load("finger-wheel", [f"initial_guess={{waypoints: [{{t: 0.5, {name}: 1}}]}}"])
    with pytest.raises(ConfigError, match=r"initial_guess\.waypoints\[0\]") as e:
        task.validate()
    assert words in str(e.value)


def test_check_shows_the_tracking_rollout(capsys):
    args = ["check", "finger-wheel"] + [a for w in WAYPOINTS for a in ("--set", w)]
    assert cli.main(args) == 0
    out = capsys.readouterr().out
    assert "initial guess (positions: 2 waypoints)" in out
    assert "position guess: tracking rollout, largest |q - q_ref|: finger_shoulder" in out
    # the rest of the state: the wheel, which this path's finger pushes
    assert "the rest of the configuration (first -> last state): wheel_axle 0 -> " in out
    assert "largest control / effort limit: finger_shoulder" in out
