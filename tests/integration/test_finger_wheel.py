"""finger-wheel: a finger turns a free wheel from a still start through an approach stage
(a distance term in a continuation stage, off in the task as written); smoke size."""

from __future__ import annotations

import numpy as np

from hydroilqr import Task, solve
from hydroilqr.metrics import compute, validate_task
from hydroilqr.metrics.goals import evaluate


def test_the_guess_touches_nothing_and_only_the_stage_has_the_approach_term():
    task = Task.load("finger-wheel", smoke=True)
    validate_task(task)
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


def test_no_progress_without_contact_names_the_approach_stage_and_check_says_the_same():
    from hydroilqr import explain
    from hydroilqr.studies.check import check_task

    # without its approach stage the still start touches nothing: no gradient, no progress
    bare = Task.load("finger-wheel", ["continuation=[]"], smoke=True)
    sol = solve(bare)
    assert sol.status == "no_progress"
    text = explain(sol, bare)
    assert "approach term (a distance term in cost.terms" in text
    assert "in a first continuation stage" in text and "an initial guess that moves" in text
    assert "closer start alone does not help" in text
    (warning,) = [w for w in check_task(bare, rollout_steps=10)["warnings"] if "touches" in w]
    assert "in a first continuation stage" in warning  # check gives solve's remedy
    # with the stage, check says the approach term is there for it
    task = Task.load("finger-wheel", smoke=True)
    (warning,) = [w for w in check_task(task, rollout_steps=10)["warnings"] if "touches" in w]
    assert "the approach term approach (cost.terms) should bring them into contact" in warning
    # a stage too weak to reach the rim: solve says to strengthen the approach term
    weak_stage = "continuation=[{cost.terms.approach.weight: 1.0e-6}]"
    weak = Task.load("finger-wheel", [weak_stage], smoke=True)
    sol = solve(weak)
    assert sol.status == "no_progress"
    assert "the approach term approach did not bring them into contact" in explain(sol, weak)


def test_the_guide_shows_the_task_file_as_it_is():
    import re
    from pathlib import Path

    import yaml

    from hydroilqr.problem.files import task_file

    guide = (Path(__file__).resolve().parents[2] / "docs" / "guide.md").read_text()
    section = guide[guide.index("## From no contact to contact") :]
    block = re.search(r"```yaml\n(.*?)```", section, re.S).group(1)
    assert yaml.safe_load(block) == yaml.safe_load(task_file("finger-wheel").read_text())


def test_a_clearance_distance_term_is_not_an_approach_term():
    from hydroilqr.solver.explain import no_contact_remedy

    staged = Task.load("finger-wheel", smoke=True)
    assert no_contact_remedy(staged).startswith("the approach term approach (cost.terms)")
    clearance = [
        "continuation=[]",
        "cost.terms.approach.weight=1.0",
        "cost.terms.approach.max=null",
        "cost.terms.approach.min=0.01",
    ]
    task = Task.load("finger-wheel", clearance, smoke=True)
    assert no_contact_remedy(task, None, "wheel").startswith("add an approach term")


def test_check_shows_the_approach_terms_weight_in_the_task_and_in_its_stage(capsys):
    from hydroilqr import cli

    assert cli.main(["check", "finger-wheel", "--smoke"]) == 0
    out = capsys.readouterr().out
    assert "cost term approach (distance)" in out
    assert "(weight 0; continuation[0]: weight 100000)" in out
