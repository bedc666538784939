"""Metrics, cost terms and the quaternion-aware state difference, checked against hand-built
trajectories and contact patterns (from a mutation-testing round: each test kills a mutation the
rest of the suite let through). Smoke-sized."""

from __future__ import annotations

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
    from hydroilqr import metrics_cheetah as mc

    sol, feet, faces, body, S = _synthetic_cheetah_run(cheetah)
    monkeypatch.setattr(mc, "contacts", lambda task, s: (feet, faces, body))
    monkeypatch.setattr(mc, "foot_slip_speeds", lambda task, s: S)
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
    assert m["max_foot_faces"] == 9
    assert m["mean_foot_faces"] == pytest.approx(faces[feet].mean())
    assert m["mean_foot_faces"] > faces.mean()  # over touching states only
    assert m["iterations_per_resolve"] == 3.0 and m["resolve_seconds"] == pytest.approx(0.2)


def test_foot_slip_is_zero_for_feet_rolling_on_their_lowest_points(cheetah):
    """The whole robot rolls about the line through the feet's lowest points (x axis): those
    material points stand still, the sphere centres (one radius above) do not."""
    from hydroilqr.metrics_cheetah import foot_slip_speeds

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
    from hydroilqr import metrics_kinova as mk

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
    monkeypatch.setattr(mk, "contact_pairs", lambda dyn, x: pairs.get(keys[x.tobytes()], []))
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
    from hydroilqr.metrics import cartpole_wall

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
    from hydroilqr.config import ConfigError
    from hydroilqr.solution import Solution

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
    from hydroilqr.state import Block, StateLayout

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


def test_layout_quaternion_values_are_unit_and_checked():
    from hydroilqr.config import ConfigError

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
