"""model.terms: task-space cost terms (cost.terms): derivatives against central finite
differences, windows and ramps, the cost breakdown, and configuration errors."""

from __future__ import annotations

import re

import numpy as np
import pytest

from hydroilqr import Task
from hydroilqr.model.activations import Bounds, Identity, SoftMin, Sum, Target
from hydroilqr.model.residuals import RESIDUALS
from hydroilqr.model.terms import Term, softmin
from hydroilqr.model.windows import Ramp, Terminal, Window
from hydroilqr.problem.errors import ConfigError
from tests.conftest import edit, write_case

# Every term type on the Kinova arm and its ball (a quaternion floating body), with the
# options that change the residual: per-axis weights, a moving target, a relative frame,
# relative_to_start, chosen axes, one-sided bounds, a tilted plane, a ramp, a window, a soft
# minimum over the window, a slip's sphere radius (its contact point moves with the body's
# rotation) and its clearance.
# Cases of each registered term type (model/residuals.py's RESIDUALS): a new type adds its
# cases here, and the tests below (the finite-difference Jacobian test among them) run them.
CASES = {
    "position": [
        {"name": "reach", "type": "position", "body": "end_effector_link", "point": [0, 0, 0.12],
         "target": [0.5, 0.1, 0.3], "target_velocity": [0.1, 0, 0], "weight": [1.0, 2.0, 3.0]},
        {"name": "rel", "type": "position", "body": "gripper", "relative_to": "ball",
         "axes": ["x", "z"], "relative_to_start": True, "target": [0.02, 0, 0.01],
         "weight": 5.0, "after": 0.01},
    ],
    "orientation": [
        {"name": "turn", "type": "orientation", "body": "gripper", "target": [0.1, 0.2, 0.3],
         "weight": [1.0, 2.0, 3.0]},
        {"name": "roll", "type": "orientation", "body": "ball", "relative_to": "gripper",
         "relative_to_start": True, "target": [0.9, 0.1, 0.2, 0.1], "axes": ["x", "y"],
         "weight": 0.5},
    ],
    "velocity": [
        {"name": "slide", "type": "velocity", "body": "bracelet_link",
         "point": [0.01, 0.02, 0.03], "axes": ["x", "z"], "weight": 0.3},
        {"name": "ballv", "type": "velocity", "body": "ball", "point": [0.03, 0.02, 0.05],
         "relative_to": "gripper", "target": [0.1, 0, 0], "weight": 0.2},
    ],
    "height": [
        {"name": "lift", "type": "height", "body": "ball", "min": 0.5, "weight": 10.0,
         "terminal": True},
        {"name": "tilt", "type": "height", "body": "gripper", "target": 0.2,
         "normal": [0.2, 0.1, 1.0], "ramp": [0.5, 2.0]},
        {"name": "over", "type": "height", "body": "gripper", "point": [0.01, 0.0, 0.02],
         "above_body": "ball", "above_point": [0.0, 0.03, 0.0], "min": 0.5, "weight": 4.0},
    ],
    "distance": [
        {"name": "near", "type": "distance", "geometry_a": "gripper", "geometry_b": "ball",
         "target": 0.0, "weight": 7.0},
        {"name": "apart", "type": "distance", "geometry_a": "ball",
         "geometry_b": "forearm_link", "max": 0.01, "weight": 2.0, "until": 0.015},
        {"name": "touch", "type": "distance", "geometry_a": "gripper", "geometry_b": "ball",
         "max": 0.0, "weight": 3.0, "softmin": 1.0e-4},
    ],
    "joint_limits": [{"name": "limits", "type": "joint_limits", "margin": 1.0, "weight": 3.0}],
    "slip": [
        {"name": "ballslip", "type": "slip", "body": "ball", "radius": 0.05, "clearance": 0.5,
         "weight": 3.0},
        {"name": "linkslip", "type": "slip", "body": "bracelet_link",
         "point": [0.01, 0.02, 0.03], "radius": 0.02, "clearance": 1.0, "weight": 0.4,
         "after": 0.01},
    ],
}  # fmt: skip
TERMS = [term for cases in CASES.values() for term in cases]

N = 3


@pytest.fixture(scope="module")
def kinova():
    """A 3-step Kinova task with every term, and states with the arm moved, velocities, and
    the ball turned and lifted (so that every term is active): (task, X, U)."""
    task = Task.load("kinova-forward", smoke=True, overrides={"cost.terms": TERMS, "num_steps": N})
    lay = task.dynamics.layout
    rng = np.random.default_rng(3)
    X = np.tile(task.x0, (N + 1, 1))
    X[:, :7] += 0.1 * rng.standard_normal((N + 1, 7))
    X[:, 14:] += 0.5 * rng.standard_normal((N + 1, 13))
    X[:, list(lay.primitives["ball.orientation"].coords)] = rng.standard_normal((N + 1, 4))
    X[:, list(lay.primitives["ball.position"].coords)] += [0.0, 0.0, 0.05]
    return task, lay.normalize(X), np.zeros((N, 7))


def _fd(f, X, h=1e-6):
    """Central differences of f(X) -> array over every entry of X: [*f.shape, *X.shape]."""
    f0 = np.asarray(f(X))
    out = np.zeros(f0.shape + X.shape)
    for idx in np.ndindex(X.shape):
        Xp, Xm = X.copy(), X.copy()
        Xp[idx] += h
        Xm[idx] -= h
        out[(...,) + idx] = (np.asarray(f(Xp)) - np.asarray(f(Xm))) / (2 * h)
    return out


def assert_jacobians_match_central_differences(terms, X, kind: str) -> None:
    """J = ∂r/∂x of each term of type ``kind`` where its weight is positive, against central
    differences (h = 1e-6) of its residual over every coordinate of the state, quaternion
    ones included: within 1e-8 (measured: 1e-10). ``terms``: a TaskSpaceTerms."""
    active, factor, R, Js, _ = terms._evaluate(X, 0.0, True)
    checked = 0
    for i, term in enumerate(terms.terms):
        if term.cfg.type != kind:
            continue
        assert active[i].any(), term.name
        for k in np.flatnonzero(factor[i] > 0):

            def residual(x, i=i, k=k):
                Xk = X.copy()
                Xk[k] = x
                return terms._evaluate(Xk, 0.0, False)[2][i][k]

            J_fd = _fd(residual, X[k])
            np.testing.assert_allclose(Js[i][k], J_fd, atol=1e-8, err_msg=term.name)
            checked += 1
    assert checked, f"no {kind} term with a positive weight factor"


def test_every_registered_term_type_has_cases():
    """Each type in the registry is exercised here: a new type adds its cases to CASES."""
    assert set(RESIDUALS) <= set(CASES)


@pytest.mark.parametrize("kind", sorted(RESIDUALS))
def test_residual_jacobian_matches_central_differences(kinova, kind):
    """Over the registry: every term type's Jacobian (position, orientation, velocity incl.
    its q-dependence, height, distance, joint limits, slip incl. its height weight) against
    central differences of its residual, with its cases' options."""
    task, X, _ = kinova
    assert_jacobians_match_central_differences(task.cost.task_terms, X, kind)


def test_term_gradient_and_gauss_newton_hessian(kinova):
    """l_x of the whole cost (quadratic + terms) against central differences of the total
    cost (1e-7 relative); the terms' l_xx is the Gauss-Newton 2 Jᵀ W J (symmetric, PSD)."""
    task, X, U = kinova
    cost = task.cost
    quad = cost.quadratize(X, U)
    lx_fd = _fd(lambda Y: cost.total(Y, U), X)
    # (quaternion blocks of the quadratic part are Gauss-Newton in the tangent space, exact
    # in l_x: compare everything)
    np.testing.assert_allclose(quad.lx, lx_fd, rtol=1e-7, atol=1e-7 * np.abs(lx_fd).max())
    _, lxx = cost.task_terms.quadratize(X)
    np.testing.assert_allclose(lxx, np.swapaxes(lxx, 1, 2), atol=1e-12)
    assert np.linalg.eigvalsh(lxx).min() > -1e-9 * np.abs(lxx).max()


def test_windows_ramps_and_breakdown(kinova):
    task, X, U = kinova
    terms = task.cost.task_terms
    dt = task.config.plant.time_step
    active, factor = terms.windows(N, 0.0)
    names = [t.name for t in terms.terms]
    # running terms: steps 0..N-1 (times 0, .01, .02), times dt (running_cost_dt)
    np.testing.assert_array_equal(active[names.index("reach")], [1, 1, 1, 0])
    np.testing.assert_array_equal(active[names.index("rel")], [0, 1, 1, 0])  # after 0.01
    np.testing.assert_array_equal(active[names.index("apart")], [1, 1, 0, 0])  # until .015
    np.testing.assert_array_equal(active[names.index("lift")], [0, 0, 0, 1])  # terminal
    assert factor[names.index("lift"), N] == 1.0  # terminal: no dt
    # ramp 0.5 -> 2 over [0, the task's end (N dt)]
    np.testing.assert_allclose(factor[names.index("tilt")], dt * np.array([0.5, 1.0, 1.5, 0.0]))
    # receding windows: the task's times (t0) decide
    np.testing.assert_array_equal(terms.windows(N, 0.01)[0][names.index("apart")], [1, 0, 0, 0])
    br = task.cost.breakdown(X, U)
    assert sum(br.values()) == pytest.approx(task.cost.total(X, U), rel=1e-12)
    assert set(names) == {k.split(".", 1)[1] for k in br if k.startswith("terms.")}
    rep = terms.report(X)
    assert rep["lift"]["step"] == N and rep["lift"]["error"] == pytest.approx(
        max(0.0, 0.5 - rep["lift"]["final"])
    )
    assert rep["near"]["error"] == pytest.approx(abs(rep["near"]["final"]))
    # states sampled on another grid (an MPC run's): their own times decide the windows
    assert terms.report(X, 0.0, times=[0.0, 0.02, 0.04, 0.06])["apart"]["step"] == 0
    assert rep["apart"]["step"] == 1


def test_position_term_targets_relative_to_start_and_moving(kinova):
    task, _, _ = kinova
    terms = task.cost.task_terms
    plant = task.dynamics.plant
    ctx = plant.CreateDefaultContext()
    plant.SetPositionsAndVelocities(ctx, task.x0)
    p0 = plant.CalcPointsPositions(
        ctx, plant.GetFrameByName("gripper"), np.zeros(3), plant.GetFrameByName("ball")
    ).ravel()
    rel = next(t for t in terms.terms if t.name == "rel")
    np.testing.assert_allclose(rel.residual.target0, p0 + [0.02, 0, 0.01])
    X = np.tile(task.x0, (N + 1, 1))
    rep = terms.report(X, 0.0)
    # reach: target [0.5, 0.1, 0.3] moving at 0.1 m/s in x; last running step at t = 0.02
    err = (np.array(rep["reach"]["final"]) - [0.502, 0.1, 0.3]) * [1.0, 1.0, 1.0]
    assert rep["reach"]["error"] == pytest.approx(np.linalg.norm(err))


def test_a_cost_without_terms_is_unchanged():
    task = Task.load("cartpole-wall", ["num_steps=5"])
    assert task.cost.task_terms is None


def test_terms_on_the_acrobot_and_overrides_by_name(tmp_path):
    """A model without collision geometry, a term given with --set by name, and terms as the
    only cost (Q, Qf, R all zero)."""
    spec = edit(
        cost={
            "R": 0.0,
            "terms": [
                {
                    "name": "tip",
                    "type": "position",
                    "body": "lower_link",
                    "point": [0, 0, -2],
                    "target": [0, 0, 3],
                    "terminal": True,
                },
            ],
        }  # fmt: skip
    )
    task = Task.load(str(write_case(tmp_path, spec)), ["cost.terms.tip.weight=4"])
    assert task.config.cost.terms[0].weight == 4
    X = np.tile(task.x0, (6, 1))
    assert task.cost.total(X, np.zeros((5, 1))) > 0


@pytest.mark.parametrize(
    ("term", "message"),
    [
        ({"type": "position", "body": "lower_lnk", "target": [0, 0, 0]},
         "cost.terms.t.body: unknown body or frame (did you mean 'lower_link'?"),
        ({"type": "position", "body": "lower_link", "relative_to": "nowhere",
          "target": [0, 0, 0]}, "cost.terms.t.relative_to: unknown body or frame"),
        ({"type": "distance", "geometry_a": "lower_link", "geometry_b": "nothing", "target": 0},
         "cost.terms.t.geometry_b: no collision geometry or body named 'nothing'"),
    ],
)  # fmt: skip
def test_unknown_model_names_are_one_line_config_errors(tmp_path, term, message):
    spec = edit(cost__terms=[{"name": "t", **term}])
    task = Task.load(str(write_case(tmp_path, spec)))
    with pytest.raises(ConfigError, match=re.escape(message)) as e:
        _ = task.cost
    assert "\n" not in str(e.value)


@pytest.mark.parametrize(
    ("term", "message"),
    [
        ({"name": "t", "type": "pose", "body": "b"}, "cost.terms.t.type: unknown term type"),
        ({"type": "position", "body": "b"}, "cost.terms[0].name: required"),
        ({"name": "t", "type": "position", "body": "b"}, "cost.terms.t.target: required"),
        ({"name": "t", "type": "height", "body": "b", "target": 1, "min": 0},
         "cost.terms.t: give a target, or min and/or max (not both)"),
        ({"name": "t", "type": "height", "body": "b", "min": 0, "geometry_a": "g"},
         "cost.terms.t.geometry_a: a height term has no geometry_a"),
        ({"name": "t", "type": "orientation", "body": "b", "target": [1, 2]},
         "cost.terms.t.target: expected 3 numbers (roll, pitch, yaw) or 4"),
        ({"name": "t", "type": "orientation", "body": "b", "target": [0, 0, 0],
          "point": [0, 0, 1]}, "cost.terms.t.point: an orientation term has no point"),
        ({"name": "t", "type": "velocity", "body": "b", "axes": ["x", "w"]},
         "cost.terms.t.axes: expected distinct axes"),
        ({"name": "t", "type": "velocity", "body": "b", "axes": ["x", "y"], "weight": [1, 2, 3]},
         "cost.terms.t.weight: expected a number or 2 values"),
        ({"name": "t", "type": "velocity", "body": "b", "weight": -1},
         "cost.terms.t.weight: weights must be non-negative"),
        ({"name": "t", "type": "velocity", "body": "b", "terminal": True, "until": 1},
         "cost.terms.t.terminal: a terminal term has no after, until or ramp"),
        ({"name": "t", "type": "velocity", "body": "b", "after": 1, "until": 0.5},
         "cost.terms.t.until: 0.5 s is before after"),
        ({"name": "t", "type": "distance", "geometry_a": "a", "max": 0.1},
         "cost.terms.t: a distance term needs geometry_a and geometry_b"),
        ({"name": "t", "type": "joint_limits", "margin": -0.1},
         "cost.terms.t.margin: must be >= 0"),
        ({"name": "t", "type": "joint_limits", "body": "b"},
         "cost.terms.t.body: a joint_limits term has no body"),
        ({"name": "t", "type": "height", "body": "b", "min": 0, "margin": 0.1},
         "cost.terms.t.margin: a height term has no margin"),
        ({"name": "t", "type": "slip", "body": "b"}, "cost.terms.t.clearance: required"),
        ({"name": "t", "type": "slip", "body": "b", "clearance": 0.0},
         "cost.terms.t.clearance: required, a height > 0 (m), got 0.0"),
        ({"name": "t", "type": "slip", "body": "b", "clearance": 0.1, "radius": -1},
         "cost.terms.t.radius: expected a length >= 0 (m)"),
        ({"name": "t", "type": "slip", "body": "b", "clearance": 0.1, "axes": ["x"]},
         "cost.terms.t.axes: a slip term has no axes"),
        ({"name": "t", "type": "height", "body": "b", "min": 0, "clearance": 0.1},
         "cost.terms.t.clearance: a height term has no clearance"),
        ({"name": "t", "type": "height", "body": "b", "min": 0, "softmin": -1},
         "cost.terms.t.softmin: a temperature >= 0 (cost units), got -1"),
        ({"name": "t", "type": "height", "body": "b", "min": 0, "softmin": 0.1,
          "terminal": True}, "cost.terms.t.softmin: a terminal term has one step"),
    ],
)  # fmt: skip
def test_bad_terms_are_config_errors_before_the_plant_is_built(tmp_path, term, message):
    with pytest.raises(ConfigError, match=re.escape(message)):
        Task.load(str(write_case(tmp_path, edit(cost__terms=[term]))))


def test_joint_limits_term_reads_the_model_limits_with_a_margin(kinova):
    """The Gen3 model file limits joints 2, 4 and 6 (±2.41, ±2.66, ±2.23 rad); the term costs
    only the part of each beyond its limit less the margin, one residual per joint."""
    task, X, _ = kinova
    terms = task.cost.task_terms
    t = next(t for t in terms.terms if t.name == "limits")
    lim = t.residual
    lay = task.dynamics.layout
    assert [int(i) for i in lim.coords] == [lay.block(f"joint_{j}").coords[0] for j in (2, 4, 6)]
    np.testing.assert_allclose(lim.upper, np.array([2.41, 2.66, 2.23]) - 1.0)
    x = X[0].copy()
    x[lim.coords] = [0.0, -2.0, 1.5]  # inside, 0.34 below -1.66, 0.27 above 1.23
    terms.kin.set(x)
    r, J, _ = t.evaluate(terms.kin, x, 0.0, True)
    np.testing.assert_allclose(r, [0.0, -0.34, 0.27], atol=1e-12)
    assert J[0].sum() == 0 and J[1, lim.coords[1]] == 1 and J[2, lim.coords[2]] == 1


def test_plant_joint_limits_false_removes_drakes_but_the_term_still_reads_them(tmp_path):
    """``plant.joint_limits: false``: the plant has no position limits (a joint may pass
    them); ``Scene.position_limits`` and a joint_limits term keep the model file's."""
    term = {"name": "lim", "type": "joint_limits", "joints": ["joint_4"], "weight": 1.0}
    free = Task.load(
        "kinova-forward",
        smoke=True,
        overrides={"plant.joint_limits": False, "cost.terms": [term]},
    )
    plant = free.dynamics.plant
    assert np.all(np.isinf(plant.GetPositionUpperLimits()))
    i = free.dynamics.layout.block("joint_4").coords[0]
    assert free.dynamics.scene.position_limits[1][i] == pytest.approx(2.66)
    t = free.cost.task_terms.terms[0].residual
    assert list(t.coords) == [i] and t.upper[0] == pytest.approx(2.66)
    held = Task.load("kinova-forward", smoke=True)
    assert held.dynamics.plant.GetPositionUpperLimits()[i] == pytest.approx(2.66)


@pytest.mark.parametrize(
    ("term", "message"),
    [
        ({"joints": ["joint_1"]}, "cost.terms.t.joints: joint_1 has no position limits"),
        ({"joints": ["ball.orientation"]}, "ball.orientation is not a block of joint positions"),
        ({"joints": ["joint_9"]}, "unknown state block 'joint_9'"),
        ({"margin": 3.0}, "cost.terms.t.margin: 3.0 is more than half of a joint's range"),
    ],
)
def test_joint_limits_term_errors_name_the_joint(term, message):
    spec = {"name": "t", "type": "joint_limits", **term}
    task = Task.load("kinova-forward", smoke=True, overrides={"cost.terms": [spec]})
    with pytest.raises(ConfigError, match=re.escape(message)):
        _ = task.cost


def test_two_terms_with_one_name_are_refused(tmp_path):
    t = {"name": "t", "type": "velocity", "body": "b"}
    with pytest.raises(ConfigError, match="cost.terms\\[1\\].name: two terms are named 't'"):
        Task.load(str(write_case(tmp_path, edit(cost__terms=[t, t]))))


def test_orientation_error_is_two_sin_half_the_angle_from_the_target(kinova):
    from pydrake.math import RollPitchYaw, RotationMatrix

    task, X, _ = kinova
    terms = task.cost.task_terms
    plant = task.dynamics.plant
    ctx = plant.CreateDefaultContext()
    target = RotationMatrix(RollPitchYaw([0.1, 0.2, 0.3]))
    rep = terms.report(X)  # turn: running, last step N - 1
    plant.SetPositionsAndVelocities(ctx, X[N - 1])
    R = plant.CalcRelativeRotationMatrix(ctx, plant.world_frame(), plant.GetFrameByName("gripper"))
    angle = target.InvertAndCompose(R).ToAngleAxis().angle()
    assert rep["turn"]["error"] == pytest.approx(2 * np.sin(angle / 2), rel=1e-9)
    np.testing.assert_allclose(rep["turn"]["final"], RollPitchYaw(R).vector(), atol=1e-9)
    # relative to the start, no extra rotation: no error at the initial state
    start = task.with_overrides(["cost.terms.roll.target=null"]).cost.task_terms
    assert start.report(np.tile(task.x0, (N + 1, 1)))["roll"]["error"] < 1e-12


def test_slip_counts_the_contact_points_horizontal_velocity_while_low(kinova):
    """A slip term's residual: g(h) (v_WC)_xy with C the sphere's lowest point as a point of
    the body (so a sphere spinning about a horizontal axis in place slips at its bottom) and
    g = 1 − h/clearance; 0 once the point is a clearance above the ground."""
    task, _, _ = kinova
    terms = task.cost.task_terms
    lay = task.dynamics.layout
    x = task.x0.copy()
    x[list(lay.primitives["ball.angular_velocity"].coords)] = [0.0, 2.0, 0.0]  # about +y
    x[list(lay.primitives["ball.velocity"].coords)] = [0.3, 0.0, 0.0]
    X = np.tile(x, (N + 1, 1))
    ball = next(i for i, t in enumerate(terms.terms) if t.name == "ballslip")
    _, _, R, _, meas = terms._evaluate(X, 0.0, False)
    plant = task.dynamics.plant
    ctx = plant.CreateDefaultContext()
    plant.SetPositionsAndVelocities(ctx, x)
    z = plant.CalcPointsPositions(ctx, plant.GetFrameByName("ball"), np.zeros(3),
                                  plant.world_frame())[2, 0]  # fmt: skip
    h = z - 0.05
    # the bottom point: v_ball + ω × (−r ẑ) = v_ball + r (−ω_y, ω_x, 0)
    expect = (1.0 - h / 0.5) * np.array([0.3 - 0.05 * 2.0, 0.0])
    np.testing.assert_allclose(R[ball][0], expect, atol=1e-12)
    assert meas[ball][0][1] == pytest.approx(h)
    high = task.with_overrides(["cost.terms.ballslip.clearance=0.01"]).cost.task_terms
    _, _, R_high, Js, _ = high._evaluate(X, 0.0, True)
    assert not R_high[ball].any() and not Js[ball].any()


def test_cheetah_walk_example_prices_slip_on_its_four_feet():
    """examples/cheetah-walk.yaml loads, with a slip term per foot and issue 37's goal."""
    task = Task.load("examples/cheetah-walk.yaml", smoke=True)
    terms = task.cost.task_terms.terms
    assert sorted(t.name for t in terms) == ["FL_slip", "FR_slip", "HL_slip", "HR_slip"]
    assert all(t.cfg.type == "slip" for t in terms)
    assert task.config.goal["diagonal_pair_overlap"].margin == 0.2


def test_height_over_a_point_is_the_difference_of_the_two_points_heights(kinova):
    """``above_body``: the height is measured from a point of another body (e.g. one foot over
    another), not from the plane through the origin."""
    task, X, U = kinova
    terms = [
        {"name": "g", "type": "height", "body": "gripper", "point": [0.0, 0.0, 0.02],
         "target": 0.0},
        {"name": "b", "type": "height", "body": "ball", "point": [0.0, 0.03, 0.0],
         "target": 0.0},
        {"name": "gb", "type": "height", "body": "gripper", "point": [0.0, 0.0, 0.02],
         "above_body": "ball", "above_point": [0.0, 0.03, 0.0], "target": 0.1},
    ]  # fmt: skip
    t2 = Task.load("kinova-forward", smoke=True, overrides={"cost.terms": terms, "num_steps": N})
    rep = t2.cost.task_terms.report(X)
    g, ball, gb = (rep[n]["final"] for n in ("g", "b", "gb"))
    assert gb == pytest.approx(g - ball, abs=1e-12)
    assert abs(gb) > 1e-3  # (the two points are apart: the test sees a difference)


def test_softmin_lies_between_min_and_mean_and_its_gradient_is_the_softmax():
    c = np.array([0.3, 0.1, 0.7, 5.0])
    active = np.array([True, True, True, False])  # the last step is outside the window
    for tau in (1e-3, 0.1, 10.0):
        value, p = softmin(c, active, tau)
        assert 0.1 <= value <= np.mean(c[:3]) + 1e-12
        assert p[3] == 0.0 and p.sum() == pytest.approx(1.0)
        h = 1e-7
        for k in range(3):
            e = np.zeros(4)
            e[k] = h
            fd = (softmin(c + e, active, tau)[0] - softmin(c - e, active, tau)[0]) / (2 * h)
            assert p[k] == pytest.approx(fd, rel=1e-5, abs=1e-9)
    assert softmin(c, active, 1e-6)[0] == pytest.approx(0.1, abs=1e-4)  # τ -> 0: the minimum
    assert softmin(c, active, 1e6)[0] == pytest.approx(np.mean(c[:3]), rel=1e-5)  # the mean
    assert softmin(np.full(4, 0.2), active, 0.1)[0] == pytest.approx(0.2)
    assert softmin(c, np.zeros(4, bool), 0.1) == (0.0, pytest.approx(np.zeros(4)))
    assert softmin(c, active, 1e-300)[0] == pytest.approx(0.1)  # no overflow for a tiny τ
    assert softmin(np.array([0.3, np.inf, 0.7, 0.0]), active, 0.1)[0] == np.inf  # as a sum


def test_a_softmin_term_costs_its_windows_soft_minimum(kinova):
    """The term's cost along X is the soft minimum of its steps' costs (not their sum), in
    the breakdown and in the total; its gradient is checked with the others above."""
    task, X, U = kinova
    terms = task.cost.task_terms
    names = [t.name for t in terms.terms]
    i = names.index("touch")
    active, factor, R, _, _ = terms._evaluate(X, 0.0, False)
    c = factor[i] * np.einsum("ki,i,ki->k", R[i], terms.terms[i].weights, R[i])
    assert np.ptp(c[active[i]]) > 1e-4  # the steps differ: the soft minimum is not trivial
    value = softmin(c, active[i], 1.0e-4)[0]
    assert c[active[i]].min() <= value < np.sum(c)
    assert task.cost.breakdown(X, U)["terms.touch"] == pytest.approx(value, rel=1e-12)
    rep = terms.report(X)["touch"]
    assert rep["cost"] == pytest.approx(value, rel=1e-12)
    k = int(np.argmin(np.where(active[i], c, np.inf)))  # reported where it is smallest
    assert rep["step"] == k and rep["error"] == pytest.approx(np.linalg.norm(R[i][k]))


def test_a_term_of_weight_zero_is_reported_but_not_evaluated_in_the_cost(monkeypatch):
    """finger-wheel's approach term has weight 0 outside its continuation stage: the cost, its
    derivatives and the breakdown skip its signed-distance queries; the report measures it."""
    task = Task.load("finger-wheel", smoke=True)
    terms = task.cost.task_terms
    assert terms.terms[0].name == "approach" and not np.any(terms.terms[0].weights)
    calls = []
    real = Term.evaluate

    def counting(self, *a, **k):
        calls.append(self.name)
        return real(self, *a, **k)

    monkeypatch.setattr(Term, "evaluate", counting)
    X = task.dynamics.rollout(task.x0, task.initial_guess(task.steps))
    assert terms.stage_costs(X).sum() == 0.0 and np.all(terms.quadratize(X)[0] == 0.0)
    assert calls == []
    rep = terms.report(X)
    assert "approach" in calls and rep["approach"]["final"] > 0.0  # not touching yet


def test_each_term_is_its_residual_composed_with_activation_weights_and_window(kinova):
    """The keys a term gives choose its parts: a target or bounds, a window with a ramp or the
    last state, a sum or a soft minimum over the window."""
    task, _, _ = kinova
    terms = {t.name: t for t in task.cost.task_terms.terms}
    assert all(type(t.residual) is RESIDUALS[t.cfg.type] for t in terms.values())
    assert terms["lift"].time == Terminal() and terms["lift"].shape == Bounds(0.5, np.inf)
    assert terms["tilt"].time == Window(None, None, Ramp(0.5, 2.0))
    assert terms["tilt"].shape == Target(0.2) and terms["apart"].time == Window(None, 0.015)
    assert terms["apart"].shape == Bounds(-np.inf, 0.01) and terms["reach"].shape == Identity()
    assert terms["touch"].aggregate == SoftMin(1.0e-4) and isinstance(terms["near"].aggregate, Sum)
    np.testing.assert_array_equal(terms["reach"].weights, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(terms["limits"].weights, [3.0, 3.0, 3.0])  # one per joint


def test_bounds_cost_only_beyond_them_with_a_unit_slope():
    r, d = Bounds(np.array([-1.0, 0.0, -np.inf]), np.array([1.0, np.inf, 2.0]))(
        np.array([1.5, -0.25, 0.5])
    )
    np.testing.assert_array_equal(r, [0.5, -0.25, 0.0])
    np.testing.assert_array_equal(d, [1.0, 1.0, 0.0])
    assert Target(0.5)(np.array([2.0])) == (np.array([1.5]), None)


def test_a_ramp_is_linear_over_its_window_up_to_the_tasks_end():
    times = np.linspace(0.0, 1.0, 6)  # 5 steps of 0.2 s
    on, f = Window(0.2, None, Ramp(1.0, 3.0)).factors(times, 0.5, end_time=1.0)
    np.testing.assert_array_equal(on, [0, 1, 1, 1, 1, 0])  # the last state is a terminal's
    np.testing.assert_allclose(f, 0.5 * np.array([0.0, 1.0, 1.5, 2.0, 2.5, 0.0]))
    on, f = Terminal().factors(times, 0.5, end_time=1.0)
    np.testing.assert_array_equal(f, [0, 0, 0, 0, 0, 1.0])
