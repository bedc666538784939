"""metrics.cartpole on synthetic runs."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from hydroilqr import Task


def _wall_run(task, carts, final_angle=np.pi):
    """States with the pole upright (the tip right above the cart, x = cart) at these carts."""
    lay = task.dynamics.layout
    X = np.tile(task.x0, (len(carts), 1))
    X[:, lay.block("pole_angle").coords[0]] = np.pi
    X[-1, lay.block("pole_angle").coords[0]] = final_angle
    X[:, lay.block("cart_position").coords[0]] = carts
    return SimpleNamespace(t=0.01 * np.arange(len(carts)), X=X)


def test_cartpole_wall_tunnelling_overlap_and_contact_steps():
    """Wall: x in [-0.55, -0.45]; tip: a 5 cm sphere starting on the +x side."""
    from hydroilqr.metrics.cartpole import cartpole_wall

    task = Task.load("cartpole-wall", ["num_steps=5", "metric_params.contact_pair=[pole, wall]"])
    # Through the wall: the tip centre ends a step beyond the far face (x < -0.55), then back.
    through = cartpole_wall(task, _wall_run(task, [0.0, -0.3, -0.43, -0.62, -0.3]))
    assert through["tunnelled"] is True
    assert through["max_overlap_m"] == pytest.approx(0.03, abs=1e-6)
    # Deep into the wall (centre 2 cm inside, at the second state) but not through it.
    deep = cartpole_wall(task, _wall_run(task, [-0.3, -0.47, -0.3, -0.1, -0.2], np.pi - 0.1))
    assert deep["tunnelled"] is False
    assert deep["min_signed_distance_m"] == pytest.approx(-0.07, abs=1e-6)
    assert deep["max_overlap_m"] == pytest.approx(0.07, abs=1e-6)
    assert deep["wall_contact_steps"] == 1  # the pair named by body (pole) still counts
    assert deep["final_angle_error_rad"] == pytest.approx(0.1)
