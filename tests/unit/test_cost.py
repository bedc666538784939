"""model.cost: quadratization, blocks and weights, the cost breakdown, cost settings."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hydroilqr import Task
from hydroilqr.model.state import StateLayout
from hydroilqr.problem.errors import ConfigError
from tests.conftest import edit, write_case


def _reference_quadratization(cost, X, U, t0):
    """The cost derivatives from the definitions, densely: l_x = 2 Jrᵀ W r, l_xx = 2 Jrᵀ W Jr
    (r = x ⊖ x_nom, Jr = ∂r/∂x from diff_jacobian), l_u = 2 R u, l_uu = 2 R."""
    N = U.shape[0]
    Xn = cost.targets(N, t0)
    r = cost.layout.diff(X, Xn)
    Jr = cost.layout.diff_jacobian(X, Xn)
    W = np.array([cost.q] * N + [cost.qf])
    lx = np.stack([2 * Jr[k].T @ (W[k] * r[k]) for k in range(N + 1)])
    lxx = np.stack([2 * Jr[k].T @ np.diag(W[k]) @ Jr[k] for k in range(N + 1)])
    return lx, lxx, 2 * U * cost.r, np.stack([2 * np.diag(cost.r)] * N)


def test_a_scalar_nominal_rate_applies_to_every_coordinate_of_its_block():
    task = Task.load("cheetah-trot-1.0", ["cost.nominal_rate.position=0.5"], smoke=True)
    pos = list(task.dynamics.layout.block("position").coords)
    x0 = task.cost.nominal(np.array([0.0]))[0, pos]
    np.testing.assert_allclose(task.cost.nominal(np.array([2.0]))[0, pos] - x0, [1.0, 1.0, 1.0])


def test_breakdown_adds_up_to_the_cost_with_nominal_time_horizon_end():
    task = Task.load("cheetah-trot-1.0", ["cost.nominal_time=horizon_end"], smoke=True)
    N, t0 = 4, 0.3
    X = np.tile(task.x0, (N + 1, 1))
    U = np.zeros((N, task.dynamics.nu))
    terms = task.cost.breakdown(X, U, t0)
    assert sum(terms.values()) == pytest.approx(task.cost.total(X, U, t0), rel=1e-12)


def test_overlapping_blocks_each_coordinate_is_reported_under_the_block_whose_weight_applies():
    task = Task.load(
        "cartpole-wall",
        [
            "num_steps=10",
            "blocks.positions=[cart_slider, pole_pin]",
            "cost.Q={positions: 0.5, pole_angle: 2.0}",  # pole_angle (later) sets pole_pin's
        ],
    )
    lay = task.dynamics.layout
    X = task.dynamics.rollout(task.x0, np.full((10, 1), 3.0))
    U = np.full((10, 1), 3.0)
    R = lay.diff(X, task.cost.targets(10, 0.0))
    pole, cart = lay.block("pole_angle").tangent[0], lay.block("cart_position").tangent[0]
    terms = task.cost.breakdown(X, U)
    dt = task.config.plant.time_step  # running_cost_dt
    assert terms["Q.pole_angle"] == pytest.approx(2.0 * dt * np.sum(R[:10, pole] ** 2))
    assert terms["Q.positions"] == pytest.approx(0.5 * dt * np.sum(R[:10, cart] ** 2))


def test_cost_settings_that_cannot_apply_are_config_errors(tmp_path):
    from hydroilqr.solver.solution import Solution

    with pytest.raises(ConfigError, match="cost.reference_blocks: given without cost.reference"):
        _ = Task.load("cartpole-wall", ["cost.reference_blocks=[pole_angle]"]).cost
    with pytest.raises(ConfigError, match="cost.nominal_rate.orientation: not supported"):
        _ = Task.load("cheetah-trot-1.0", ["cost.nominal_rate.orientation=0.1"], smoke=True).cost
    N = 3
    X = np.zeros((N + 1, 4))
    X[2, 1] = np.nan  # a blown-up reference run
    Solution(
        X, np.zeros((N, 1)), np.zeros(0), np.zeros(0), 0.01 * np.arange(N + 1), np.ones(1),
        [], {}, False, "", "",
    ).save(tmp_path / "solution.npz")  # fmt: skip
    with pytest.raises(ConfigError, match="NaN or infinite"):
        _ = Task.load("cartpole-wall", [f"cost.reference={tmp_path}"]).cost


@pytest.mark.parametrize("quaternion", [False, True])
def test_quadratize_equals_the_dense_reference(quaternion):
    """Both paths of QuadraticCost.quadratize (the coordinate permutation when there are no
    quaternions, the Jacobian einsum otherwise) against the dense formulas."""
    from hydroilqr.model.cost import QuadraticCost
    from hydroilqr.model.state import Block

    if quaternion:
        blocks = [
            Block("b.orientation", (0, 1, 2, 3), (0, 1, 2), "quaternion"),
            Block("b.position", (4, 5, 6), (3, 4, 5)),
            Block("b.angular_velocity", (7, 8, 9), (6, 7, 8)),
            Block("b.velocity", (10, 11, 12), (9, 10, 11)),
        ]
        layout = StateLayout(7, 6, blocks, ["a", "b"])
    else:  # tangent order differs from coordinate order by 3-cycles: the permutation matters
        blocks = [
            Block("p", (2, 0, 1), (0, 1, 2)),
            Block("p.v", (3, 4, 5), (4, 5, 3)),
        ]
        layout = StateLayout(3, 3, blocks, ["a", "b"])
    rng = np.random.default_rng(7)
    nx, nt, N = layout.nx, 2 * layout.nv, 6
    X = rng.standard_normal((N + 1, nx))
    if quaternion:
        X = layout.normalize(X)
    U = rng.standard_normal((N, 2))
    x_nom = layout.normalize(rng.standard_normal(nx)) if quaternion else rng.standard_normal(nx)
    rate = np.zeros(nx)
    rate[4 if quaternion else 0] = 0.3  # a moving nominal on a euclidean coordinate
    cost = QuadraticCost(
        layout, rng.uniform(0.1, 2, nt), rng.uniform(1, 5, nt), [0.2, 0.7], x_nom, rate, 0.1
    )
    quad = cost.quadratize(X, U, t0=0.4)
    for got, want in zip(
        (quad.lx, quad.lxx, quad.lu, quad.luu), _reference_quadratization(cost, X, U, 0.4)
    ):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


def test_cost_reference_quaternions_are_renormalized():
    from hydroilqr.model.cost import QuadraticCost

    task = Task.load("cheetah-trot-1.0", smoke=True)
    layout = task.dynamics.layout
    X = np.tile(task.x0, (2, 1))
    q = list(layout.quaternions[0].coords)
    a = 0.8
    X[1, q] = [np.cos(a / 2), 0, 0, np.sin(a / 2)]
    cost = task.cost
    assert isinstance(cost, QuadraticCost)
    cost.set_reference(np.array([0.0, 1.0]), X, [])
    mid = cost.nominal(np.array([0.5]))[0, q]
    assert abs(np.linalg.norm(mid) - 1.0) < 1e-12


def test_cost_terms_add_up_to_the_cost_when_blocks_overlap():
    task = Task.load(
        "cartpole-wall",
        [
            "num_steps=10",
            "blocks.positions=[cart_slider, pole_pin]",
            "cost.Q={positions: 0.5, pole_angle: 2.0}",
        ],
    )
    X = task.dynamics.rollout(task.x0, np.full((10, 1), 3.0))
    U = np.full((10, 1), 3.0)
    terms = task.cost.breakdown(X, U)
    assert sum(terms.values()) == pytest.approx(task.cost.total(X, U), rel=1e-12)


def test_scalar_weight_still_applies_to_a_whole_block():
    from hydroilqr.model.task import Task

    path_spec = edit(initial_state={"angles": 0.05})
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        task = Task.load(str(write_case(Path(d), path_spec)))
        np.testing.assert_allclose(task.x0[:2], [0.05, 0.05])
