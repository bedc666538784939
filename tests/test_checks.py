"""`hydroilqr check` warnings and config validation at the edges (from a mutation-testing
round: each test kills a mutation the rest of the suite let through). Smoke-sized."""

from __future__ import annotations

import numpy as np
import pytest

from hydroilqr import Task

# ------------------------------------------------------------------------------------------
# check.py
# ------------------------------------------------------------------------------------------


def _check(task, **kw):
    import io

    from rich.console import Console

    from hydroilqr.check import check_task

    return check_task(task, Console(file=io.StringIO()), **kw)


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
    from hydroilqr.config import ConfigError, load_task

    extra = ["solver.regularization_min=1e-6"] if "regularization_max" in override else []
    with pytest.raises(ConfigError, match=needle.replace(".", r"\.")):
        load_task("cartpole-wall", [*extra, override])


def test_settings_at_the_edges_of_their_ranges_are_accepted():
    from hydroilqr.config import load_task

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
    from hydroilqr.config import load_task

    urdf = "package://drake/examples/pendulum/Pendulum.urdf"
    (tmp_path / "base.yaml").write_text(
        f"models: [{{file: '{urdf}'}}]\nhorizon: 0.5\ncost: {{R: 0.1}}\n"
    )
    (tmp_path / "child.yaml").write_text("extends: base.yaml\nnum_steps: 3\n")
    assert load_task(str(tmp_path / "child.yaml")).steps == 3


def test_geometry_overrides_by_dotted_name_and_shorthand_errors():
    from hydroilqr.config import ConfigError, load_task

    cfg = load_task("cartpole-wall", ["geometry.my.tip.friction=0.3"])
    assert cfg.geometry["my.tip"].friction == 0.3  # a geometry name with a dot in it
    # A geometry the task names: a far-off key is reported against its contact properties.
    with pytest.raises(ConfigError, match=r"geometry\.tip\.youngs: unknown key"):
        load_task("cartpole-wall", ["tip.youngs=1e6"])  # (not a near-miss of a property)
    # A name that is both a scene object and a geometry entry is ambiguous.
    with pytest.raises(ConfigError, match="names both a scene object and a geometry entry"):
        load_task("cartpole-wall", ["geometry.wall.friction=0.3", "wall.dissipation=1"])
