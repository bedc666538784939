"""hopper-forward: a planar hopper hops forward from a still, standing start; its guess is a
path of leg configurations (a tracking rollout), not controls; smoke size."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from hydroilqr import Task, solve
from hydroilqr.metrics import compute
from hydroilqr.metrics.goals import evaluate
from hydroilqr.problem.guess import PositionGuess


def test_the_start_stands_still_and_the_guess_is_positions_whose_rollout_hops():
    task = Task.load("hopper-forward")
    nq = task.dynamics.nq
    assert not np.any(task.x0[nq:])  # zero velocity
    pairs = task.dynamics.contact_pairs(task.x0)
    assert pairs and {pairs[0][0], pairs[0][2]} == {"foot", "ground"}  # standing on its foot
    assert isinstance(task.config.initial_guess, PositionGuess)
    U = task.initial_guess(task.steps)
    X = task.dynamics.rollout(task.x0, U)
    t = np.arange(task.steps + 1) * task.config.plant.time_step
    metrics = compute(task, SimpleNamespace(X=X, U=U, t=t))
    assert metrics["flight_phases"] >= 1  # the rollout of the guess leaves the ground
    goal = evaluate(task.config.goal, metrics)
    assert [c["metric"] for c in goal["checks"]] == [
        "base_forward_m",
        "flight_phases",
        "longest_flight_s",
        "base_lowest_m",
    ]


def test_smoke_solve_runs_and_reports_the_flight_metrics():
    task = Task.load("hopper-forward", smoke=True)
    sol = solve(task)
    assert sol.status != "diverged"
    metrics = compute(task, sol)
    for key in (
        "flight_phases",
        "flight_time_s",
        "longest_flight_s",
        "base_forward_m",
        "base_lowest_m",
    ):
        assert key in metrics
    assert metrics["base_displacement_m"][1] == 0.0  # planar: no sideways travel
