"""model.state: the state layout, quaternion differences and their Jacobian."""

from __future__ import annotations

import numpy as np
import pytest

from hydroilqr import Task
from hydroilqr.model.state import StateLayout
from hydroilqr.problem.errors import ConfigError


def _quat_layout():
    from hydroilqr.model.state import Block, StateLayout

    return StateLayout(
        7,
        6,
        [
            Block("b.orientation", (0, 1, 2, 3), (0, 1, 2), "quaternion"),
            Block("b.position", (4, 5, 6), (3, 4, 5)),
            Block("b.angular_velocity", (7, 8, 9), (6, 7, 8)),
            Block("b.velocity", (10, 11, 12), (9, 10, 11)),
        ],
        [],
    )


def _rz(a):
    return np.array([np.cos(a / 2), 0.0, 0.0, np.sin(a / 2)])


def test_quaternion_difference_is_relative_and_ignores_the_sign_of_the_quaternion():
    layout = _quat_layout()
    pad = np.zeros(9)
    a, b = 0.3, 1.1
    x, ref = np.r_[_rz(a + b), pad], np.r_[_rz(b), pad]
    # Rz(a + b) against Rz(b): a rotation of a about z, whatever the reference.
    np.testing.assert_allclose(layout.diff(x, ref)[:3], [0, 0, 2 * np.sin(a / 2)], atol=1e-12)
    # -q is the same rotation as q: no error, and the same error against another reference.
    flipped = np.r_[-_rz(b), pad]
    np.testing.assert_allclose(layout.diff(flipped, ref)[:3], 0.0, atol=1e-12)
    np.testing.assert_allclose(layout.diff(-x, ref), layout.diff(x, ref), atol=1e-12)
    # The Jacobian is that of the difference there too (sign branch included).
    J = layout.diff_jacobian((-x)[None], ref[None])[0]
    h = 1e-7
    Jn = np.stack(
        [
            (layout.diff(-x + h * e, ref) - layout.diff(-x - h * e, ref)) / (2 * h)
            for e in np.eye(13)
        ],
        axis=1,
    )
    np.testing.assert_allclose(J, Jn, atol=1e-6)


def test_state_difference_names_wrong_shapes():
    layout = _quat_layout()
    x = np.r_[_rz(0.3), np.zeros(9)]
    assert layout.diff(np.stack([x, x]), x).shape == (2, 12)  # one reference for all rows
    with pytest.raises(ValueError, match=r"X must have shape \[\.\.\., 13\] \(nx\), got \(5,\)"):
        layout.diff(x[:5], x)
    with pytest.raises(ValueError, match=r"Xref must have shape \[\.\.\., 13\]"):
        layout.diff(x, x[:-1])
    with pytest.raises(ValueError, match=r"Xref \(3, 13\) does not broadcast"):
        layout.diff(np.stack([x, x]), np.stack([x, x, x]))
    with pytest.raises(ValueError, match=r"X must have shape \[T, 13\]"):
        layout.diff_jacobian(x, x)


def test_layout_quaternion_values_are_unit_and_checked():

    layout = _quat_layout()
    x = layout.normalize(np.r_[2.0, 0, 0, 0, np.ones(9)])
    np.testing.assert_allclose(x[:4], [1, 0, 0, 0])
    np.testing.assert_allclose(layout.default_nominal()[:4], [1, 0, 0, 0])
    base = layout.default_nominal()
    v = layout.coordinate_vector({"b.orientation": [0, 0, 0, 3.0]}, "initial_state", base)
    np.testing.assert_allclose(v[:4], [0, 0, 0, 1])
    for bad, msg in (([0, 0, 0, 0], "non-zero"), (1.0, "4 values")):
        with pytest.raises(ConfigError, match=msg):
            layout.coordinate_vector({"b.orientation": bad}, "initial_state", base)
    with pytest.raises(ConfigError, match="cannot be grouped"):
        layout.add_groups({"pose": ["b.orientation", "b.position"]})


def test_a_given_x0_has_its_quaternions_normalized_like_the_task_files():

    task = Task.load("kinova-forward", smoke=True)
    lay = task.dynamics.layout
    (qb,) = lay.quaternions
    x = task.x0.copy()
    x[list(qb.coords)] = [2.0, 0.0, 0.0, 0.0]
    x0 = task.checked_state(x)
    np.testing.assert_array_equal(x0[list(qb.coords)], [1.0, 0.0, 0.0, 0.0])
    assert x[qb.coords[0]] == 2.0  # the caller's array is not changed
    np.testing.assert_array_equal(task.problem(x).x0, x0)  # the same rule for problem()
    x[list(qb.coords)] = 0.0
    with pytest.raises(ValueError, match="non-zero"):
        task.checked_state(x)
    with pytest.raises(ValueError, match="shape"):
        task.checked_state(x[:-1])


def test_quaternion_difference_jacobian():
    from hydroilqr.model.state import Block

    layout = StateLayout(
        7,
        6,
        [
            Block("b.orientation", (0, 1, 2, 3), (0, 1, 2), "quaternion"),
            Block("b.position", (4, 5, 6), (3, 4, 5)),
            Block("b.angular_velocity", (7, 8, 9), (6, 7, 8)),
            Block("b.velocity", (10, 11, 12), (9, 10, 11)),
        ],
        [],
    )
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.standard_normal(4), rng.standard_normal(3), rng.standard_normal(6)])
    x[:4] /= np.linalg.norm(x[:4])
    ref = layout.normalize(x + 0.1 * rng.standard_normal(13))
    J = layout.diff_jacobian(x[None], ref[None])[0]
    h = 1e-7
    Jn = np.stack(
        [(layout.diff(x + h * e, ref) - layout.diff(x - h * e, ref)) / (2 * h) for e in np.eye(13)],
        axis=1,
    )
    np.testing.assert_allclose(J, Jn, atol=1e-6)
    # A rotation of angle a about z gives an error of (0, 0, ~a).
    a = 0.2
    q = np.array([np.cos(a / 2), 0, 0, np.sin(a / 2)])
    xq = np.concatenate([q, np.zeros(9)])
    ident = np.concatenate([[1.0, 0, 0, 0], np.zeros(9)])
    np.testing.assert_allclose(layout.diff(xq, ident)[:3], [0, 0, 2 * np.sin(a / 2)])
