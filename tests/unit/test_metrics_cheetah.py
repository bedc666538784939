"""metrics.cheetah on synthetic contact patterns."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from hydroilqr import Task


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
