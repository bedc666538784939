"""kinova-reach: a position term (cost.terms) brings the hand to a Cartesian target; smoke size."""

from __future__ import annotations

import numpy as np
import pytest

from hydroilqr import Task, solve
from hydroilqr.metrics import compute, validate_task
from hydroilqr.metrics.goals import evaluate
from hydroilqr.problem.errors import ConfigError


def test_kinova_reach_smoke_solve_reduces_the_hand_error_and_reports_its_goal_metric():
    task = Task.load("kinova-reach", smoke=True)
    validate_task(task)  # names, metrics and the goal's metric (term_error.hand) before a solve
    sol = solve(task)
    assert sol.costs[-1] < sol.costs[0]
    metrics = compute(task, sol)
    assert set(metrics["term_error"]) == {"hand"}
    assert "terms.hand" in metrics["cost_terms"]
    # the error is the distance of the hand point from the target at the last state
    final = np.asarray(metrics["term_final"]["hand"])
    target = np.asarray(task.config.cost.terms[0].target)
    assert metrics["term_error"]["hand"] == pytest.approx(np.linalg.norm(final - target))
    start = task.cost.task_terms.report(np.tile(task.x0, (sol.X.shape[0], 1)))["hand"]["error"]
    assert metrics["term_error"]["hand"] < start
    assert evaluate(task.config.goal, metrics)["checks"][0]["metric"] == "term_error.hand"


def test_the_terms_metric_needs_terms():
    with pytest.raises(ConfigError, match="metrics: the terms metric needs cost.terms"):
        validate_task(Task.load("cartpole-wall", ["metrics=[default, terms]", "num_steps=5"]))


def test_check_lists_the_terms_on_the_initial_guess(capsys):
    from hydroilqr import cli

    assert cli.main(["check", "kinova-reach", "--smoke"]) == 0
    out = capsys.readouterr().out
    # the hand starts 0.59 m from its target (the guess holds the arm still)
    assert "cost term hand (position): |r| = 0.593" in out
