"""problem.check: warnings and reports of the task check on a rollout."""

from __future__ import annotations

import numpy as np
import pytest

from hydroilqr import Task


def _check(task, **kw):
    from hydroilqr.studies.check import check_task

    return check_task(task, **kw)


def test_check_warns_about_a_blow_up_many_polygons_and_no_pairs():
    spin = Task.load("cartpole-wall", ["num_steps=30", "initial_state.pole_angular_velocity=300"])
    f = _check(spin, rollout_steps=10)
    assert f["rollout_steps"] == 10  # at most rollout_steps of the 30
    X = spin.dynamics.rollout(spin.x0, spin.initial_guess(30)[:10])
    assert f["max_speed"] == pytest.approx(np.max(np.abs(X[:, spin.dynamics.nq :])))
    assert any("(> 100)" in w for w in f["warnings"]), f["warnings"]  # |v| ~ 380 rad/s

    fine = Task.load(
        "kinova-forward",
        ["initial_state.ball_position=[0.4, 0, 0.09]", "ball_collision.resolution_hint=0.005"],
    )
    f = _check(fine, rollout_steps=5)
    assert f["contact_faces"] == sum(c["faces"] for c in f["contacts"]) > 500
    assert any("contact polygons at x0" in w for w in f["warnings"]), f["warnings"]
    d = [p["distance"] for p in f["pairs"] if p["distance"] is not None]
    assert len(d) > 3 and d == sorted(d)  # closest first

    pendulum = Task.from_dict(
        {"models": [{"file": "package://drake/examples/pendulum/Pendulum.urdf"}],
         "num_steps": 5, "cost": {"R": 0.1}}
    )  # fmt: skip
    f = _check(pendulum)
    assert f["geometries"] and not f["pairs"]
    assert any("no candidate collision pairs" in w for w in f["warnings"])


def test_check_reports_a_deep_overlap_when_the_rollout_is_fast():
    """10 mm into the floor (below the 20 mm always reported) with the ball moving at 6 m/s."""
    task = Task.load(
        "kinova-forward",
        ["initial_state.ball_position=[0.4, 0, 0.09]", "initial_state.ball_velocity=[6, 0, 0]"],
    )
    f = _check(task, rollout_steps=5)
    assert f["max_speed"] > 5.0
    assert any("overlap by 10 mm" in w and "reaches |v|" in w for w in f["warnings"]), f["warnings"]


def test_check_names_the_contact_model_of_each_pair():
    def models(overrides):
        task = Task.load("cartpole-wall", ["num_steps=5", *overrides])
        f = _check(task, rollout_steps=2)
        return [p["model"] for p in f["pairs"]], f["warnings"]

    assert models([])[0] == ["hydroelastic"]  # compliant tip, rigid wall
    assert models(["plant.contact_model=point"])[0] == ["point"]
    rigid = ["tip.compliance=rigid", "tip.resolution_hint=0.01"]
    assert models(rigid)[0] == ["point (fallback)"]  # rigid-rigid: no hydroelastic surface
    # A point-contact pair of a sphere (the tip) and a box: AutoDiff handles it, no warning
    # (pairs without a sphere: tests/unit/test_check_report.py).
    post = (
        "scene=[{name: wall, shape: box, size: [0.1, 1.0, 2.0], xyz: [-0.5, 0, 0], "
        "compliance: rigid}, {name: post, shape: box, size: [0.1, 0.1, 0.1], xyz: [2, 0, 0], "
        "compliance: compliant, hydroelastic_modulus: 1.0e+6}]"
    )
    kinds, warnings = models([*rigid, post, "solver.derivatives=autodiff"])
    assert sorted(kinds) == ["hydroelastic", "point (fallback)"]
    assert not any("point-contact pair" in w for w in warnings)
    # A scene object's no_contact_with removes its pairs (the wall here: none left).
    filtered = post.replace("compliance: rigid}", "compliance: rigid, no_contact_with: [tip]}")
    kinds, _ = models([*rigid, filtered])
    assert kinds == ["hydroelastic"]  # only the post's pair with the tip


def test_no_contact_warning_knows_when_the_cost_brings_the_arm_to_the_ball():
    """kinova-forward's guess holds the arm 17 mm above the ball (no contact), but its control
    cost pulls the gravity-compensating torques down and the arm sags onto the ball: no
    no-contact alarm (issue 54, item 8). Without a control cost nothing pulls: the alarm."""
    f = _check(Task.load("kinova-forward"))
    assert not [w for w in f["warnings"] if "no gradient reaches it" in w], f["warnings"]
    pull = f["cost_pull"]
    assert pull and pull["scale"] in (0.5, 0.0)
    assert all("ball_collision" in p for p in pull["pairs"]) and pull["pairs"]
    f = _check(Task.load("kinova-forward", ["cost.R=0"]))
    assert f["cost_pull"] is None
    assert [w for w in f["warnings"] if "no gradient reaches it" in w], f["warnings"]
