"""`hydroilqr solve` and its run directory: outputs, Ctrl+C keeps the best-so-far, re-runs
replace old results, runs never mix, one-line refusals."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import numpy as np
import pytest

from hydroilqr import IterationTable, Solution, Task, cli, solve
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.solver import SolverConfig
from hydroilqr.solver.loop import solve as ilqr_solve
from tests.conftest import ACROBOT_TASK as TASK
from tests.conftest import BASE, assert_one_line, edit, write_case, write_task


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


def test_cli_solve_writes_outputs(tmp_path):
    import json

    from hydroilqr.cli import main

    out = tmp_path / "run"
    assert (
        main(
            [
                "solve",
                "cartpole-wall",
                "--smoke",
                "--set",
                "solver.max_iterations=2",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    summary = json.loads((out / "summary.json").read_text())
    for key in (
        "task",
        "converged",
        "iterations",
        "final_cost",
        "iteration_seconds",
        "phase_seconds",
        "derivatives",
        "metrics",
    ):
        assert key in summary
    for key in ("final_angle_error_rad", "max_overlap_m", "wall_contact_steps"):
        assert key in summary["metrics"]
    for f in ("solution.npz", "convergence.png", "replay.html"):
        assert (out / f).stat().st_size > 0
    assert "<html" in (out / "replay.html").read_text()[:2000].lower()


def test_ctrl_c_during_a_solve_writes_the_best_so_far(tmp_path, monkeypatch, capsys):
    seen = []

    def interrupt_at_third(self, info):
        seen.append(info.cost)
        if info.iteration == 3:
            raise KeyboardInterrupt

    monkeypatch.setattr(IterationTable, "__call__", interrupt_at_third)
    out = tmp_path / "out"
    goal = {"final_error.angles": {"max": 1e-9}}
    task = write_task(tmp_path, goal=goal)
    rc = cli.main(["solve", str(task), "--out", str(out), "--no-replay"])
    assert rc == 130
    sol = Solution.load(out / "solution.npz")
    summary = json.loads((out / "summary.json").read_text())
    assert sol.reason == summary["reason"] == "interrupted" and not sol.converged
    # Three iterations were recorded; the saved trajectory is the one whose cost is last.
    assert len(sol.costs) == 4 and len(sol.iteration_seconds) == 3
    assert sol.costs[-1] == seen[-1] < sol.costs[0]
    printed = capsys.readouterr().out
    assert "interrupted" in printed
    # the goal judged in summary.json is printed too (issue 39, 4)
    assert summary["goal"]["judged"] and summary["goal"]["met"] is False
    assert "goal: FAIL" in printed and "(the plan kept at Ctrl+C)" in printed


def test_resolving_replaces_earlier_results_and_refuses_another_tasks_dir(tmp_path, capsys):
    out = tmp_path / "out"
    (out / "playback-ilqr").mkdir(parents=True)
    (out / "playback-ilqr" / "playback.json").write_text("{}")
    (out / "gait.png").write_bytes(b"old")
    (out / "notes.txt").write_text("mine")
    (out / "summary.json").write_text(json.dumps({"task": "cheetah-trot-1.0"}))
    task = write_task(tmp_path, solver={"max_iterations": 2})
    rc = cli.main(["solve", str(task), "--out", str(out), "--no-replay"])
    err = capsys.readouterr().err
    assert rc == 2 and "holds the results of task 'cheetah-trot-1.0'" in err
    (out / "summary.json").write_text(json.dumps({"task": TASK["name"]}))
    assert cli.main(["solve", str(task), "--out", str(out), "--no-replay"]) == 0
    assert not (out / "gait.png").exists() and not (out / "playback-ilqr").exists()
    assert (out / "notes.txt").read_text() == "mine"  # not ours: left alone
    summary = json.loads((out / "summary.json").read_text())
    assert summary["task"] == TASK["name"]
    # Provenance: contact-rich results move with last-bit differences, so every result says
    # what produced it.
    env = summary["environment"]
    assert env["drake"] == version("drake") and env["python"] == platform.python_version()
    assert env["numpy"] and env["cores"] >= 1 and env["cpu"]
    assert env["command"] == f"hydroilqr solve {task} --out {out} --no-replay"
    from hydroilqr.io import environment

    assert not hasattr(environment, "COMMAND")  # no global: nothing carried into later calls
    assert environment.environment()["command"] is None


def test_a_failed_resolve_keeps_the_earlier_results(tmp_path, monkeypatch, capsys):
    """Old results go only when the new solve has a trajectory to write in their place."""
    out = tmp_path / "out"
    task = write_task(tmp_path, solver={"max_iterations": 2})
    assert cli.main(["solve", str(task), "--out", str(out), "--no-replay"]) == 0
    (out / "playback-pd").mkdir()
    (out / "playback-pd" / "playback.json").write_text("{}")
    before = (out / "solution.npz").read_bytes()

    def fail(*args, **kwargs):
        raise RuntimeError("the simulation diverged")

    monkeypatch.setattr("hydroilqr.solver.api.solve", fail)
    assert cli.main(["solve", str(task), "--out", str(out), "--no-replay"]) != 0
    assert (out / "solution.npz").read_bytes() == before
    assert (out / "summary.json").exists() and (out / "playback-pd" / "playback.json").exists()


def test_task_name_and_task_file_together_is_an_error(tmp_path, capsys):
    rc = cli.main(["solve", "cartpole-wall", "--task-file", str(write_task(tmp_path))])
    assert rc == 2 and "not both" in capsys.readouterr().err


def test_interrupted_ilqr_statistics_are_consistent():
    """stop_on_interrupt: every per-iteration list has one entry per recorded iteration."""
    from hydroilqr.model.task import Task

    calls = []

    def stop(info):
        calls.append(info)
        if len(calls) == 2:
            raise KeyboardInterrupt

    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        task = Task.load(str(write_task(Path(d))))
    sol = ilqr_solve(
        task.problem(), task.initial_guess(20), SolverConfig(), [stop], stop_on_interrupt=True
    )
    n = len(sol.costs) - 1
    assert sol.reason == "interrupted" and n >= 2
    assert len(sol.iteration_seconds) == len(sol.eps) == len(sol.mu) == n
    assert all(len(v) == n for v in sol.phase_seconds.values())
    np.testing.assert_allclose(task.cost.total(sol.X, sol.U, 0.0), sol.costs[-1])


def test_a_smoke_solve_says_how_short_it_is(tmp_path, capsys):
    """Issue 39, 13: a smoke plan (and its replay) is too short to show the task's motion."""
    task = write_task(tmp_path, smoke={"num_steps": 3, "solver.max_iterations": 1})
    out = str(tmp_path / "o")
    assert cli.main(["solve", str(task), "--smoke", "--out", out, "--no-replay"]) == 0
    printed = " ".join(capsys.readouterr().out.split())
    assert "--smoke: the task shrunk to 3 steps (0.06 s of motion)" in printed
    assert "too short for the motion the task is for" in printed


def test_a_solve_that_never_steps_says_why(tmp_path, capsys):
    # Zero state weights: the zero guess is already optimal, so no step is ever taken.
    task = write_task(tmp_path, cost={"R": 0.01}, solver={"max_iterations": 3})
    assert cli.main(["solve", str(task), "--out", str(tmp_path / "o"), "--no-replay"]) == 0
    assert "no step was taken" in capsys.readouterr().out


def test_a_run_directory_loads_as_a_solution_and_playback_wants_the_directory(tmp_path, capsys):
    out = tmp_path / "out"
    task = write_task(tmp_path, solver={"max_iterations": 2})
    assert cli.main(["solve", str(task), "--out", str(out), "--no-replay"]) == 0
    assert Solution.load(out).X.shape == Solution.load(out / "solution.npz").X.shape
    capsys.readouterr()
    assert cli.main(["playback", str(out / "summary.json")]) == 2
    assert "give the run directory" in capsys.readouterr().err
    (out / "solution.npz").write_text("not an npz")
    assert cli.main(["playback", str(out)]) == 2
    assert "cannot read" in capsys.readouterr().err


def test_one_run_per_output_directory_at_a_time(tmp_path):
    import time

    from hydroilqr.output.report import output_dir
    from hydroilqr.problem.errors import ConfigError

    out = tmp_path / "shared"
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from hydroilqr.output.report import output_dir; "
            f"output_dir({str(out)!r}, 'cartpole-wall'); print('locked', flush=True); "
            "time.sleep(60)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(ConfigError, match="in use by another hydroilqr run"):
            output_dir(out, "cartpole-wall")
    finally:
        holder.kill()
        holder.wait()
    time.sleep(0.1)
    assert output_dir(out, "cartpole-wall") == out  # released when its process ended
    assert output_dir(out, "cartpole-wall") == out  # and this process may ask again


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only directories")
def test_a_read_only_run_directory_is_refused_before_the_solve(tmp_path, capsys):
    """Its lock file, left by the earlier run, still opens for writing: the directory itself
    must be checked, or the whole solve runs and then fails on its first file."""
    out = tmp_path / "kept"
    out.mkdir()
    (out / "summary.json").write_text(json.dumps({"task": "cartpole-wall"}))
    (out / ".hydroilqr.lock").write_text("1")
    out.chmod(0o555)
    try:
        rc = cli.main(["solve", "cartpole-wall", "--smoke", "--out", str(out)])
    finally:
        out.chmod(0o755)
    assert rc == 2
    captured = capsys.readouterr()
    assert f"--out {out}: not writable (Permission denied)" in captured.err
    assert "iter" not in captured.out  # refused before solving
    assert sorted(p.name for p in out.iterdir()) == [".hydroilqr.lock", "summary.json"]


def test_a_finished_command_leaves_no_lock_file(tmp_path):
    out = tmp_path / "run"
    task = write_task(tmp_path, num_steps=10, solver={"max_iterations": 1})
    assert cli.main(["solve", str(task), "--out", str(out), "--no-replay"]) == 0
    fast = ["--truth-time-step", "0.005", "--rest-max", "0", "--no-replay"]
    assert cli.main(["playback", str(out), *fast]) == 0
    assert (out / "playback-pd" / "playback.json").is_file()
    assert not list(tmp_path.rglob(".hydroilqr.lock"))


def test_a_full_disk_at_the_lock_leaves_no_directory_or_lock_file(tmp_path, capsys, monkeypatch):
    """Issue 39: the lock file of a new directory was left behind when writing it failed."""
    import errno

    from hydroilqr.output import report

    real_write = os.write

    def full(fd, data):
        if data == str(os.getpid()).encode():
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(fd, data)

    monkeypatch.setattr(report.os, "write", full)
    out = tmp_path / "new" / "run"
    rc = cli.main(["solve", str(write_task(tmp_path)), "--out", str(out), "--no-replay"])
    cap = capsys.readouterr()
    assert rc == 2 and "No space left on device" in cap.err
    assert not list(tmp_path.rglob(".hydroilqr.lock")) and not (tmp_path / "new").exists()


def test_solution_files_are_written_whole(tmp_path):
    task = Task.load("cartpole-wall", ["num_steps=5", "solver.max_iterations=1"])
    path = solve(task).save(tmp_path / "s")
    assert path.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["s.npz"]


def test_out_that_is_a_file_or_another_tasks_directory(tmp_path, capsys):
    path = write_case(tmp_path, BASE)
    (tmp_path / "afile").write_text("x")
    rc = cli.main(["solve", str(path), "--out", str(tmp_path / "afile"), "--no-replay"])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "exists and is not a directory")
    other = tmp_path / "other"
    other.mkdir()
    (other / "mpc.json").write_text('{"task": "cartpole-wall"}')
    rc = cli.main(["mpc", str(path), "--duration", "0.1", "--out", str(other), "--no-replay"])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "holds the results of task 'cartpole-wall'")


def test_overflowing_cost_is_an_error_not_a_finish(tmp_path, capsys):
    path = write_case(
        tmp_path, edit(cost__Qf={"angles": 1e308}, initial_state={"angles": [2.0, 1.0]})
    )
    rc = cli.main(["solve", "--task-file", str(path), "--out", str(tmp_path / "o"), "--no-replay"])
    cap = capsys.readouterr()
    assert rc != 0 and "Traceback" not in cap.err and "RuntimeWarning" not in cap.err
    lines = [ln for ln in cap.err.splitlines() if ln.strip()]
    # (refused with the task, before the cost of the guess overflows: issue 39)
    assert len(lines) == 1 and "cost.Qf.angles: 1e+308 is too large" in lines[0], cap.err
    assert not (tmp_path / "o" / "solution.npz").exists()


def test_a_run_directory_named_like_the_task_is_not_a_task_file(tmp_path, monkeypatch):
    from hydroilqr.problem.load import load_task

    monkeypatch.chdir(tmp_path)
    (tmp_path / "cartpole-wall").mkdir()  # e.g. `solve cartpole-wall --out cartpole-wall`
    assert load_task("cartpole-wall").name == "cartpole-wall"
    (tmp_path / "mine.yaml").mkdir()
    with pytest.raises(ConfigError, match="a directory, not a task YAML file"):
        load_task("mine.yaml")


@pytest.mark.parametrize("kind", ["symlink", "dangling", "hardlink"])
def test_a_lock_file_that_links_outside_is_never_followed(tmp_path, capsys, kind):
    """Issue 39: a .hydroilqr.lock that is a link changes no file outside the run (solve and
    playback refuse it in one line)."""
    outside = tmp_path / "outside.txt"
    if kind != "dangling":
        outside.write_text("precious")
    out = tmp_path / "run"
    out.mkdir()
    lock = out / ".hydroilqr.lock"
    if kind == "hardlink":
        os.link(outside, lock)
    else:
        os.symlink(outside, lock)
    task = write_task(tmp_path)
    rc = cli.main(["solve", str(task), "--out", str(out), "--no-replay"])
    cap = capsys.readouterr()
    assert rc == 2 and "not a lock file hydroilqr made" in cap.err
    assert len(cap.err.strip().splitlines()) == 1
    if kind == "dangling":
        assert not outside.exists()
    else:
        assert outside.read_text() == "precious"
    rc = cli.main(["playback", str(out)])
    assert rc == 2 and "not a lock file hydroilqr made" in capsys.readouterr().err


def test_check_robust_resolves_perturbed_guesses_and_reports_the_spread(tmp_path, capsys):
    """Issue 54, item 13: `solve --check-robust K` says whether a result sits on a knife
    edge: K more solves from last-bit perturbed guesses, the goal's pass rate and each
    check's spread, also in summary.json."""
    path = write_case(tmp_path, edit(goal={"final_error.angles": {"max": 10.0}}))
    out = tmp_path / "run"
    argv = ["solve", "--task-file", str(path), "--no-replay", "--out", str(out)]
    assert cli.main([*argv, "--check-robust", "2"]) == 0
    printed = capsys.readouterr().out
    assert "check-robust: goal met in" in printed and "final_error.angles: min" in printed
    cr = json.loads((out / "summary.json").read_text())["check_robust"]
    assert cr["runs"] == 2 and len(cr["results"]) == 2 and cr["noise"] == 1e-9
    values = [r["values"]["final_error.angles"] for r in cr["results"]]
    s = cr["check_spread"]["final_error.angles"]
    assert (s["min"], s["max"]) == (min(values), max(values))
    assert cr["goal_met"] == sum(v <= 10.0 for v in values)
    rc = cli.main([*argv, "--check-robust", "2", "--starts", "2"])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "--check-robust")
