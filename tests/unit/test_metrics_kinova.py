"""metrics.kinova on a synthetic ball path."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from hydroilqr import Task


def test_kinova_metrics_on_a_synthetic_ball_path_and_contacts(monkeypatch):
    """kinova-up weights only the ball's final z (Qf); its running Q here weighs every axis."""
    from hydroilqr.metrics import kinova as mk
    from hydroilqr.metrics import objects

    task = Task.load("kinova-up", ["cost.Q.ball_position=[1, 1, 1]"], smoke=True)
    lay = task.dynamics.layout
    pos = list(lay.primitives["ball.position"].coords)
    z_nom = task.cost.x_nom[pos[2]]
    T = 6
    X = np.tile(task.x0, (T, 1))
    p0 = X[0, pos].copy()
    path = [[0, 0, 0], [0, 0, 0.05], [0.01, 0, 0.30], [0.02, 0.01, 0.15], [0.03, 0.0, 0.12]]
    for k, d in enumerate(path, start=1):
        X[k, pos] = p0 + d
    X[-2, pos] = p0 + [0.5, 0.5, 0.5]  # the second-to-last state is far off: not the final one
    X[-1, pos] = p0 + [0.04, 0.02, 0.10]  # final: 0.1 m up, target 0.2 m up
    X[-2, pos[2]] = p0[2] + 0.25
    pairs = {
        0: [("base_link_collision", "base_link", "ball_collision", "ball", 50)],  # x0: not counted
        1: [
            ("ball_collision", "ball", "forearm_link_collision", "forearm_link", 3),
            ("base_link_collision", "base_link", "ball_collision", "ball", 4),
            ("ball_collision", "ball", "ground", "world", 20),  # the ground: not a link
        ],
        2: [("ball_collision", "ball", "forearm_link_collision", "forearm_link", 2)],
        3: [("half_arm_2_link_collision", "half_arm_2_link", "ground", "world", 6)],
    }
    keys = {X[k].tobytes(): k for k in range(T)}
    monkeypatch.setattr(objects, "contact_pairs", lambda dyn, x: pairs.get(keys[x.tobytes()], []))
    sol = SimpleNamespace(t=0.01 * np.arange(T), X=X)
    m = mk.kinova_metrics(task, sol)
    np.testing.assert_allclose(m["ball_displacement_m"], [0.04, 0.02, 0.10], atol=1e-12)
    np.testing.assert_allclose(m["target_error_xyz_m"], [0.0, 0.0, p0[2] + 0.10 - z_nom])
    assert m["target_error_m"] == pytest.approx(abs(p0[2] + 0.10 - z_nom)) and z_nom > p0[2] + 0.1
    assert m["max_ball_height_gain_m"] == pytest.approx(0.30)
    assert m["contact_links"] == ["base_link", "forearm_link"]  # plant order, world excluded
    assert m["contact_steps"] == {"base_link": 1, "forearm_link": 2}
    assert m["max_arm_ball_faces"] == 7  # 3 + 4 at one step (x0 and the ground excluded)
