"""Issue 53, 20: `check` prints the force a compliant geometry makes at a few overlaps,
measured with Drake, so a point contact's stiffness can be matched by the modulus."""

from __future__ import annotations

import math

import pytest

from hydroilqr import Task, cli
from hydroilqr.studies.check import geometry_table
from hydroilqr.studies.stiffness import pressed_forces


def _tip(*overrides: str):
    dyn = Task.load("cartpole-wall", list(overrides), smoke=True).dynamics
    (tip,) = [g for g in geometry_table(dyn) if g["name"] == "tip"]
    return dyn, tip["id"]


def _sphere_force(E: float, R: float, d: float) -> float:
    """A sphere's hydroelastic force on a rigid plane at overlap d (pressure E·(R - |x|)/R,
    integrated over the plane's disc inside the sphere)."""
    c = R - d
    a2 = R * R - c * c
    return 2 * math.pi * E / R * (R * a2 / 2 - (R**3 - c**3) / 3)


def test_a_finely_meshed_sphere_pressed_into_a_plane_gives_the_known_force():
    dyn, gid = _tip("geometry.tip.resolution_hint=0.0025")  # radius 0.05 m, 2e6 Pa
    for row in pressed_forces(dyn, gid, (0.002, 0.005)):
        exact = _sphere_force(2e6, 0.05, row["overlap_m"])
        assert row["force_n"] == pytest.approx(exact, rel=0.03)
        assert row["stiffness_n_per_m"] == pytest.approx(row["force_n"] / row["overlap_m"])


def test_the_force_scales_with_the_modulus_and_a_coarse_mesh_gives_less():
    coarse = pressed_forces(*_tip())  # hint 0.02: the mesh lies inside the sphere
    doubled = pressed_forces(*_tip("geometry.tip.hydroelastic_modulus=4e6"))
    for a, b in zip(coarse, doubled, strict=True):
        assert b["force_n"] == pytest.approx(2 * a["force_n"], rel=1e-9)
        assert a["force_n"] < _sphere_force(2e6, 0.05, a["overlap_m"])
    assert [r["overlap_m"] for r in coarse] == [0.0005, 0.001, 0.002, 0.005]


def test_check_prints_the_forces_of_each_compliant_geometry_on_a_moving_body(capsys):
    assert cli.main(["check", "cartpole-wall"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "compliant geometries pressed into a rigid plane" in out
    assert "tip (pole) (modulus 2e+06 Pa):" in out and " N at 1 mm (" in out


def test_check_counts_faces_per_pair_and_measures_a_coarser_mesh_of_the_busiest(capsys):
    """Issue 53, 15: the faces of each pair along the guess, the time per step, the geometry
    whose mesh decides the count, and the same guess with its hint doubled, measured."""
    from hydroilqr.studies.step_cost import MIN_FACES, step_cost_report

    fine = Task.load("cartpole-wall", ["geometry.tip.resolution_hint=0.004"], smoke=True)
    report = step_cost_report(fine, 50)
    (pair,) = report["now"]["pairs"]
    assert pair["pair"] == ["tip (pole)", "wall (world)"] and pair["max_faces"] >= MIN_FACES
    assert report["geometry"] == "pole/tip" and report["resolution_hint"] == 0.004
    coarse = report["coarser"]
    assert 0 < coarse["max_faces"] < pair["max_faces"]
    assert coarse["ms_in_contact"] > 0 and report["now"]["ms_without_contact"] > 0
    assert step_cost_report(Task.load("cartpole-wall", smoke=True), 50)["coarser"] is None
    assert cli.main(["check", "cartpole-wall", "--set", "geometry.tip.resolution_hint=0.004"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "contact faces along 50 steps of the guess: tip (pole)/wall (world) up to" in out
    assert "most faces: pole/tip (resolution_hint 0.004); with 0.008, measured: up to" in out
