"""metrics.common: the default metrics."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from hydroilqr import Task


def test_default_metrics_final_error_is_against_the_nominal_at_the_final_time():
    from hydroilqr.metrics import default_metrics

    task = Task.load("cheetah-trot-1.0", ["cost.Q={position: 1.0}"], smoke=True)
    dyn, lay = task.dynamics, task.dynamics.layout
    pos = list(lay.primitives["body.position"].coords)
    X = np.tile(task.x0, (3, 1))
    X[-1, pos[0]] = 0.3  # the final state (the one before it stays at x = 0)
    sol = SimpleNamespace(t=np.array([0.0, 0.5, 1.0]), X=X, U=np.zeros((2, dyn.nu)))
    m = default_metrics(task, sol)
    # nominal position at t = 1 s: x advanced by 1.0 m/s * 1 s, height 0.29166
    want = np.linalg.norm([0.3 - 1.0, 0.0, task.x0[pos[2]] - 0.29166])
    assert m["final_error"]["position"] == pytest.approx(want, rel=1e-6)
    assert set(m["final_error"]) == set(task.config.cost.Qf)  # every Qf block, not Q's
    assert m["steps"] == 2
    faces = [[p[4] for p in dyn.contact_pairs(x)] for x in X]  # four feet on the ground
    assert m["max_contact_faces"] == max(map(sum, faces)) > max(map(max, faces))  # all pairs
