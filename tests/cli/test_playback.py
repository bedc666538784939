"""`hydroilqr playback` beside `hydroilqr solve` on the same run directory."""

from __future__ import annotations

import pytest


def test_a_plan_being_played_is_not_replaced_and_playback_dirs_hold_no_runs(tmp_path):
    import json

    from hydroilqr.output import report
    from hydroilqr.problem.errors import ConfigError

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


@pytest.fixture(scope="module")
def acrobot_run(tmp_path_factory):
    """A two-iteration solve of the tiny acrobot task (its elbow is actuated) to play back."""
    from hydroilqr import cli
    from tests.conftest import write_task

    tmp = tmp_path_factory.mktemp("acro")
    task = write_task(tmp, num_steps=10, solver={"max_iterations": 2})
    assert cli.main(["solve", str(task), "--out", str(tmp / "run"), "--no-replay"]) in (0, 4)
    return tmp / "run"


def test_the_feedforward_is_in_the_header_and_playback_json(acrobot_run, tmp_path, capsys):
    import json

    from hydroilqr import cli

    fast = ["--truth-time-step", "0.005", "--rest-max", "0", "--no-replay"]
    capsys.readouterr()
    for extra, name in (([], "scaled"), (["--feedforward", "plan"], "plan")):
        out = tmp_path / name
        assert cli.main(["playback", str(acrobot_run), *fast, *extra, "--out", str(out)]) in (0, 4)
        header = capsys.readouterr().out.splitlines()[0]
        assert f"pd playback at speed 0.5, feed-forward {name}, truth dt=0.005" in header
        data = json.loads((out / "playback.json").read_text())
        assert data["settings"]["feedforward"] == name
        assert ("--feedforward plan" in data["environment"]["command"]) == (name == "plan")


def test_feedforward_with_the_ilqr_policy_is_refused_not_ignored(acrobot_run, tmp_path, capsys):
    from hydroilqr import cli
    from tests.conftest import assert_one_line

    out = str(tmp_path / "pb")
    args = ["playback", str(acrobot_run), "--policy", "ilqr", "--out", out]
    rc = cli.main([*args, "--feedforward", "plan"])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "--feedforward: options of the PD+ loop")
    rc = cli.main([*args, "--kp", "100", "--feedforward", "scaled"])
    assert rc == 2 and "--kp, --feedforward: options" in capsys.readouterr().err


def test_a_damping_law_mismatch_is_noted_and_recorded(acrobot_run, tmp_path, capsys, monkeypatch):
    """SAP damps contact by relaxation times, the other approximations by Hunt-Crossley
    dissipation: a playback across the two says so, one within a law does not, nor one of a
    plan without contact (the acrobot's: issue 39, 6)."""
    import json

    from hydroilqr import cli
    from hydroilqr.control import playback

    fast = ["--truth-time-step", "0.005", "--rest-max", "0", "--no-replay"]
    capsys.readouterr()
    args = ["playback", str(acrobot_run), *fast, "--truth-contact", "similar"]
    assert cli.main([*args, "--out", str(tmp_path / "none")]) in (0, 4)
    assert "damps contact" not in capsys.readouterr().out  # the acrobot touches nothing
    monkeypatch.setattr(playback, "plan_touches", lambda task, X: True)  # as if it did
    for truth, noted in (("similar", True), ("sap", False)):
        out = tmp_path / truth
        args = ["playback", str(acrobot_run), *fast, "--truth-contact", truth, "--out", str(out)]
        assert cli.main(args) in (0, 4)
        printed = capsys.readouterr().out
        assert ("note: the planner (sap) damps contact by relaxation times" in printed) == noted
        data = json.loads((out / "playback.json").read_text())
        assert data["planner"]["damping"] == "relaxation_time"
        assert data["truth"]["damping"] == ("hunt_crossley" if noted else "relaxation_time")


def test_a_smoke_plans_playback_records_its_goal_as_not_judged(acrobot_run, tmp_path, capsys):
    """As its solve did (summary.json ``smoke: true``); a full plan's playback is judged."""
    import json

    from hydroilqr import cli
    from tests.conftest import write_task

    task = write_task(tmp_path, num_steps=10, solver={"max_iterations": 2})
    smoke = tmp_path / "smoke"
    assert cli.main(["solve", str(task), "--smoke", "--out", str(smoke), "--no-replay"]) == 0
    fast = ["--truth-time-step", "0.005", "--rest-max", "0", "--no-replay"]
    for run, judged in ((smoke, False), (acrobot_run, True)):
        out = tmp_path / f"pb-{judged}"
        assert cli.main(["playback", str(run), *fast, "--out", str(out)]) in (0, 4)
        goal = json.loads((out / "playback.json").read_text())["goal"]
        assert goal["judged"] is judged


def test_a_joint_without_a_motor_leads_with_the_plan_end_gap(acrobot_run, tmp_path, capsys):
    """Issue 39, 6: the acrobot's shoulder has no motor, so the hold after the plan cannot hold
    it: the headline is the gap at the plan's end, the unheld rest after it is secondary;
    playback.json says where executed_metrics' final values were taken."""
    import json

    from hydroilqr import cli

    out = tmp_path / "pb"
    fast = ["--truth-time-step", "0.005", "--rest-max", "0.1", "--no-replay", "--out", str(out)]
    capsys.readouterr()
    assert cli.main(["playback", str(acrobot_run), "--policy", "ilqr", *fast]) in (0, 4)
    printed = " ".join(capsys.readouterr().out.split())
    assert "object shoulder: final gap" in printed
    data = json.loads((out / "playback.json").read_text())
    assert "; after the plan, unheld (no motor): resting gap" in printed
    if not data["object"]["rest"]["planned"]["rested"]:  # still swinging (issue 54, item 2)
        assert "against the plan's extension still moving (see the warning)" in printed
        assert "did not come to rest" in data["object"]["resting_gap_caveat"]
    assert data["executed_metrics_final_state"] == "end of the hold after the plan"


@pytest.mark.parametrize(
    "option, needle",
    [
        (["--rest-max", "1e9"], "rest-max"),  # a hold of 1e12 truth steps: refused, not run
    ],
)
def test_a_playback_hold_too_long_is_refused(acrobot_run, tmp_path, capsys, option, needle):
    from hydroilqr import cli
    from tests.conftest import assert_one_line

    rc = cli.main(["playback", str(acrobot_run), "--out", str(tmp_path / "pb"), *option])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, needle)


def test_a_truth_step_off_the_tasks_grid_is_named_as_the_option():
    """The task's own check of its horizon under the truth's step, worded for the option."""
    from hydroilqr import Task
    from hydroilqr.control.playback import PlaybackSettings, truth_config
    from hydroilqr.problem.errors import ConfigError

    task = Task.load("cartpole-wall")  # 2 s, no num_steps: the horizon must be whole steps
    with pytest.raises(ConfigError, match=r"^playback truth-time-step 0.003 s: horizon"):
        truth_config(task, PlaybackSettings(truth_time_step=0.003))
    assert truth_config(task, PlaybackSettings(truth_time_step=0.002)).plant.time_step == 0.002
