"""studies.sweep pure logic: values and grids."""

from __future__ import annotations

import pytest


def test_parse_values_and_grid_edges():
    from hydroilqr.problem.errors import ConfigError
    from hydroilqr.studies.sweep import grid, parse_values

    assert parse_values("linspace:0:0.3:4") == [0.0, 0.1, 0.2, 0.3]  # not 0.09999999999999999
    with pytest.raises(ConfigError, match="positive START and STOP"):
        parse_values("logspace:1:0:3")
    with pytest.raises(ConfigError, match="positive START and STOP"):
        parse_values("logspace:1:-10:3")
    g = grid([("a", [1, 2]), ("b", [3, 4, 5])])
    assert g == [{"a": a, "b": b} for a in (1, 2) for b in (3, 4, 5)]  # first varies slowest


def test_a_sweep_line_speaks_solves_status_words():
    """Issue 54, item 7: a point's line has solve's status and stop test, and names its
    worker (it said "not converged (stop test max_iterations) ... on 0")."""
    from hydroilqr.cli.sweep import describe
    from hydroilqr.studies.sweep import solve_point

    row = solve_point("cartpole-wall", None, True, {}, {"solver.max_iterations": 1}, "p0")["row"]
    assert row["status"] == "ok" and row["solve_status"] == "max_iterations"
    line = describe(row, ["solver.max_iterations"])
    assert "status max_iterations after 1 iterations (stop test: max_iterations)" in line
    assert f"on worker {row['worker']}" in line and "not converged" not in line


def test_a_sweep_point_has_its_goal_and_the_plot_a_goal_panel(tmp_path):
    """Issue 54, item 6: a goal column per point and the goal's metric plotted with its
    bound."""
    from hydroilqr.cli.sweep import describe
    from hydroilqr.problem.goal import GoalCheck
    from hydroilqr.studies.sweep import goal_panels, plot_sweep, solve_point

    row = solve_point("cartpole-wall", None, True, {"solver.max_iterations": 1}, {}, "p0")["row"]
    met = row["final_angle_error_rad"] <= 0.05 and row["wall_contact_steps"] >= 1  # its goal
    assert row["goal_met"] is met
    assert describe(row, []).endswith(f"goal {'PASS' if met else 'FAIL'}")
    goal = {"final_cost": GoalCheck(max=1.0e9), "x": GoalCheck(above="y")}
    assert goal_panels(goal) == [("final_cost", "final_cost\n(goal: <= 1e+09)")]
    rows = [{**row, "param:a": 1.0}, {**row, "param:a": 2.0, "goal_met": False}]
    plot_sweep(tmp_path / "s.png", "t", ["a"], rows, [[1.0, 2.0]], goal_panels(goal), goal)
    assert (tmp_path / "s.png").stat().st_size > 1000
