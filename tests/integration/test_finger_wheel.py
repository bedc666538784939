"""finger-wheel: a finger turns a free wheel from a still start through an approach stage
(a distance term in a continuation stage, off in the task as written); smoke size."""

from __future__ import annotations

import numpy as np

from hydroilqr import Task, solve
from hydroilqr.metrics import compute
from hydroilqr.metrics.goals import evaluate


def test_the_guess_touches_nothing_and_only_the_stage_has_the_approach_term():
    task = Task.load("finger-wheel", smoke=True)
    task.validate()
    assert not np.any(task.initial_guess(task.steps))  # zero torque: a still start
    X = task.dynamics.rollout(task.x0, task.initial_guess(task.steps))
    assert np.allclose(X, task.x0)  # nothing moves (the plane is horizontal)
    report = task.cost.task_terms.report(X)["approach"]
    assert report["final"] > 0.02  # m: the tip starts clear of the rim
    assert task.cost.task_terms.breakdown(X)["terms.approach"] == 0.0  # weight 0 as written
    (stage,) = task.config.continuation
    assert stage == {"cost.terms.approach.weight": 1.0e5}
    staged = task.with_overrides(stage)
    assert staged.cost.task_terms.breakdown(X)["terms.approach"] > 0.0


def test_smoke_solve_makes_contact_and_turns_the_wheel():
    task = Task.load("finger-wheel", smoke=True)
    sol = solve(task)
    stages = sol.extra["continuation"]
    assert [s["overrides"] for s in stages] == [{"cost.terms.approach.weight": 1.0e5}, {}]
    # the approach stage brings the tip to the rim, so contact appears and the wheel turns
    metrics = compute(task, sol)
    assert metrics["contacts"] and metrics["contacts"][0]["bodies"] == ["wheel", "finger_link_2"]
    wheel = task.dynamics.layout.block("wheel_axle").coords[0]
    assert sol.X[-1, wheel] > 1e-3  # towards +2 rad
    assert evaluate(task.config.goal, metrics)["checks"][0]["metric"] == "final_error.wheel_axle"
