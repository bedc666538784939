"""What a user sees of goals, status, multi-start and crash-safe result sets through
``hydroilqr solve`` (small acrobot task: a few seconds each)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from hydroilqr import cli
from hydroilqr.cli.solve import GOAL_NOT_MET
from hydroilqr.io import rundir
from tests.conftest import ACROBOT_TASK
from tests.conftest import write_task as write_acrobot_task

TASK = {
    **ACROBOT_TASK,
    "name": "trust-acrobot",
    "solver": {"max_iterations": 15},
    "metrics": ["default"],
}


def write_task(tmp_path, **changes):
    return write_acrobot_task(tmp_path, TASK, **changes)


def summary(out):
    return json.loads((out / "summary.json").read_text())


def _complete_run(tmp_path):
    out = tmp_path / "run"
    assert cli.main(["solve", str(write_task(tmp_path)), "--out", str(out), "--no-replay"]) == 0
    return out, (out / "solution.npz").read_bytes(), summary(out)


def _solve_in_a_process(task, out, kill_at: str = ""):
    env = {**os.environ, rundir.KILL_ENV: kill_at}
    cmd = [sys.executable, "-m", "hydroilqr", "solve", task, "--out", str(out), "--no-replay"]
    return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)


def test_goal_pass_and_fail_reach_the_terminal_json_and_exit_code(tmp_path, capsys):
    ok = write_task(tmp_path, goal={"steps": {"min": 20}})
    assert cli.main(["solve", str(ok), "--out", str(tmp_path / "a"), "--no-replay"]) == 0
    s = summary(tmp_path / "a")
    assert s["goal"]["met"] is True and s["goal"]["checks"][0]["value"] == 20
    assert "goal: PASS (1/1 checks)" in capsys.readouterr().out
    bad = write_task(tmp_path, goal={"final_error.angles": {"max": 1e-9}})
    rc = cli.main(["solve", str(bad), "--out", str(tmp_path / "b"), "--no-replay"])
    assert rc == GOAL_NOT_MET == 4
    s = summary(tmp_path / "b")
    assert s["goal"]["met"] is False and "> 1e-09" in s["goal"]["checks"][0]["why"]
    assert "goal: FAIL (0/1 checks): final_error.angles" in capsys.readouterr().out


def test_a_smoke_run_reports_its_goal_but_is_not_judged(tmp_path, capsys):
    bad = write_task(tmp_path, goal={"final_error.angles": {"max": 1e-9}})
    rc = cli.main(["solve", str(bad), "--smoke", "--out", str(tmp_path / "s"), "--no-replay"])
    assert rc == 0
    assert "(smoke-sized run: not judged)" in capsys.readouterr().out
    assert summary(tmp_path / "s")["goal"]["met"] is False


def test_status_is_written_and_printed(tmp_path, capsys):
    task = write_task(tmp_path)
    assert cli.main(["solve", str(task), "--out", str(tmp_path / "o"), "--no-replay"]) == 0
    s = summary(tmp_path / "o")
    assert s["status"] in ("converged", "stalled", "max_iterations")
    assert s["converged"] == (s["status"] in ("converged", "stalled"))
    assert f"status {s['status']} after " in capsys.readouterr().out


def test_multistart_keeps_the_best_and_reports_the_spread(tmp_path, capsys, dask_scheduler):
    task = write_task(tmp_path, goal={"steps": {"min": 20}})
    out = tmp_path / "m"
    argv = ["solve", str(task), "--out", str(out), "--no-replay", "--starts", "2"]
    assert cli.main([*argv, "--scheduler", dask_scheduler, "--start-noise", "0.5"]) == 0
    ms = summary(out)["multistart"]
    assert ms["starts"] == ms["finished"] == 2 and ms["goal_met"] == 2
    assert [r["index"] for r in ms["results"]] == [0, 1]
    best = ms["results"][ms["best"]]
    assert best["final_cost"] == ms["best_cost"] == min(r["final_cost"] for r in ms["results"])
    assert abs(summary(out)["final_cost"] - ms["best_cost"]) <= 1e-9 * abs(ms["best_cost"])
    text = capsys.readouterr().out
    assert "multi-start: 2 solves (seed 0)" in text and "start 1: status " in text
    # the last lines: all starts' time, then the best start's line with its own time
    assert "all 2 starts took " in text
    assert f"cost {best['final_cost']:.6g}, {best['seconds']:.2f} s" in text


def test_multistart_arguments_are_checked_before_work(tmp_path, capsys):
    task = str(write_task(tmp_path))
    for extra, message in [
        (["--starts", "0"], "--starts: must be from 1 to 1000"),
        (["--scheduler", "tcp://127.0.0.1:1"], "go with --starts N"),
        (["--starts", "2", "--start-noise", "-1"], "--start-noise: must be a finite number"),
        (["--starts", "2", "--start-noise", "inf"], "--start-noise: must be a finite number"),
        (["--starts", "2", "--start-noise", "nan"], "--start-noise: must be a finite number"),
        (["--starts", "100000000"], "--starts: must be from 1 to 1000"),
        (["--starts", "2", "--workers", "-1"], "--workers: must be at least 1"),
        (["--starts", "2", "--workers", "0"], "--workers: must be at least 1"),
        (["--starts", "2", "--seed", "-1"], "--seed: must be at least 0"),
        (["--seed", "3"], "--seed and --start-noise go with --starts N"),  # else ignored
        (["--start-noise", "0.2"], "--seed and --start-noise go with --starts N"),
    ]:
        assert cli.main(["solve", task, "--out", str(tmp_path / "x"), *extra]) == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_a_run_failing_after_the_solve_leaves_the_earlier_set(tmp_path, capsys, monkeypatch):
    out, npz, first = _complete_run(tmp_path)
    from hydroilqr import metrics

    def broken(*a, **k):
        raise RuntimeError("a metric failed")

    monkeypatch.setattr(metrics, "compute", broken)
    rc = cli.main(["solve", str(write_task(tmp_path)), "--out", str(out), "--no-replay"])
    assert rc == 1 and "a metric failed" in capsys.readouterr().err
    assert (out / "solution.npz").read_bytes() == npz and summary(out) == first
    assert not (out / rundir.STAGE).exists()


def test_a_full_disk_while_writing_leaves_the_earlier_set(tmp_path, capsys, monkeypatch):
    import errno

    out, npz, first = _complete_run(tmp_path)
    from hydroilqr.output import results

    real = results.write_json

    def full(path, data):
        real(path, data)
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(results, "write_json", full)
    rc = cli.main(["solve", str(write_task(tmp_path)), "--out", str(out), "--no-replay"])
    assert rc == 1 and "No space left on device" in capsys.readouterr().err
    assert (out / "solution.npz").read_bytes() == npz and summary(out) == first


def test_resolving_retires_old_playbacks_and_never_follows_a_symlink(tmp_path):
    out, _, _ = _complete_run(tmp_path)
    (out / "playback-pd").mkdir()
    (out / "playback-pd" / "playback.json").write_text('{"task": "trust-acrobot"}')
    target = tmp_path / "keep"
    target.mkdir()
    (target / "playback.json").write_text("precious")
    (out / "playback-ilqr").symlink_to(target)
    (out / "notes.txt").write_text("mine")
    assert cli.main(["solve", str(write_task(tmp_path)), "--out", str(out), "--no-replay"]) == 0
    assert not (out / "playback-pd").exists()  # derived from the earlier plan
    assert (target / "playback.json").read_text() == "precious"
    assert (out / "notes.txt").read_text() == "mine"


def test_killed_while_writing_results_leaves_one_complete_set(tmp_path):
    out = tmp_path / "run"  # (another process: this one would hold the directory's lock)
    assert _solve_in_a_process(str(write_task(tmp_path)), out).returncode == 0
    first, npz = summary(out), (out / "solution.npz").read_bytes()
    task = str(write_task(tmp_path, solver={"max_iterations": 3}))
    # Killed before the journal and half-way through installing: a solve's commit is
    # io.rundir's (tests/unit/test_rundir.py kills one at every step of it).
    for step in ("staged", "install:1"):
        proc = _solve_in_a_process(task, out, step)
        assert proc.returncode == -9, proc.stderr
        rundir.recover(out)
        s = summary(out)
        if step == "staged":  # before the journal: the earlier set, untouched
            assert s == first and (out / "solution.npz").read_bytes() == npz
        else:  # after it: the new set, whole
            assert s["iterations"] <= 3 and s["config"]["solver"]["max_iterations"] == 3
        from hydroilqr import Solution

        assert Solution.load(out).final_cost == s["final_cost"]
        names = {p.name for p in out.iterdir() if not p.name.startswith(".")}
        assert names == {"summary.json", "solution.npz", "convergence.png", "contacts.png"}
        first, npz = s, (out / "solution.npz").read_bytes()


def test_a_playback_written_into_the_run_directory_is_retired_by_the_next_solve(tmp_path):
    out, _, _ = _complete_run(tmp_path)
    stale = ("playback.json", "playback.npz", "reference.csv", "playback.png")
    for name in stale:  # as `hydroilqr playback RUN --out RUN` leaves them
        (out / name).write_text("of the earlier plan")
    assert cli.main(["solve", str(write_task(tmp_path)), "--out", str(out), "--no-replay"]) == 0
    assert not any((out / name).exists() for name in stale)
    assert (out / "summary.json").exists()


def test_a_goal_on_a_metric_the_task_never_reports_is_refused_before_solving(tmp_path, capsys):
    bad = write_task(tmp_path, goal={"final_eror.angles": {"max": 0.1}})
    rc = cli.main(["solve", str(bad), "--out", str(tmp_path / "g"), "--no-replay"])
    err = capsys.readouterr().err
    assert (
        rc == 2 and "goal.final_eror.angles" in err and "did you mean 'final_error.angles'" in err
    )
    assert not (tmp_path / "g").exists()
    other = write_task(tmp_path, goal={"steps": {"above": "nosuch"}})
    assert cli.main(["solve", str(other), "--out", str(tmp_path / "h")]) == 2
    assert "goal.steps.above: 'nosuch'" in capsys.readouterr().err


def test_a_smoke_runs_goal_is_recorded_as_not_judged(tmp_path):
    task = write_task(tmp_path, goal={"steps": {"min": 1}})
    assert cli.main(["solve", str(task), "--smoke", "--out", str(tmp_path / "s")]) == 0
    assert summary(tmp_path / "s")["goal"]["judged"] is False
    assert cli.main(["solve", str(task), "--out", str(tmp_path / "f"), "--no-replay"]) == 0
    assert summary(tmp_path / "f")["goal"]["judged"] is True
