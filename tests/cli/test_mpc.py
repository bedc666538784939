"""`hydroilqr mpc` options checked at the command line."""

from __future__ import annotations

import pytest

from hydroilqr import cli
from tests.conftest import BASE, assert_one_line, write_case


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


@pytest.mark.parametrize(
    "option",
    [
        ["--duration", "nan"],
        ["--rate", "inf"],
        ["--threads", "-2"],
        ["--push", "nan:lower_link:1,0,0"],
        ["--push-duration", "nan", "--push", "0.01:lower_link:1,0,0"],
        ["--push-duration", "0.2"],
    ],
)
def test_mpc_rejects_non_finite_or_negative_options(tmp_path, capsys, option):
    path = write_case(tmp_path, BASE)
    rc = cli.main(["mpc", str(path), "--out", str(tmp_path / "o"), "--no-replay", *option])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, option[0].lstrip("-").split("-")[0])


def test_mpc_goal_judges_the_closed_loop_apart_from_the_plan_goal(tmp_path, capsys):
    """Issue 38: ``mpc.goal`` is what the loop must achieve; without it the task's goal."""
    import json

    from hydroilqr.cli import main

    out = tmp_path / "loop"
    argv = ["mpc", "cartpole-wall", "--duration", "0.1", "--no-replay", "--out", str(out)]
    lenient = "mpc.goal={final_error.pole_angle: {max: 1000.0}}"
    assert main([*argv, "--set", lenient]) == 0
    goal = json.loads((out / "mpc.json").read_text())["goal"]
    assert goal["source"] == "mpc.goal" and goal["met"] is True
    assert [c["metric"] for c in goal["checks"]] == ["final_error.pole_angle"]
    assert "mpc.goal, on the closed loop" in capsys.readouterr().out
    assert main([*argv, "--set", "mpc.goal.final_error.pole_angle.max=1e-9"]) == 4
    assert json.loads((out / "mpc.json").read_text())["goal"]["met"] is False
    assert main(argv) in (0, 4)  # no mpc.goal: the task's goal judges the loop
    assert json.loads((out / "mpc.json").read_text())["goal"]["source"] == "goal"
    capsys.readouterr()
    rc = main([*argv, "--set", "mpc.goal={nosuch_metric: {max: 1}}"])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "mpc.goal.nosuch_metric")


def test_the_task_files_realtime_and_feedback_scale_apply_unless_the_command_line_says(
    tmp_path,
):
    """A task's ``mpc.realtime`` and ``mpc.feedback_scale`` are its defaults (the options
    only override them); mpc.json records them and the derivative method in use."""
    import json

    from hydroilqr.cli import main

    out = tmp_path / "o"
    argv = ["mpc", "cartpole-wall", "--smoke", "--no-replay", "--out", str(out)]
    task_says = ["--set", "mpc.realtime=true", "--set", "mpc.feedback_scale=0"]
    assert main([*argv, *task_says]) in (0, 4)
    doc = json.loads((out / "mpc.json").read_text())
    assert doc["realtime_mode"] is True and doc["feedback_scale"] == 0.0
    assert doc["derivatives"] in ("autodiff", "forward", "central")
    assert main([*argv, *task_says, "--no-realtime", "--feedback-scale", "0.5"]) in (0, 4)
    doc = json.loads((out / "mpc.json").read_text())
    assert doc["realtime_mode"] is False and doc["feedback_scale"] == 0.5


def test_commands_beyond_limits_counts_what_the_controller_asked_not_what_was_applied(tmp_path):
    """The applied inputs are clipped; the metric counts the commands that were clipped, as
    the saturation warning does."""
    import json

    import numpy as np

    from hydroilqr.cli import main

    out = tmp_path / "o"
    argv = ["mpc", "hopper-forward", "--smoke", "--rate", "20", "--horizon", "0.5"]
    assert main([*argv, "--plant-time-step", "0.01", "--no-replay", "--out", str(out)]) in (0, 4)
    doc = json.loads((out / "mpc.json").read_text())
    n = np.load(out / "mpc.npz")["U"].size
    assert doc["metrics"]["commands_beyond_limits"] == round(doc["saturated_fraction"] * n)
    assert doc["metrics"]["commands_beyond_limits"] > 0  # this loop's hops ask beyond limits
    assert doc["metrics"]["max_command_to_limit_ratio"] > 1.0  # of the asked commands


@pytest.mark.parametrize(
    "option, needle",
    [
        (["--plan-set", "mpc.rate=10"], "mpc.plan_overrides"),
        (["--plan-set", "goal.final_angle_error_rad.max=10"], "mpc.plan_overrides"),
        (["--plan-set", "ensemble=[{tip.friction: 0.1}]"], "mpc.plan_overrides"),
        (["--push", "0.096:cart:-20,0,0"], "--push at 0.096"),
        (["--push", "0.05:cart:-20,0,0", "--push-duration", "0.001"], "--push-duration"),
    ],
)
def test_settings_the_loop_would_not_apply_as_asked_are_refused(tmp_path, capsys, option, needle):
    """A plan override of a key no plan reads, and a push that is not whole simulated steps
    (it would be rounded: moved, lengthened or dropped), are one-line errors."""
    argv = ["mpc", "cartpole-wall", "--smoke", "--no-replay", "--out", str(tmp_path / "o")]
    rc = cli.main([*argv, *option])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, needle)


def test_mpc_with_the_sampling_planner_records_its_samples(tmp_path, capsys):
    """``--planner sampling`` (issue 52): the loop runs, mpc.json names the planner and the
    samples each update took; a bad sampler setting is one line before any work."""
    import json

    from hydroilqr.cli import main

    small = ["--set", "search.samples=4", "--set", "search.iterations=2", "--set",
             "search.knots=2", "--set", "mpc.sampling_workers=1"]  # fmt: skip
    out = tmp_path / "s"
    argv = ["mpc", "cartpole-wall", "--smoke", "--planner", "sampling", "--duration", "0.03"]
    assert main([*argv, *small, "--no-replay", "--out", str(out)]) == 0
    doc = json.loads((out / "mpc.json").read_text())
    assert doc["planner"] == "sampling" and doc["sampling"]["samples_per_update_mean"] == 4
    assert "sampler (sampling): 4 samples per update" in capsys.readouterr().out
    rc = main([*argv, *small, "--set", "mpc.samples=1", "--out", str(tmp_path / "t")])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "mpc.samples")
