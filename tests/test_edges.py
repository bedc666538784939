"""Metrics, cost, state difference, config, check, bench, sweep, Solution files and worker
line-search rounds, checked at their edges against hand-built data (a mutation-testing round:
each test kills a mutation the rest of the suite let through). Smoke-sized."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from hydroilqr import Task

# ------------------------------------------------------------------------------------------
# metrics_cheetah
# ------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def cheetah():
    return Task.load("cheetah-trot-1.0", smoke=True)


def _synthetic_cheetah_run(task):
    """41 states 0.05 s apart (from t = 3.0 s: metrics use time from the start). Before 0.2 s
    (4 states) every foot and the body touch; afterwards a fixed irregular pattern."""
    lay = task.dynamics.layout
    T = 41
    t = 3.0 + 0.05 * np.arange(T)
    X = np.tile(task.x0, (T, 1))
    pos = lay.primitives["body.position"].coords
    vel = lay.primitives["body.velocity"].coords
    X[:, pos[2]] = 0.25
    X[2, pos[2]] = 0.05  # before settling: ignored
    X[30, pos[2]] = 0.20  # the lowest settled height
    X[:, vel[0]] = np.where(t - t[0] >= 1.0 - 1e-9, 2.0, 0.0)  # 2 m/s over the last second
    phase = (np.arange(T) // 3) % 2 == 0  # a trot: FL+HR, then FR+HL, 3 states each
    feet = np.stack([phase, ~phase, ~phase, phase], axis=1)
    feet[[12, 25, 26], 1] = True  # FR also down at a few states
    feet[33, 3] = False  # HR lifts once more
    feet[:4] = True
    feet[39:] = True  # all down at the end: touchdowns outnumber lift-offs
    body = np.zeros(T, bool)
    body[:4] = True
    body[10] = True
    faces = 3 * feet.astype(int)
    faces[0, 0] = 9  # the most polygons (before settling: still counted)
    S = np.tile(0.001 * np.arange(T)[:, None], (1, 4))  # distinct values: a shifted median shows
    S[:4] = 5.0  # sliding while settling: ignored
    S[20:23, :] = 1.0  # a few fast steps: the median ignores them, a mean would not
    sol = SimpleNamespace(
        t=t,
        X=X,
        extra={"resolves": [{"iterations": 2, "seconds": 0.1}, {"iterations": 4, "seconds": 0.3}]},
    )
    return sol, feet, faces, body, S


def test_cheetah_metrics_on_a_synthetic_contact_pattern(cheetah, monkeypatch):
    from hydroilqr.metrics import cheetah as mc

    sol, feet, faces, body, S = _synthetic_cheetah_run(cheetah)
    monkeypatch.setattr(mc, "contacts", lambda task, s: (feet, faces, body))
    monkeypatch.setattr(mc, "foot_slip_speeds", lambda task, s: S)
    F = np.tile(10.0 * np.arange(1, 5), (len(sol.t) - 1, 1))  # [N, 4]: 10, 20, 30, 40 N
    F[:4] = 500.0  # while settling: ignored
    monkeypatch.setattr(mc, "foot_vertical_forces", lambda task, s: F)
    m = mc.cheetah_metrics(cheetah, sol)

    settled = np.arange(len(sol.t)) >= 4  # t - t0 >= 0.2 s
    fl, fr, hl, hr = feet[settled].T
    n = settled.sum()
    assert m["target_velocity_mps"] == 1.0
    assert m["mean_forward_velocity_mps"] == pytest.approx(2.0)  # last second only
    assert m["velocity_error_fraction"] == pytest.approx(1.0)  # |2 - 1| / 1
    assert m["min_body_height_m"] == pytest.approx(0.20)
    assert m["body_ground_contact_steps"] == 1
    assert m["duty_factor"] == pytest.approx(
        {"FL": fl.sum() / n, "FR": fr.sum() / n, "HL": hl.sum() / n, "HR": hr.sum() / n}
    )
    diag = ((fl & hr).sum() + (fr & hl).sum()) / (2 * n)
    lat = ((fl & hl).sum() + (fr & hr).sum()) / (2 * n)
    assert diag != pytest.approx(lat)  # the pattern tells the two apart
    assert m["diagonal_pair_overlap"] == pytest.approx(diag)
    assert m["lateral_pair_overlap"] == pytest.approx(lat)
    f = feet[settled]
    downs = {
        lab: int(np.sum(f[1:, j] & ~f[:-1, j])) for j, lab in enumerate(("FL", "FR", "HL", "HR"))
    }
    ups = {
        lab: int(np.sum(~f[1:, j] & f[:-1, j])) for j, lab in enumerate(("FL", "FR", "HL", "HR"))
    }
    assert downs != ups
    assert m["foot_touchdowns"] == downs
    stance = feet & settled[:, None]
    slip = {lab: np.median(S[stance[:, j], j]) for j, lab in enumerate(("FL", "FR", "HL", "HR"))}
    assert all(v < 0.05 for v in slip.values())  # the three fast steps do not move the median
    assert m["foot_slip_mps"] == pytest.approx(slip)
    mg = cheetah.dynamics.plant.CalcTotalMass(cheetah.dynamics.plant_context) * 9.81
    assert m["foot_load"] == pytest.approx(
        {lab: 10.0 * (j + 1) / mg for j, lab in enumerate(("FL", "FR", "HL", "HR"))}
    )
    assert m["max_foot_faces"] == 9
    assert m["mean_foot_faces"] == pytest.approx(faces[feet].mean())
    assert m["mean_foot_faces"] > faces.mean()  # over touching states only
    assert m["iterations_per_resolve"] == 3.0 and m["resolve_seconds"] == pytest.approx(0.2)


def test_foot_slip_is_zero_for_feet_rolling_on_their_lowest_points(cheetah):
    """The whole robot rolls about the line through the feet's lowest points (x axis): those
    material points stand still, the sphere centres (one radius above) do not."""
    from hydroilqr.metrics.cheetah import foot_slip_speeds

    dyn = cheetah.dynamics
    lay = dyn.layout
    x = cheetah.x0.copy()
    plant = dyn.plant
    plant.SetPositionsAndVelocities(dyn.plant_context, x)
    query = plant.get_geometry_query_input_port().Eval(dyn.plant_context)
    ids = {name: gid for gid, (name, _) in dyn.geometry_names().items()}
    inspector = dyn.scene_graph.model_inspector()
    gid = ids["FL_foot_collision"]
    radius = inspector.GetShape(gid).radius()
    z_low = query.GetPoseInWorld(gid).translation()[2] - radius
    z_body = x[lay.primitives["body.position"].coords[2]]
    w = 2.0  # rad/s about world x
    x[list(lay.primitives["body.angular_velocity"].coords)] = [w, 0.0, 0.0]
    # v_O = -w x (p_low - O): y component w * (z_low - z_body)
    x[list(lay.primitives["body.velocity"].coords)] = [0.0, w * (z_low - z_body), 0.0]
    S = foot_slip_speeds(cheetah, SimpleNamespace(X=np.array([x])))
    assert radius > 0.01
    np.testing.assert_allclose(S, 0.0, atol=1e-3 * w * radius)


# ------------------------------------------------------------------------------------------
# metrics_kinova
# ------------------------------------------------------------------------------------------


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


# ------------------------------------------------------------------------------------------
# metrics.py: default metrics and cartpole_wall
# ------------------------------------------------------------------------------------------


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


# ------------------------------------------------------------------------------------------
# cost.py
# ------------------------------------------------------------------------------------------


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
    from hydroilqr.problem.config import ConfigError
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


# ------------------------------------------------------------------------------------------
# state.py
# ------------------------------------------------------------------------------------------


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
    from hydroilqr.problem.config import ConfigError

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


# ------------------------------------------------------------------------------------------
# check.py
# ------------------------------------------------------------------------------------------


def _check(task, **kw):
    from hydroilqr.problem.check import check_task

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
    # One point-contact pair among hydroelastic ones is enough for the AutoDiff warning.
    post = (
        "scene=[{name: wall, shape: box, size: [0.1, 1.0, 2.0], xyz: [-0.5, 0, 0], "
        "compliance: rigid}, {name: post, shape: box, size: [0.1, 0.1, 0.1], xyz: [2, 0, 0], "
        "compliance: compliant, hydroelastic_modulus: 1.0e+6}]"
    )
    kinds, warnings = models([*rigid, post, "solver.derivatives=autodiff"])
    assert sorted(kinds) == ["hydroelastic", "point (fallback)"]
    assert any("point-contact pairs under autodiff" in w for w in warnings)
    # A scene object's no_contact_with removes its pairs (the wall here: none left).
    filtered = post.replace("compliance: rigid}", "compliance: rigid, no_contact_with: [tip]}")
    kinds, _ = models([*rigid, filtered])
    assert kinds == ["hydroelastic"]  # only the post's pair with the tip


# ------------------------------------------------------------------------------------------
# config.py
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "override,needle",
    [
        ("horizon=0", "horizon: must be positive"),
        ("solver.line_search_factor=1.0", "solver.line_search_factor"),
        ("solver.regularization_max=1e-6", "solver.regularization_max"),  # = its min
        ("mpc.deadline=1.5", "mpc.deadline"),
        ("receding_horizon={window_steps: 4, shift_steps: 2, resolves: 2, max_iterations: 0}",
         "receding_horizon.max_iterations"),
        ("continuation=[{plant.time_step: 0.02}]", "cannot change between stages"),
    ],
)  # fmt: skip
def test_settings_that_cannot_run_are_refused(override, needle):
    from hydroilqr.problem.config import ConfigError, load_task

    extra = ["solver.regularization_min=1e-6"] if "regularization_max" in override else []
    with pytest.raises(ConfigError, match=needle.replace(".", r"\.")):
        load_task("cartpole-wall", [*extra, override])


def test_settings_at_the_edges_of_their_ranges_are_accepted():
    from hydroilqr.problem.config import load_task

    ok = [
        "solver.short_step=0",  # 0 = always shrink after a success (documented)
        "receding_horizon={window_steps: 4, shift_steps: 4, resolves: 2}",  # whole window kept
        "cost.nominal_rate.cart_position=-0.5",  # a nominal moving backwards
    ]
    for o in ok:
        load_task("cartpole-wall", [o])
    # With num_steps the horizon is not used: it need not be whole steps of the time step.
    assert load_task("cartpole-wall", ["plant.time_step=0.03", "num_steps=5"]).steps == 5
    # 0.29 / 0.01 = 28.999999999999996: rounded, not truncated
    assert load_task("cartpole-wall", ["horizon=0.29"]).steps == 29
    # Whole floats for integers (e.g. a linspace sweep of solver.max_iterations)
    assert load_task("cartpole-wall", {"solver.max_iterations": 20.0}).solver.max_iterations == 20
    cfg = load_task("cartpole-wall", {"cost.running_cost_dt": "0"})
    assert cfg.cost.running_cost_dt is False
    assert load_task("cartpole-wall", {"cost.running_cost_dt": "1"}).cost.running_cost_dt is True


def test_a_child_task_num_steps_wins_over_its_base_horizon(tmp_path):
    from hydroilqr.problem.config import load_task

    urdf = "package://drake/examples/pendulum/Pendulum.urdf"
    (tmp_path / "base.yaml").write_text(
        f"models: [{{file: '{urdf}'}}]\nhorizon: 0.5\ncost: {{R: 0.1}}\n"
    )
    (tmp_path / "child.yaml").write_text("extends: base.yaml\nnum_steps: 3\n")
    assert load_task(str(tmp_path / "child.yaml")).steps == 3


def test_geometry_overrides_by_dotted_name_and_shorthand_errors():
    from hydroilqr.problem.config import ConfigError, load_task

    cfg = load_task("cartpole-wall", ["geometry.my.tip.friction=0.3"])
    assert cfg.geometry["my.tip"].friction == 0.3  # a geometry name with a dot in it
    # A geometry the task names: a far-off key is reported against its contact properties.
    with pytest.raises(ConfigError, match=r"geometry\.tip\.youngs: unknown key"):
        load_task("cartpole-wall", ["tip.youngs=1e6"])  # (not a near-miss of a property)
    # A name that is both a scene object and a geometry entry is ambiguous.
    with pytest.raises(ConfigError, match="names both a scene object and a geometry entry"):
        load_task("cartpole-wall", ["geometry.wall.friction=0.3", "wall.dissipation=1"])


# ------------------------------------------------------------------------------------------
# bench.py
# ------------------------------------------------------------------------------------------


def _fake_solution(X, iteration_seconds, phases, costs):
    from hydroilqr.solver.solution import Solution

    N = X.shape[0] - 1
    return Solution(
        X, np.zeros((N, 1)), np.zeros(0), np.zeros(0), 0.01 * np.arange(N + 1),
        np.array(costs, float), list(iteration_seconds), phases, False, "max_iterations",
        "forward",
    )  # fmt: skip


def test_bench_ratios_cost_difference_and_phase_shares(monkeypatch):
    from hydroilqr.studies import bench

    def fake_runs(tasks, U0, iterations, block=1, shadow=None):
        X = np.tile(tasks[0].x0, (3, 1))
        paper = _fake_solution(
            X,
            [0.5, 0.7, 0.6],  # the phases add up to less: waits are not phases
            {"rollout": [0.1] * 3, "derivatives": [0.2, 0.4, 0.3],
             "backward_pass": [0.05] * 3, "line_search": [0.05] * 3},
            [20.0, 15.0, 12.0, 10.0],
        )  # fmt: skip
        fast = _fake_solution(
            X,
            [0.1, 0.2, 0.1],
            {"rollout": [0.02] * 3, "derivatives": [0.02] * 3,
             "backward_pass": [0.02] * 3, "line_search": [0.02] * 3},
            [20.0, 14.0, 13.0, 12.0],
        )  # fmt: skip
        return [paper, fast]

    monkeypatch.setattr(bench, "run_alternating", fake_runs)
    fast = ["solver.derivatives=forward"]
    r = bench.bench_task("cartpole-wall", 3, 1, smoke=True, fast=fast, accuracy=False)
    a = r["paper"]
    assert r["speedup_median"] == pytest.approx(0.6 / 0.1)  # a / b: > 1 when (b) is faster
    assert r["speedup_total"] == pytest.approx(1.8 / 0.4)
    assert r["cost_rel_diff"] == pytest.approx((12.0 - 10.0) / 10.0)  # (b - a) / |a|
    assert a["initial_cost"] == 20.0 and a["final_cost"] == 10.0
    assert a["p10_s"] == pytest.approx(np.percentile([0.5, 0.6, 0.7], 10))
    assert a["p10_s"] > 0.5
    assert a["phase_share"] == pytest.approx(
        {"rollout": 0.2, "derivatives": 0.6, "backward_pass": 0.1, "line_search": 0.1}
    )

    def one_fails(tasks, U0, iterations, block=1, shadow=None):
        res = fake_runs(tasks, U0, iterations, block)
        return [res[0], RuntimeError("diverged")]

    monkeypatch.setattr(bench, "run_alternating", one_fails)
    r = bench.bench_task("cartpole-wall", 3, 1, smoke=True, fast=fast, accuracy=False)
    assert r["fast"] == {"error": "RuntimeError: diverged"} and "speedup_median" not in r


def test_bench_alternates_blocks_of_iterations(monkeypatch):
    from hydroilqr.solver import ilqr
    from hydroilqr.studies import bench

    order = []

    def fake_solve(problem, U0, settings, callbacks, max_iterations, final_gains):
        for _ in range(max_iterations):
            order.append(problem)
            for cb in callbacks:
                cb(None)
        return problem

    monkeypatch.setattr(ilqr, "solve", fake_solve)
    tasks = [
        SimpleNamespace(problem=lambda i=i: i, config=SimpleNamespace(solver=None)) for i in (0, 1)
    ]
    assert bench.run_alternating(tasks, np.zeros(1), 3, block=1) == [0, 1]
    assert order == [0, 1, 0, 1, 0, 1]
    order.clear()
    bench.run_alternating(tasks, np.zeros(1), 4, block=2)
    assert order == [0, 0, 1, 1, 0, 0, 1, 1]


def test_contact_polygons_and_classes():
    from hydroilqr.studies.bench import contact_state, polygons

    task = Task.load("cartpole-wall", ["num_steps=5"])
    lay = task.dynamics.layout
    X = np.tile(task.x0, (4, 1))
    X[:, lay.block("pole_angle").coords[0]] = np.pi
    X[:, lay.block("cart_position").coords[0]] = [0.0, -0.43, -0.44, 0.0]  # 2 touch the wall
    faces = [contact_state(task.dynamics, x)[0] for x in X]
    p = polygons(task.dynamics, X)
    assert p["contact_steps"] == 2 and p["max_faces"] == max(faces) > 0
    assert p["mean_faces"] == pytest.approx(np.mean(faces))
    assert np.mean(faces) < max(faces)
    assert contact_state(task.dynamics, X[1])[1] == "compliant-rigid"
    soft = Task.load(
        "cartpole-wall",
        ["num_steps=5", "wall.compliance=compliant", "wall.hydroelastic_modulus=1e7"],
    )
    assert contact_state(soft.dynamics, X[1])[1] == "compliant-compliant"
    assert contact_state(soft.dynamics, X[0]) == (0, "free")


def test_probe_and_thread_scaling_read_the_times_the_right_way_round(monkeypatch):
    from hydroilqr.model import derivatives
    from hydroilqr.studies import bench

    clock = [0.0]  # bench's perf_counter: advanced only by the fake linearize (no sleeps)

    def fake_linearize(dyn, X, U, method, eps, threads, interval=1, **kw):
        clock[0] += 0.04 if method == "autodiff" else 0.02 if threads == 1 else 0.004
        return None

    monkeypatch.setattr(bench, "time", SimpleNamespace(perf_counter=lambda: clock[0]))
    monkeypatch.setattr(derivatives, "linearize", fake_linearize)
    monkeypatch.setattr(derivatives, "num_threads", lambda n: 2)
    task = Task.load("cartpole-wall", ["num_steps=5"])
    U0 = np.zeros((5, 1))
    monkeypatch.setattr(task.dynamics, "autodiff", lambda: None)
    probe = bench.probe_derivatives(task, U0, 1, repeats=1)
    assert probe["choice"] == "forward"  # the faster
    assert probe["seconds_per_step"] == pytest.approx({"autodiff": 0.04 / 5, "forward": 0.02 / 5})
    th = bench.thread_scaling(task, None, None, 2, repeats=1)
    assert th["speedup"]["1"] == 1.0 and th["speedup"]["2"] == pytest.approx(5.0)  # t(1) / t(2)


# ------------------------------------------------------------------------------------------
# solution.py
# ------------------------------------------------------------------------------------------


def test_solution_save_load_round_trip_keeps_every_field(tmp_path):
    from hydroilqr.solver.solution import Solution

    N, nx, nu = 3, 2, 1
    rng = np.random.default_rng(0)
    sol = Solution(
        X=rng.standard_normal((N + 1, nx)), U=rng.standard_normal((N, nu)),
        K=rng.standard_normal((N, nu, nx)), kappa=rng.standard_normal((N, nu)),
        t=0.1 * np.arange(N + 1), costs=np.array([3.0, 2.0, 1.5]),
        iteration_seconds=[0.25, 0.5],
        phase_seconds={"rollout": [0.1, 0.2], "derivatives": [0.1, 0.2],
                       "backward_pass": [0.0, 0.05], "line_search": [0.05, 0.05]},
        converged=True, reason="relative_cost", derivatives="autodiff",
        eps=[1.0, 0.5], mu=[1e-6, 1e-7], extra={"task_initial_cost": 9.0, "resolves": [{"a": 1}]},
    )  # fmt: skip
    path = sol.save(tmp_path / "plan.v2")  # a dotted name: .npz appended, not substituted
    assert path == tmp_path / "plan.v2.npz"
    back = Solution.load(tmp_path / "plan.v2")
    for k in ("X", "U", "K", "kappa", "t", "costs"):
        np.testing.assert_array_equal(getattr(back, k), getattr(sol, k))
    for k in ("iteration_seconds", "phase_seconds", "converged", "reason", "derivatives",
              "eps", "mu", "extra"):  # fmt: skip
        assert getattr(back, k) == getattr(sol, k), k
    assert back.stats() == sol.stats()
    assert sol.stats()["initial_cost"] == 9.0  # a continuation's task-model cost
    assert sol.total_seconds == 0.75
    # A plan saved without gains (final_gains=False) loads too.
    bare = Solution(sol.X, sol.U, np.zeros(0), np.zeros(0), sol.t, sol.costs, [], {}, False, "", "")
    bare.save(tmp_path / "bare.npz")
    assert Solution.load(tmp_path / "bare.npz").K.shape == (0,)
    # Gains of the wrong shape are refused.
    bad = Solution(sol.X, sol.U, np.zeros((N, nu, nx + 1)), sol.kappa, sol.t, sol.costs, [], {},
                   False, "", "")  # fmt: skip
    bad.save(tmp_path / "bad.npz")
    with pytest.raises(ValueError, match="arrays disagree"):
        Solution.load(tmp_path / "bad.npz")


def test_an_existing_file_is_loaded_as_given_not_its_npz_sibling(tmp_path):
    from hydroilqr.solver.solution import solution_file

    (tmp_path / "plan").write_bytes(b"x")
    (tmp_path / "plan.npz").write_bytes(b"y")
    assert solution_file(tmp_path / "plan") == tmp_path / "plan"
    assert solution_file(tmp_path / "other") == tmp_path / "other"
    (tmp_path / "other.npz").write_bytes(b"z")
    assert solution_file(tmp_path / "other") == tmp_path / "other.npz"


# ------------------------------------------------------------------------------------------
# sweep.py
# ------------------------------------------------------------------------------------------

KEY = "tip.hydroelastic_modulus"
SMALL = ["num_steps=5", "solver.max_iterations=1"]


def test_parse_values_and_grid_edges():
    from hydroilqr.problem.config import ConfigError
    from hydroilqr.studies.sweep import grid, parse_values

    assert parse_values("linspace:0:0.3:4") == [0.0, 0.1, 0.2, 0.3]  # not 0.09999999999999999
    with pytest.raises(ConfigError, match="positive START and STOP"):
        parse_values("logspace:1:0:3")
    with pytest.raises(ConfigError, match="positive START and STOP"):
        parse_values("logspace:1:-10:3")
    g = grid([("a", [1, 2]), ("b", [3, 4, 5])])
    assert g == [{"a": a, "b": b} for a in (1, 2) for b in (3, 4, 5)]  # first varies slowest


def test_sweep_refuses_bad_specs_before_starting(tmp_path):
    from hydroilqr.problem.config import ConfigError
    from hydroilqr.studies.sweep import run_sweep

    with pytest.raises(ConfigError, match="at most two"):
        run_sweep("cartpole-wall", [("a", [1]), ("b", [1]), ("c", [1])], tmp_path / "a")
    with pytest.raises(ConfigError, match="the same key twice"):
        run_sweep("cartpole-wall", [(KEY, [1e6]), (KEY, [2e6])], tmp_path / "b")
    # The last point is built before the cluster starts, like the first.
    with pytest.raises(ConfigError, match="must be positive"):
        run_sweep("cartpole-wall", [(KEY, [1e6, -5.0])], tmp_path / "c", sets=SMALL)
    assert not (tmp_path / "c" / "points").exists()


def test_sweep_retry_failed_and_a_different_param_in_the_same_directory(tmp_path):
    import json

    from hydroilqr.problem.config import ConfigError
    from hydroilqr.studies.sweep import point_id, run_sweep

    out = tmp_path / "s"
    (out / "points").mkdir(parents=True)
    pid = point_id({KEY: 1e6})
    failed = {"id": pid, f"param:{KEY}": 1e6, "status": "failed", "error": "KilledWorker: x"}
    (out / "points" / f"{pid}.json").write_text(json.dumps(failed))
    # A spec written before solver.threads=1 stopped being listed under --set: the same sweep.
    spec = {
        "task": "cartpole-wall",
        "config_file": None,
        "smoke": False,
        "set": sorted(SMALL + ["solver.threads=1"]),
        "params": [{"key": KEY, "values": [1e6]}],
    }
    (out / "sweep_spec.json").write_text(json.dumps(spec))  # fmt: skip
    res = run_sweep("cartpole-wall", [(KEY, [1e6])], out, sets=SMALL, plots=False)
    assert res["computed"] == 0 and res["failed"] == 1  # kept as it is
    # Another swept key over the same values is another sweep.
    with pytest.raises(ConfigError, match="--param"):
        run_sweep("cartpole-wall", [("tip.dissipation", [1e6])], out, sets=SMALL, plots=False)
    res = run_sweep(
        "cartpole-wall", [(KEY, [1e6])], out, sets=SMALL, plots=False, retry_failed=True, workers=1
    )
    assert res["computed"] == 1 and res["failed"] == 0
    assert json.loads((out / "points" / f"{pid}.json").read_text())["status"] == "ok"


def test_an_older_point_file_does_not_replace_the_current_one(tmp_path):
    import json

    from hydroilqr.studies.sweep import _adopt_older_point, point_id

    old = point_id({KEY: 1000000}, {KEY: repr(1000000)})
    new = point_id({KEY: 1e6})
    (tmp_path / f"{old}.json").write_text(json.dumps({"id": old, "status": "failed"}))
    (tmp_path / f"{new}.json").write_text(json.dumps({"id": new, "status": "ok"}))
    _adopt_older_point(tmp_path, {KEY: 1e6}, new)
    assert json.loads((tmp_path / f"{new}.json").read_text())["status"] == "ok"


# ------------------------------------------------------------------------------------------
# workers.py / line-search rounds
# ------------------------------------------------------------------------------------------


def test_line_search_rounds_go_to_the_workers_and_stop_at_max_steps(monkeypatch):
    """Rounds of two trials (as with line_search_workers=2): sent together, the first acceptable
    one taken (bitwise the serial iterates), and never more trials than line_search_max_steps."""
    from hydroilqr.model import workers
    from hydroilqr.model.plant import SimulationError
    from hydroilqr.solver.ilqr import solve as ilqr_solve

    task = Task.load("cartpole-wall", ["num_steps=20", "solver.max_iterations=3"])
    dyn = task.dynamics
    problem, U0 = task.problem(), task.initial_guess(task.steps)
    serial = ilqr_solve(problem, U0, task.config.solver)

    rounds = []

    def side_by_side(dyn, x0, U, X, K, kappa, eps_list):  # computed here, recorded
        rounds.append(list(eps_list))
        out = []
        for e in eps_list:
            try:
                out.append(dyn.closed_loop_rollout(x0, U, X, K, kappa, e))
            except SimulationError as err:
                out.append(err)
        return out

    monkeypatch.setattr(workers, "line_search_width", lambda dyn, requested: 2)
    monkeypatch.setattr(workers, "closed_loop_rollouts", side_by_side)
    par = ilqr_solve(problem, U0, task.config.solver)
    assert rounds and all(len(r) == 2 for r in rounds)
    np.testing.assert_array_equal(par.costs, serial.costs)
    assert par.eps == serial.eps

    def reject_all(dyn, x0, U, X, K, kappa, eps_list):
        rounds.append(list(eps_list))
        return [SimulationError("rejected") for _ in eps_list]

    def reject_one(x0, U, X, K, kappa, eps):  # a round of one trial runs here
        rounds.append([eps])
        raise SimulationError("rejected")

    rounds.clear()
    monkeypatch.setattr(workers, "closed_loop_rollouts", reject_all)
    monkeypatch.setattr(dyn, "closed_loop_rollout", reject_one)
    s = task.config.solver
    s.line_search_max_steps, s.line_search_retries, s.max_iterations = 3, 0, 1
    ilqr_solve(problem, U0, s)
    assert rounds == [[1.0, 0.5], [0.25]]  # 3 trials: ε, ε·f in one round, ε·f² alone


def test_a_trial_that_blows_up_in_a_worker_keeps_the_pool():
    from hydroilqr.model import workers
    from hydroilqr.model.plant import SimulationError

    task = Task.load("cartpole-wall", ["solver.line_search_workers=2"], smoke=True)
    dyn = task.dynamics
    N = 10
    U, X = np.zeros((N, dyn.nu)), dyn.rollout(task.x0, np.zeros((N, dyn.nu)))
    K, kappa = np.zeros((N, dyn.nu, dyn.nx)), np.full((N, dyn.nu), -1e12)
    out = workers.closed_loop_rollouts(dyn, task.x0, U, X, K, kappa, [0.0, 1.0])
    np.testing.assert_array_equal(out[0][0], X)  # ε = 0: the nominal itself, from a worker
    assert isinstance(out[1], SimulationError)
    assert workers.pool(dyn, 2) is not None and workers.line_search_width(dyn, 2) == 2


# ------------------------------------------------------------------------------------------
# effort limits
# ------------------------------------------------------------------------------------------


def test_commands_beyond_the_effort_limits_are_reported():
    """Drake clips the actuation input to the effort limits (the same trajectory as a clipped
    command, partials zero beyond it); a plan whose commands exceed them says so."""
    from hydroilqr import Task
    from hydroilqr.metrics import beyond_limits, summary_lines

    task = Task.load("kinova-forward", ["solver.autodiff_workers=1"], smoke=True)
    dyn = task.dynamics
    lim = dyn.effort_limits
    N = task.steps
    U = task.initial_guess(N)
    assert beyond_limits(dyn, U) == {"commands_beyond_limits": 0}
    U[3, 5] = 2.5 * lim[5]
    U[4, 1] = -1.5 * lim[1]
    np.testing.assert_array_equal(  # the plant applies the limit
        dyn.rollout(task.x0, U), dyn.rollout(task.x0, np.clip(U, -lim, lim))
    )
    m = beyond_limits(dyn, U)
    assert m["commands_beyond_limits"] == 2 and m["max_command_over_limit"] == pytest.approx(2.5)
    assert (
        m["max_command_over_limit_actuator"]
        == dyn.plant.get_joint_actuator(dyn.plant.GetJointActuatorIndices()[5]).name()
    )
    assert any("exceed" in line for line in summary_lines(m))


def test_a_given_x0_has_its_quaternions_normalized_like_the_task_files():
    from hydroilqr import Task

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


def test_python_dash_m_runs_the_command_line():
    import subprocess
    import sys

    r = subprocess.run(
        [sys.executable, "-m", "hydroilqr", "tasks"], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0 and "cartpole-wall" in r.stdout


def test_a_failed_command_leaves_no_empty_output_directory(tmp_path, monkeypatch):
    from hydroilqr.cli import main
    from hydroilqr.model.plant import SimulationError
    from hydroilqr.solver import api

    def fail(*a, **k):
        raise SimulationError("contact solver did not converge")

    monkeypatch.setattr(api, "solve", fail)
    new = tmp_path / "new" / "run"
    assert main(["solve", "cartpole-wall", "--smoke", "--no-replay", "--out", str(new)]) == 3
    assert not (tmp_path / "new").exists()  # nor the parent made for it
    kept = tmp_path / "kept"
    kept.mkdir()
    (kept / "notes.txt").write_text("mine")
    assert main(["solve", "cartpole-wall", "--smoke", "--no-replay", "--out", str(kept)]) == 3
    assert (kept / "notes.txt").exists()  # a directory the user made stays


def test_check_warns_that_a_rigid_geometrys_modulus_is_unused():
    from hydroilqr import Task
    from hydroilqr.problem.check import check_task

    task = Task.load(
        "cartpole-wall",
        ["geometry.tip.compliance=rigid", "geometry.tip.resolution_hint=0.01"],
        smoke=True,
    )
    out = check_task(task)
    assert any("hydroelastic_modulus is not used" in w for w in out["warnings"])


def test_final_gains_are_regularized_only_as_q_uu_needs():
    """A solve that ends with a large μ (here it starts at 1e3) still returns the feedback of
    eq. (8): the backward pass around the final trajectory at the smallest workable μ, not
    gains shrunk to ~0 by the solver's μ."""
    from hydroilqr import Task
    from hydroilqr.model.derivatives import linearize
    from hydroilqr.solver.ilqr import backward_pass, solve

    task = Task.load(
        "cartpole-wall",
        ["solver.regularization_init=1000", "solver.derivatives=central"],
        smoke=True,
    )
    s = task.config.solver
    for its in (1, 3):
        sol = solve(task.problem(), task.initial_guess(task.steps), s, max_iterations=its)
        assert sol.mu[-1] >= 1.0  # the solver's μ is still large
        assert sol.extra["gains_mu"] == s.regularization_min
        A, B = linearize(task.dynamics, sol.X, sol.U, "central", s.fd_epsilon)
        bp = backward_pass(A, B, task.cost.quadratize(sol.X, sol.U), s.regularization_min)
        np.testing.assert_allclose(sol.K, bp.K, rtol=1e-6, atol=1e-9)


def test_mpc_smoke_runs_a_few_updates_unless_a_duration_is_given(tmp_path):
    import json

    from hydroilqr.cli import main
    from hydroilqr.control.mpc import SMOKE_UPDATES

    assert main(["mpc", "cartpole-wall", "--smoke", "--out", str(tmp_path / "a")]) == 0
    doc = json.loads((tmp_path / "a" / "mpc.json").read_text())
    assert doc["duration_s"] == pytest.approx(SMOKE_UPDATES / doc["requested_rate_hz"])
    argv = ["mpc", "cartpole-wall", "--smoke", "--duration", "0.2", "--out", str(tmp_path / "b")]
    assert main(argv) == 0
    assert json.loads((tmp_path / "b" / "mpc.json").read_text())["duration_s"] == 0.2


def test_worker_processes_exit_when_their_parent_is_killed(tmp_path):
    """kill -9 of a solve must not leave its worker processes (each holding a plant) behind."""
    import os
    import signal
    import subprocess
    import sys
    import time

    script = tmp_path / "pool.py"
    script.write_text(
        "import sys, time\n"
        "from hydroilqr import Task\nfrom hydroilqr.model import workers\n"
        "task = Task.load('kinova-forward', ['solver.autodiff_workers=2'], smoke=True)\n"
        "workers.warm_up(task.dynamics, 2)\n"
        "pool = workers.pool(task.dynamics, 2)\n"
        "print(' '.join(str(p) for p in pool._processes), flush=True)\n"
        "time.sleep(600)\n"
    )
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        pids = [int(p) for p in proc.stdout.readline().split()]
        assert pids
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()

    def alive(pid: int) -> bool:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        # a zombie child of init counts as gone
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"

    deadline = time.time() + 20
    while any(alive(p) for p in pids) and time.time() < deadline:
        time.sleep(0.2)
    assert not any(alive(p) for p in pids)


def test_a_member_given_after_its_group_overrides_it():
    """--set initial_state.joint_2=... over a task's group arm_q changes that joint only."""
    from hydroilqr import Task

    base = Task.load("kinova-forward", smoke=True)
    task = Task.load("kinova-forward", ["initial_state.joint_2=1.0"], smoke=True)
    j2 = task.dynamics.layout.block("joint_2").coords[0]
    assert task.x0[j2] == 1.0
    others = np.ones(task.dynamics.nx, bool)
    others[j2] = False
    np.testing.assert_array_equal(task.x0[others], base.x0[others])


def test_sibling_defaults_agree():
    """Linearizer and linearize read X the same way by default (not as a rollout of U);
    PlaybackSettings picks the CLI's default speed per policy; batch_step is step, batched."""
    from hydroilqr import Task
    from hydroilqr.control.playback import PlaybackSettings
    from hydroilqr.model.derivatives import Linearizer, batch_step, linearize

    task = Task.load("cartpole-wall", ["num_steps=5", "solver.derivatives=forward"])
    dyn = task.dynamics
    U = np.zeros((5, 1))
    X = dyn.rollout(task.x0, U) + 0.01  # not a rollout of U
    A1, B1 = linearize(dyn, X, U, "forward")
    A2, B2 = Linearizer.from_settings(dyn, task.config.solver)(X, U)
    np.testing.assert_array_equal(A1, A2)
    np.testing.assert_array_equal(B1, B2)
    assert PlaybackSettings(policy="ilqr").speed == 1.0 and PlaybackSettings().speed == 0.5
    nxt = batch_step(dyn, X[:5], U)
    np.testing.assert_array_equal(nxt[2], dyn.step(X[2], U[2]))


def test_debug_variable_shows_tracebacks_for_config_errors(monkeypatch):
    from hydroilqr.cli import main
    from hydroilqr.problem.config import ConfigError

    monkeypatch.setenv("HYDROILQR_DEBUG", "1")
    with pytest.raises(ConfigError):
        main(["check", "cartpole-wall", "--set", "solver.max_iterations=-1"])


def test_a_runs_resolved_config_is_a_task_file_and_parent_smoke_paths_anchor(tmp_path):
    """summary.json's config solves as a YAML task file (one trajectory length), and a
    parent's smoke: paths are relative to the parent's own directory."""
    import json

    import yaml

    from hydroilqr import Task
    from hydroilqr.cli import main

    out = tmp_path / "run"
    argv = ["solve", "cartpole-wall", "--smoke", "--set", "num_steps=12", "--no-replay"]
    assert main([*argv, "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    cfg = summary["config"]
    assert "horizon" not in cfg and cfg["num_steps"] == 12
    for m in cfg["models"]:  # relative to base_dir, as documented
        m["file"] = str(Path(summary["base_dir"]) / m["file"])
    f = tmp_path / "again.yaml"
    f.write_text(yaml.safe_dump(cfg))
    assert Task.from_yaml(f).steps == 12

    parent_dir = tmp_path / "p"
    parent_dir.mkdir()
    np.savetxt(parent_dir / "U.csv", np.zeros((5, 1)), delimiter=",")
    (parent_dir / "parent.yaml").write_text(
        yaml.safe_dump({**cfg, "smoke": {"num_steps": 5, "initial_guess": "U.csv"}})
    )
    (tmp_path / "child.yaml").write_text("extends: p/parent.yaml\nname: child\n")
    task = Task.load(str(tmp_path / "child.yaml"), smoke=True)
    assert Path(task.config.initial_guess) == parent_dir / "U.csv"


def test_ctrl_c_while_results_are_written_waits_for_them():
    import os
    import signal

    from hydroilqr.output.report import deferred_interrupt

    done = []
    with pytest.raises(KeyboardInterrupt, match="written first"):
        with deferred_interrupt():
            os.kill(os.getpid(), signal.SIGINT)
            done.append("the rest of the block ran")
    assert done
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_plan_being_played_is_not_replaced_and_playback_dirs_hold_no_runs(tmp_path):
    import json

    from hydroilqr.output import report
    from hydroilqr.problem.config import ConfigError

    run = tmp_path / "run"
    run.mkdir()
    (run / "summary.json").write_text(json.dumps({"task": "t"}))
    with pytest.raises(ConfigError, match="playback directory"):
        report.output_dir(run / "playback-pd", "t")
    assert report.output_dir(run / "playback-pd", "t", playback=True).is_dir()
    # another process reads (plays) the run: a solve into it is refused meanwhile
    import subprocess
    import sys

    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import sys, time; from pathlib import Path; from hydroilqr.output import report; "
         f"report.read_lock(Path({str(run)!r})); print('held', flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(ConfigError, match="in use by another hydroilqr run"):
            report._lock(run)
    finally:
        holder.kill()
        holder.wait()


def test_an_ignored_sigint_stays_ignored_and_a_read_lock_upgrades(tmp_path):
    import os
    import signal

    from hydroilqr.output import report

    old = signal.signal(signal.SIGINT, signal.SIG_IGN)  # e.g. a background job
    try:
        with report.deferred_interrupt():
            os.kill(os.getpid(), signal.SIGINT)  # ignored: nothing raised afterwards
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, old)
    report.read_lock(tmp_path)  # playback RUN --out RUN: reads, then writes the same dir
    report._lock(tmp_path)
    key = str(tmp_path.resolve())
    assert key in report._LOCKS and key not in report._READ_LOCKS
    os.close(report._LOCKS.pop(key))


def test_extends_names_the_child_of_a_missing_parent_and_the_childs_smoke_length_wins(tmp_path):
    from hydroilqr import Task
    from hydroilqr.problem.config import TASKS_DIR, ConfigError

    (tmp_path / "orphan.yaml").write_text("extends: nope.yaml\n")
    with pytest.raises(ConfigError, match="orphan.yaml: extends: no such file"):
        Task.load(str(tmp_path / "orphan.yaml"))
    (tmp_path / "parent.yaml").write_text(
        f"extends: {TASKS_DIR / 'cartpole-wall.yaml'}\nsmoke: {{num_steps: 25}}\n"
    )
    (tmp_path / "child.yaml").write_text("extends: parent.yaml\nname: c\nsmoke: {horizon: 0.3}\n")
    task = Task.load(str(tmp_path / "child.yaml"), smoke=True)
    assert task.steps == round(0.3 / task.config.plant.time_step)


def test_set_with_both_horizon_and_num_steps_is_refused_like_a_task_file():
    from hydroilqr import Task
    from hydroilqr.problem.config import ConfigError

    with pytest.raises(ConfigError, match="horizon or num_steps, not both"):
        Task.load("cartpole-wall", ["horizon=0.3", "num_steps=7"])
    assert Task.load("cartpole-wall", ["horizon=0.3"]).steps == 30


def test_set_smoke_keys_change_what_smoke_applies():
    from hydroilqr import Task

    t = Task.load(
        "cartpole-wall", ["smoke.num_steps=5", "smoke.solver.max_iterations=2"], smoke=True
    )
    assert t.steps == 5 and t.config.solver.max_iterations == 2
    assert t.config.solver.derivatives == Task.load("cartpole-wall").config.solver.derivatives


def test_set_an_empty_path_means_none_not_the_working_directory(tmp_path, monkeypatch):
    from hydroilqr.problem.config import load_task

    monkeypatch.chdir(tmp_path)  # it became str(cwd): "cannot read <cwd>/solution.npz"
    cfg = load_task("cartpole-wall", ['cost.reference=""', 'mpc.warm_start_plan=""'])
    assert cfg.cost.reference == "" and cfg.mpc.warm_start_plan == ""


def test_set_smoke_length_or_whole_section_changes_what_smoke_applies():
    from hydroilqr.problem.config import ConfigError, load_task

    # kinova's smoke section gives num_steps: 10; a --set smoke.horizon was silently ignored
    cfg = load_task("kinova-forward", ["smoke.horizon=0.05"], smoke=True)
    assert cfg.steps == round(0.05 / cfg.plant.time_step)
    assert load_task("cartpole-wall", ["smoke={num_steps: 3}"], smoke=True).steps == 3  # was 200
    with pytest.raises(ConfigError, match="smoke.horizon or smoke.num_steps, not both"):
        load_task("cartpole-wall", ["smoke.horizon=0.05", "smoke.num_steps=3"], smoke=True)


def test_atomic_writes_leave_the_old_file_when_a_write_fails(tmp_path, monkeypatch):
    import os

    import numpy as np

    from hydroilqr.output import files

    p = files.atomic_write(tmp_path / "a.json", '{"old": 1}')
    files.atomic_savez(tmp_path / "a.npz", X=np.arange(3.0))
    with np.load(tmp_path / "a.npz") as d:
        assert d["X"].tolist() == [0.0, 1.0, 2.0]

    def full_disk(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", full_disk)
    with pytest.raises(OSError):
        files.atomic_write(p, '{"new": 2}')
    assert p.read_text() == '{"old": 1}'  # untouched, and no temporary file left behind
    assert sorted(q.name for q in tmp_path.iterdir()) == ["a.json", "a.npz"]


def test_absurd_lengths_and_non_finite_saved_plans_are_refused(tmp_path):
    import numpy as np

    from hydroilqr.control.mpc import MPCSettings
    from hydroilqr.problem.config import ConfigError, load_task
    from hydroilqr.problem.task import Task
    from hydroilqr.solver.solution import Solution

    for bad in (["horizon=2e6"], ["num_steps=20000000"]):
        with pytest.raises(ConfigError, match="at most 1000000"):
            load_task("cartpole-wall", bad)  # it would allocate and run for ever
    with pytest.raises(ConfigError, match="receding_horizon: .* more than 1000000"):
        load_task("cheetah-trot-1.0", ["receding_horizon.resolves=10000000"])
    task = Task.load("cartpole-wall", smoke=True)
    with pytest.raises(ConfigError, match="mpc horizon 1e\\+06 s: more than"):
        MPCSettings(horizon=1e6).check(task)
    from hydroilqr.solver.api import solve

    sol = solve(task.with_overrides({"solver.max_iterations": 1}))
    sol.U[3, 0] = np.nan
    p = sol.save(tmp_path / "plan")
    with pytest.raises(ValueError, match="its U holds non-finite"):
        Solution.load(p)


def test_an_ascii_text_encoding_is_named_in_the_import_error():
    """pydrake 1.51 cannot import under LC_ALL=C with PYTHONUTF8=0; the package says what to
    set instead of Drake's bare "initialization failed"."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "LC_ALL": "C", "PYTHONUTF8": "0"}
    p = subprocess.run(
        [sys.executable, "-c", "import hydroilqr"], env=env, capture_output=True, text=True
    )
    assert p.returncode != 0
    assert "PYTHONUTF8=1" in p.stderr.strip().splitlines()[-1]
