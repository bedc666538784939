"""Issue 53, 16: gravity switched off for one model (an arm whose own controller compensates
it) while it acts on the others."""

from __future__ import annotations

import numpy as np

from hydroilqr import Task

# The ball 0.5 m above the ground, away from the arm: it falls freely for the first steps.
LIFTED = "initial_state.ball_position=[0.6, 0.4, 0.5]"


def _free_fall(gravity: bool) -> tuple[np.ndarray, np.ndarray, float]:
    overrides = [f"models.0.gravity={str(gravity).lower()}", LIFTED]
    dyn = Task.load("kinova-forward", overrides, smoke=True).dynamics
    x0 = dyn.initial_state()
    X = dyn.rollout(x0, np.zeros((10, dyn.nu)))
    return X, dyn.gravity_compensation(x0), 10 * dyn.dt


def test_gravity_off_for_the_arm_leaves_it_on_the_ball():
    X_on, comp_on, t = _free_fall(True)
    X_off, comp_off, _ = _free_fall(False)
    arm = slice(0, 7)  # gen3's seven joints come first
    assert np.abs(X_on[-1, arm] - X_on[0, arm]).max() > 1e-3  # unpowered, it sags
    assert np.abs(X_off[-1, arm] - X_off[0, arm]).max() < 1e-9  # no gravity: it stays
    assert np.abs(comp_on).max() > 1.0 and np.abs(comp_off).max() < 1e-9
    # the ball (free body after the arm: quaternion, then xyz) falls as under g = 9.81 m/s²
    # in both; a discrete step's fall is within a step of the continuous one
    z = 7 + 4 + 2
    for X in (X_on, X_off):
        fall = X[0, z] - X[-1, z]
        assert abs(fall - 0.5 * 9.81 * t**2) < 9.81 * t * 0.01 + 1e-6, fall
