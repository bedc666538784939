"""What `hydroilqr check` prints, without a solve: warnings and tables (issue 39, 7 and 8)."""

from __future__ import annotations

import io

import numpy as np
from rich.console import Console

from hydroilqr.studies.check import _autodiff_point_warning


def _pair(shapes: str, model: str = "point (fallback)") -> dict:
    return {"a": "a (A)", "b": "b (B)", "shapes": shapes, "model": model}


def test_the_autodiff_point_contact_warning_names_only_pairs_without_a_sphere():
    spheres = [_pair("Sphere/Sphere"), _pair("Sphere/HalfSpace"), _pair("Box/Sphere")]
    assert _autodiff_point_warning(spheres, "autodiff") == ""
    w = _autodiff_point_warning([*spheres, _pair("Box/Box")], "autodiff")
    assert w.startswith("1 point-contact pair(s) without a sphere") and "(Box/Box)" in w
    assert _autodiff_point_warning([_pair("Box/Box")], "central") == ""
    assert _autodiff_point_warning([_pair("Box/Box", "hydroelastic")], "autodiff") == ""


def test_check_tables_keep_names_whole_in_80_columns(monkeypatch):
    """The names a user copies into `geometry:`, `cost.R` or `blocks` are not cut with '…'."""
    from hydroilqr.cli import check

    buf = io.StringIO()
    monkeypatch.setattr(check, "console", Console(file=buf, width=80, highlight=False))
    names = ["FL_hip_abduction_collision_with_a_long_name", "base_link_of_the_robot"]
    check._geometries(
        {
            "model": {"contact_approximation": "sap"},
            "geometries": [
                {"name": n, "body": n, "shape": "Sphere", "kind": "compliant", "modulus": 1e6,
                 "resolution_hint": 0.01, "friction": 0.5, "relaxation_time": None,
                 "dissipation": None}
                for n in names
            ],
            "geometry_overrides": {},
        }
    )  # fmt: skip
    check._actuators(
        {"actuators": [{"name": names[0], "joint": names[1], "effort_limit": 18.0,
                        "rotor_inertia": 0.0, "gear_ratio": 1.0, "reflected_inertia": 0.0}]}
    )  # fmt: skip
    out = buf.getvalue()
    assert "…" not in out
    for n in names:
        assert n in out


def test_check_warns_of_search_damping_an_explicit_step_cannot_keep_stable():
    """hopper-hop's position-space search at its own kd is inside every joint's 2·I/dt (no
    warning); at a kd between its two lowest joints' bounds the warning names exactly the
    joint whose bound is below it; no search, no warning."""
    from hydroilqr.model.pd import damping_bounds
    from hydroilqr.model.task import Task
    from hydroilqr.problem.load import load_task
    from hydroilqr.studies.check import pd_damping_warning

    task = Task(load_task("hopper-hop"))
    dyn = task.dynamics
    bounds = damping_bounds(dyn.plant, task.x0, dyn.dt)
    joints = [
        dyn.plant.get_joint_actuator(i).joint().name() for i in dyn.plant.GetJointActuatorIndices()
    ]
    assert pd_damping_warning(dyn, task.x0, task.config.search) == ""
    kd = (sorted(bounds)[0] + sorted(bounds)[1]) / 2
    low = Task(load_task("hopper-hop", [f"search.kd={kd}"]))
    w = pd_damping_warning(low.dynamics, low.x0, low.config.search)
    named = [j for j in joints if f"{j} (" in w]
    assert named == [joints[int(np.argmin(bounds))]], w
    assert pd_damping_warning(dyn, task.x0, None) == ""
