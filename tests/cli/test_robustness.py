"""``hydroilqr robustness``: perturbed solves on Dask, pass rates, the results-page section."""

from __future__ import annotations

import json

import numpy as np

from hydroilqr import Task, cli, solve
from hydroilqr.studies import results
from hydroilqr.studies.multistart import perturbation
from hydroilqr.studies.robustness import RunResult, summarize, table


def _run(k, met, checks, status="stalled"):
    return RunResult(
        task="t",
        index=k,
        status=status,
        iterations=3,
        final_cost=1.0,
        goal_met=met,
        checks=[{"metric": m, "passed": p, "value": 1.0} for m, p in checks],
    )


def test_summary_counts_the_goal_and_each_check():
    runs = [
        _run(1, True, [("a", True), ("b", True)]),
        _run(2, False, [("a", True), ("b", False)]),
        _run(3, False, [("a", False), ("b", False)], status="no_progress"),
    ]
    s = summarize("t", runs)
    assert (s["runs"], s["goal_met"], s["checks_met"]) == (3, 1, {"a": 2, "b": 1})
    assert abs(s["pass_rate"] - 1 / 3) < 1e-12
    assert s["statuses"] == {"no_progress": 1, "stalled": 2}
    assert s["results"][1]["failed_checks"] == ["b"]
    assert "| `t` | 1 of 3 | a 2/3, b 1/3 |" in table({"tasks": [s]})


def test_transfer_summary_counts_the_played_back_goal_and_the_resting_gaps():
    runs = [_run(k, True, [("a", True)]) for k in (1, 2, 3)]
    runs[0].transfer = {
        "goal_met": True,
        "failed_checks": [],
        "values": {"a": 0.01},
        "resting_gap": 0.01,
    }
    runs[1].transfer = {
        "goal_met": False,
        "failed_checks": ["a"],
        "values": {"a": 0.04},
        "resting_gap": 0.3,
    }
    runs[2].transfer = {"error": "SimulationError: diverged"}
    s = summarize("t", runs)
    assert s["transfer"] == {
        "played": 3,
        "goal_met": 1,
        "failed": 1,
        "executed_values": {"a": {"min": 0.01, "median": 0.025, "max": 0.04}},
        "median_resting_gap": 0.155,
        "max_resting_gap": 0.3,
    }
    assert s["results"][1]["transfer"]["failed_checks"] == ["a"]
    assert "| `t` | 3 of 3 | 1 of 3 | 15.5 / 30.0 |" in table({"tasks": [s], "transfer": True})
    assert "transfer" not in summarize("t", [_run(1, True, [("a", True)])])


def test_a_perturbed_plan_is_played_back_as_the_transfer_section_plays_it():
    from hydroilqr.control.playback import HALF_SPEED, PlaybackSettings, executed_goal, playback
    from hydroilqr.studies.robustness import solve_run

    ref = {
        "label": "kinova-left",
        "name": "kinova-left",
        "overrides": [],
        "config": None,
        "smoke": True,
    }
    r = solve_run(ref, 1, 0, 1e-9, transfer=True)
    task = Task.load("kinova-left", smoke=True)
    U0 = perturbation(
        task.initial_guess(task.config.steps), task.dynamics.effort_limits, 1e-9, 0, 1
    )
    sol = solve(task, U0=U0)
    pb = playback(task, sol, PlaybackSettings(**HALF_SPEED))
    gap = pb.metrics["object"]["resting_gap"]
    assert r.transfer["resting_gap"] == gap  # the same plan, played back the same way
    goal = executed_goal(task, sol, pb)["goal"]
    assert r.transfer["goal_met"] == goal["met"]
    assert r.transfer["values"] == {c["metric"]: c["value"] for c in goal["checks"]}


def test_perturbation_is_relative_reproducible_and_differs_per_run():
    U = np.array([[1.0, -2.0]] * 20)
    a, b = (perturbation(U, np.full(2, np.inf), 1e-9, 0, k) for k in (1, 2))
    assert np.array_equal(a, perturbation(U, np.full(2, np.inf), 1e-9, 0, 1))
    assert not np.array_equal(a, b) and not np.array_equal(a, U)
    assert np.max(np.abs(a - U) / np.abs(U)) < 1e-8


def test_receding_task_takes_its_first_windows_guess():
    one = ["receding_horizon.resolves=1"]  # (the first window is the one U0 seeds)
    task = Task.load("cheetah-trot-1.0", one, smoke=True)
    W = task.config.receding_horizon.window_steps
    U0 = task.initial_guess(W)
    same = solve(task, U0=U0)
    again = solve(Task.load("cheetah-trot-1.0", one, smoke=True))
    assert np.array_equal(same.X, again.X)
    try:
        solve(task, U0=U0[:-1])
    except ValueError as e:
        assert "first window's guess" in str(e)
    else:
        raise AssertionError("a guess of the wrong length was accepted")


def test_robustness_command_writes_pass_rates_and_the_results_section(
    tmp_path, capsys, dask_scheduler
):
    out = tmp_path / "docs"
    small = ["num_steps=30", "solver.max_iterations=3"]  # (what is asked is the record's shape)
    argv = ["robustness", "cartpole-wall", "--smoke", "--runs", "2", "--scheduler", dask_scheduler]
    argv += [f"--set={s}" for s in small]
    assert cli.main([*argv, "--transfer", "--out", str(out / "robustness")]) == 0
    text = capsys.readouterr().out
    assert "cartpole-wall run 1:" in text and "cartpole-wall run 2:" in text
    doc = json.loads((out / "robustness" / "robustness.json").read_text())
    (t,) = doc["tasks"]
    assert t["task"] == "cartpole-wall" and t["runs"] == 2
    assert [r["index"] for r in t["results"]] == [1, 2]
    assert doc["noise"] == 1e-9 and doc["environment"]["drake"]
    assert doc["command"].startswith("hydroilqr robustness cartpole-wall")
    # (the page's robustness section alone: the others are tests/cli/test_results.py's)
    page = results.generate(
        ["cartpole-wall"], out=out, smoke=True, overrides=small, sections=[results.robustness_table]
    )
    md = page["md"].read_text()
    assert "## Robustness to last-bit differences" in md and "equally valid local minima" in md
    # --transfer: each plan also played back
    assert "played back: goal" in text
    assert doc["transfer"] and t["transfer"]["played"] == 2
    assert set(t["results"][0]["transfer"]) >= {"goal_met", "resting_gap"}
    assert "goal met (played back)" in md and "each plan also played back" in md


def test_robustness_arguments_are_refused_before_work(tmp_path, capsys):
    for extra, message in [
        (["--runs", "0"], "--runs: must be between 1 and"),
        (["--noise", "nan"], "--noise: must be a number in [0, 1]"),
        (["--seed", "-1"], "--seed: must be >= 0"),
        (["--workers", "0"], "--workers: must be at least 1"),
        (["--min-rate", "2"], "--min-rate"),
        (["--set", "solver.max_iterations=-3"], "max_iterations"),
        (["--set", "goal={no_such_metric: {max: 1}}"], "no_such_metric"),  # checked as solve
        (["--set", "metrics=[default, nosuchset]"], "nosuchset"),
    ]:
        rc = cli.main(["robustness", "cartpole-wall", "--out", str(tmp_path / "r"), *extra])
        assert rc == 2, extra
        assert message in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


def test_robustness_refuses_an_output_it_cannot_write_before_any_solve(tmp_path, capsys):
    a_file = tmp_path / "afile"
    a_file.write_text("")
    rc = cli.main(["robustness", "cartpole-wall", "--smoke", "--runs", "1", "--out", str(a_file)])
    err = capsys.readouterr().err
    assert rc == 2 and "--out" in err and "Traceback" not in err


def test_one_worker_runs_one_solve_at_a_time_and_each_solves_threads_are_stated(tmp_path):
    """Issue 53, 17: how many solves ran at once is measured (their start and end times) and
    each solve's threads are recorded, so contended times are visible."""
    from hydroilqr.model.derivatives import num_threads
    from hydroilqr.studies.robustness import run_robustness

    small = ["num_steps=30", "solver.max_iterations=3"]  # (how the solves end is not asked)
    ref = {"label": "c", "name": "cartpole-wall", "overrides": small, "config": None, "smoke": True}
    report = run_robustness([ref], runs=2, workers=1)
    assert report["workers"] == 1 and report["most_solves_at_once"] == 1
    (task,) = report["tasks"]
    runs = task["results"]
    assert all(r["threads"] == num_threads(0) for r in runs)  # (central differences, threads 0)
    spans = sorted((r["started"], r["finished"]) for r in runs)
    assert all(a[1] <= b[0] for a, b in zip(spans, spans[1:]))  # one after another
    assert report["threads_per_solve"] == {"c": num_threads(0)}


def test_the_spread_of_each_check_shows_how_close_the_runs_came():
    """Issue 54, item 6: "3 of 3" with one run 1.3 mm inside a 20 mm limit says so."""
    from hydroilqr.metrics.goals import evaluate
    from hydroilqr.problem.goal import GoalCheck
    from hydroilqr.studies.robustness import spread_lines

    goal = {"target_error_m": GoalCheck(max=0.02)}
    runs = []
    for k, v in enumerate([0.004, 0.0187, 0.009], start=1):
        g = evaluate(goal, {"target_error_m": v})
        runs.append(_run(k, g["met"], []))
        runs[-1].checks = g["checks"]
    s = summarize("t", runs)
    spread = s["check_spread"]["target_error_m"]
    assert (spread["min"], spread["median"], spread["max"]) == (0.004, 0.009, 0.0187)
    assert spread["worst"] == 0.0187 and abs(spread["worst_slack"] - 0.0013) < 1e-12
    (line,) = spread_lines({"tasks": [s]})
    assert "min 0.004, median 0.009, max 0.0187; worst 0.0187 against <= 0.02" in line


def test_the_results_section_shows_each_rows_kernel_set_and_the_closed_loops():
    """The page's first robustness table: a column per BLAS kernel set the records were
    measured on (their environment's blas_core), a row per task, kind of run and seed; a
    closed-loop record (--mpc) is its own row."""

    def doc(blas, met, mpc=False, seed=0):
        s = summarize("t", [_run(k, k <= met, [("a", k <= met)]) for k in range(1, 11)])
        return {"tasks": [s], "mpc": mpc, "seed": seed, "environment": {"blas_core": blas}}

    md = results.kernel_table(
        [doc("Haswell", 7), doc("SkylakeX", 9), doc("Haswell", 10, mpc=True), doc("X", 8, seed=1)]
    )
    lines = md.splitlines()
    assert lines[0] == (
        "| task | run | seed | goal met, Haswell kernels | goal met, SkylakeX kernels "
        "| goal met, X kernels |"
    )
    assert "| `t` | solve | 0 | 7 of 10 | 9 of 10 | - |" in lines
    assert "| `t` | closed loop | 0 | 10 of 10 | - | - |" in lines
    assert "| `t` | solve | 1 | - | - | 8 of 10 |" in lines


def test_the_results_section_puts_each_stacks_pass_rates_side_by_side():
    """Records that name their Python and Drake get a column per kernel set and stack, so the
    rates on Python 3.12 stand beside those on 3.11 (issue 55)."""

    def doc(met, python, drake, blas="Haswell"):
        s = summarize("t", [_run(k, k <= met, [("a", k <= met)]) for k in range(1, 11)])
        env = {"blas_core": blas, "python": python, "drake": drake}
        return {"tasks": [s], "seed": 0, "environment": env}

    md = results.kernel_table(
        [doc(10, "3.11.7", "1.51.1"), doc(9, "3.11.7", "1.51.1", "SkylakeX"),
         doc(7, "3.12.1", "1.56.0")]
    )  # fmt: skip
    lines = md.splitlines()
    assert lines[0] == (
        "| task | run | seed | goal met, Haswell kernels, Python 3.11 + Drake 1.51.1 "
        "| goal met, SkylakeX kernels, Python 3.11 + Drake 1.51.1 "
        "| goal met, Haswell kernels, Python 3.12 + Drake 1.56.0 |"
    )
    assert "| `t` | solve | 0 | 10 of 10 | 9 of 10 | 7 of 10 |" in lines


def test_robustness_mpc_runs_each_tasks_closed_loop(tmp_path, capsys, dask_scheduler):
    """--mpc: each run is the task's closed loop (lock-step, smoke-sized here), judged by the
    loop's goal; the record says so. --transfer (a solve's plan played back) is refused."""
    out = tmp_path / "rob"
    argv = ["robustness", "cartpole-wall", "--mpc", "--smoke", "--runs", "2"]
    argv += ["--scheduler", dask_scheduler]
    assert cli.main([*argv, "--out", str(out)]) == 0
    assert "closed loops (lock-step)" in capsys.readouterr().out
    doc = json.loads((out / "robustness.json").read_text())
    assert doc["mpc"] is True
    (t,) = doc["tasks"]
    assert [r["status"] for r in t["results"]] == ["ran", "ran"]
    assert set(t["checks_met"]) == {"final_angle_error_rad", "wall_contact_steps"}
    assert "median closed loop s" in table(doc)
    assert cli.main([*argv, "--transfer", "--out", str(out)]) == 2
    assert "--transfer" in capsys.readouterr().err
