"""bench: the paper method vs the fast configuration, alternating in one process (smoke)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hydroilqr import cli
from hydroilqr.cli import main
from tests.conftest import assert_one_line, needs_tamsi


@needs_tamsi
def test_bench_smoke_writes_json_and_plot(tmp_path):
    out = tmp_path / "bench"
    rc = main(
        [
            "bench",
            "cartpole-wall",
            "--smoke",
            "--set",
            "num_steps=60",  # (into contact by then: free and contact steps both timed)
            "--iterations",
            "2",
            "--fast",
            "solver.derivatives=forward",
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    doc = json.loads((out / "bench.json").read_text())
    assert (out / "iterations.png").stat().st_size > 0
    for key in ("iterations", "threads", "paper", "fast", "tasks"):
        assert key in doc
    r = doc["tasks"]["cartpole-wall"]
    for key in ("speedup_median", "cost_rel_diff", "initial_polygons", "accuracy", "threads"):
        assert key in r, key
    for method in ("paper", "fast"):
        m = r[method]
        assert 1 <= m["iterations"] <= 2
        assert m["p10_s"] <= m["median_s"] <= m["p90_s"]
        assert set(m["phase_share"]) == {"rollout", "derivatives", "backward_pass", "line_search"}
        assert abs(sum(m["phase_share"].values()) - 1.0) < 1e-9
        assert m["final_cost"] < m["initial_cost"]
        assert "max_faces" in m["polygons"]
    assert "tamsi" in " ".join(r["configs"]["paper"])
    # Exact derivative modes agree with AutoDiff where AutoDiff is exact.
    acc = r["accuracy"]
    # every contact class the run visits (free, and compliant-rigid when the tip is on the
    # wall: 20 of 200 steps when written; integration/test_solve.py checks contact steps regardless)
    assert set(acc["central"]["max"]) == {*acc["contact_classes"], "all"} >= {"free", "all"}
    assert all(e < 1e-4 for e in acc["central"]["max"].values()), acc["central"]["max"]
    assert set(r["threads"]["seconds"]) >= {"1"}
    # the paper's method also timed at (b)'s own iterates: one per iteration (b) started
    si = r["same_iterates"]
    assert si["iterations"] == r["fast"]["iterations"] and not si["errors"]
    assert si["speedup_median"] > 0 and len(si["paper_max_faces"]) == si["iterations"]
    # (a'): the paper's method on (b)'s contact solver, side by side with (a) and (b)
    assert "paper_same_solver" in doc
    same = r["paper_same_solver"]
    assert 1 <= same["iterations"] <= 2 and same["final_cost"] < same["initial_cost"]
    assert same["p10_s"] <= same["median_s"] <= same["p90_s"]
    cfg = " ".join(r["configs"]["paper_same_solver"])
    assert "tamsi" not in cfg and "plant.contact_approximation=sap" in cfg
    assert "solver.derivatives=autodiff" in cfg and "solver.autodiff_workers=1" in cfg
    assert "solver.derivative_secant_updates=0" in cfg and "solver.derivative_interval=1" in cfg
    assert r["speedup_same_solver_median"] == same["median_s"] / r["fast"]["median_s"]
    assert "speedup_same_solver_total" in r and "cost_rel_diff_same_solver" in r
    # the limit analysis: one rollout, exact partials on each path, backward pass, the bound
    lim = r["limits"]
    assert lim["rollout_s"] > 0 and lim["backward_pass_s"] > 0
    assert {"autodiff_serial", "forward_threads"} <= set(lim["linearization_all_steps_s"])
    assert 1 <= lim["keypoints"] <= lim["steps"] == r["steps"]
    assert lim["cheapest_path"] in lim["linearization_per_step_s"]
    assert 0 < lim["limit_s"] <= lim["limit_all_steps_s"]
    assert lim["fast_share_of_limit"] == lim["limit_s"] / r["fast"]["median_s"]


@needs_tamsi
def test_same_iterates_starts_from_each_nominal_of_the_fast_run(monkeypatch):
    """The shadow sees U0 and then every iterate (b) continues from, with its μ, inside (b)'s
    turn; and one (a) iteration from a nominal is timed without its initial rollout."""
    from types import SimpleNamespace

    from hydroilqr import Task
    from hydroilqr.studies import bench

    seen, order = [], []

    def fake_solve(problem, U0, settings, callbacks, max_iterations, final_gains):
        for k in range(max_iterations):
            order.append(problem)
            for cb in callbacks:
                cb(SimpleNamespace(U=np.full(1, 10.0 * problem + k + 1), mu=0.5 * (k + 1)))
        return problem

    monkeypatch.setattr(bench, "solve", fake_solve)
    tasks = [
        SimpleNamespace(
            problem=lambda i=i: i,
            config=SimpleNamespace(solver=SimpleNamespace(regularization_init=7.0)),
        )
        for i in (0, 1)
    ]

    def shadow(U, mu):
        seen.append((float(U[0]), mu))
        order.append("shadow")

    bench.run_alternating(tasks, np.zeros(1), 3, block=1, shadow=shadow)
    assert seen == [(0.0, 7.0), (11.0, 0.5), (12.0, 1.0)]  # U0, then (b)'s first two iterates
    assert order == [0, 1, "shadow", 0, 1, "shadow", 0, 1, "shadow"]
    monkeypatch.undo()

    task = Task.load("cartpole-wall", bench.PAPER, smoke=True)
    same = bench.SameIterates(task)
    U0 = task.initial_guess(task.steps)
    same(U0, 1e-3)
    assert len(same.seconds) == 1 and same.seconds[0] > 0 and not same.errors
    assert same.phases["rollout"] == [0.0] and same.phases["derivatives"][0] > 0
    assert task.config.solver.regularization_init != 1e-3  # μ is passed, the task unchanged
    same._failed("rollout failed")  # stays aligned with (b)'s iterations
    fast = SimpleNamespace(
        iteration_seconds=[0.5, 0.2], phase_seconds={"rollout": [0.4, 0.0]}
    )  # (b) without its first rollout: 0.1, 0.2
    st = same.stats(fast)
    assert st["iterations"] == 2 and st["errors"] == ["rollout failed"]
    assert st["fast_median_s"] == pytest.approx(0.1)  # only the pair where both ran
    assert st["speedup_median"] == pytest.approx(same.seconds[0] / 0.1)
    assert task.config.solver.regularization_init != 1e-3  # the task's own settings unchanged


def test_three_runners_take_turns_and_a_finished_one_is_skipped(monkeypatch):
    """(a), (b), (a') in turn; a runner that stops early never blocks the other two."""
    from types import SimpleNamespace

    import numpy as np

    from hydroilqr.studies import bench

    order = []

    def fake_solve(problem, U0, settings, callbacks, max_iterations, final_gains):
        for _ in range(2 if problem == 1 else max_iterations):  # (b) stops after 2
            order.append(problem)
            for cb in callbacks:
                cb(None)
        return problem

    monkeypatch.setattr(bench, "solve", fake_solve)
    tasks = [
        SimpleNamespace(problem=lambda i=i: i, config=SimpleNamespace(solver=None))
        for i in (0, 1, 2)
    ]
    assert bench.run_alternating(tasks, np.zeros(1), 3) == [0, 1, 2]
    assert order == [0, 1, 2, 0, 1, 2, 0, 2]


def test_fast_derivative_paths_match_exact_ones():
    """Forward FD reusing the rollout is bitwise the plain one; adaptive keypoints are exact and
    include both sides of every contact event."""

    from hydroilqr import Task
    from hydroilqr.model.derivatives import contact_events, linearize

    task = Task.load("cartpole-wall", ["horizon=0.6"])
    dyn = task.dynamics
    N = task.steps
    U = np.zeros((N, dyn.nu))
    X = dyn.rollout(task.x0, U)  # the pole falls onto the wall
    events = contact_events(dyn, X[:N])
    assert events, "the falling pole should touch the wall"
    A1, B1 = linearize(dyn, X, U, "forward")
    A2, B2 = linearize(dyn, X, U, "forward", rollout=True)
    np.testing.assert_array_equal(A1, A2)
    np.testing.assert_array_equal(B1, B2)
    Ai, Bi = linearize(dyn, X, U, "forward", interval=4, rollout=True, adaptive=True)
    for k in sorted(events | set(range(0, N, 4)) | {N - 1}):
        np.testing.assert_array_equal(Ai[k], A1[k])
        np.testing.assert_array_equal(Bi[k], B1[k])


def test_bench_refuses_a_task_twice_and_another_commands_directory(tmp_path, capsys):
    rc = main(["bench", "cartpole-wall", "cartpole-wall", "--smoke", "--out", str(tmp_path)])
    assert rc == 2 and "both task 'cartpole-wall'" in capsys.readouterr().err
    (tmp_path / "solve").mkdir()
    (tmp_path / "solve" / "summary.json").write_text('{"task": "kinova-forward"}')
    rc = main(["bench", "cartpole-wall", "--smoke", "--out", str(tmp_path / "solve")])
    assert rc == 2 and "holds the results of task 'kinova-forward'" in capsys.readouterr().err
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "bench.json").write_text('{"task": "bench"}')
    rc = main(["solve", "cartpole-wall", "--smoke", "--out", str(tmp_path / "b")])
    assert rc == 2 and "holds a bench's results" in capsys.readouterr().err


def test_fast_overrides_that_change_the_trajectory_are_refused(tmp_path, capsys):
    # (b) ran with (a)'s initial guess, so its horizon was silently ignored
    for fast in ("horizon=0.5", "plant.time_step=0.02"):
        rc = main(["bench", "cartpole-wall", "--smoke", "--fast", fast, "--out", str(tmp_path)])
        err = capsys.readouterr().err
        assert rc == 2 and "both must solve the same trajectory" in err, err
        assert not tmp_path.joinpath("bench.json").exists()


def test_a_bench_failing_on_a_later_task_keeps_the_earlier_results(tmp_path, capsys):
    (tmp_path / "bench.json").write_text('{"task": "bench", "tasks": {"earlier": {}}}')
    rc = main(
        ["bench", "cartpole-wall", "kinova-forward", "--smoke", "--iterations", "1"]
        + ["--fast", "tip.hydroelastic_modulus=1e6", "--out", str(tmp_path)]
    )  # `tip` is the cart-pole's; kinova-forward has no such geometry
    assert rc == 2 and "geometry.tip" in capsys.readouterr().err
    assert "earlier" in json.loads((tmp_path / "bench.json").read_text())["tasks"]


def test_bench_block_must_be_positive(capsys):
    rc = cli.main(["bench", "cartpole-wall", "--smoke", "--block", "0", "--out", "/nonexistent"])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "--block")


def test_bench_refuses_an_ensemble_task_in_one_line(tmp_path, capsys):
    """bench times one model's iterations: an ensemble task is refused before any work."""
    from tests.conftest import write_task

    task = write_task(tmp_path, num_steps=5, ensemble=[{"plant.gravity": [0, 0, -8]}])
    rc = main(["bench", str(task), "--iterations", "1", "--out", str(tmp_path / "b")])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "has an ensemble")
    assert not (tmp_path / "b").exists()


def test_bench_without_tamsi_runs_the_other_paths_and_says_why(tmp_path, monkeypatch, capsys):
    """On a Drake without TAMSI (1.57 and newer), bench skips path (a) and (a) at (b)'s
    iterates with one note naming the Drakes that have it, and runs (a') and (b) as always."""
    from hydroilqr.studies import bench

    monkeypatch.setattr(bench, "drake_has_tamsi", lambda: False)
    out = tmp_path / "bench"
    argv = ["bench", "cartpole-wall", "--smoke", "--set", "num_steps=60", "--iterations", "2"]
    rc = main([*argv, "--fast", "solver.derivatives=forward", "--out", str(out)])
    printed = capsys.readouterr().out
    assert rc == 0
    r = json.loads((out / "bench.json").read_text())["tasks"]["cartpole-wall"]
    assert "iteration_seconds" not in r["paper"] and "1.56" in r["paper"]["skipped"]
    assert "same_iterates" not in r and "speedup_median" not in r
    for method in ("fast", "paper_same_solver"):
        assert 1 <= r[method]["iterations"] <= 2
        assert r[method]["final_cost"] < r[method]["initial_cost"]
    assert r["speedup_same_solver_median"] > 0 and "accuracy" in r and "limits" in r
    assert (out / "iterations.png").stat().st_size > 0
    assert "(a) not run: path (a), the paper's method, needs Drake's TAMSI" in printed
