"""`hydroilqr search` and `solve` on a task with a search: section: the result set, the polish,
Ctrl+C keeping the best sample, one-line refusals."""

from __future__ import annotations

import json

from hydroilqr.cli import main
from tests.conftest import assert_one_line

SMALL = ["--set", "num_steps=10", "--set", "search.samples=4", "--set", "search.knots=3"]


def test_search_writes_a_result_set_with_its_history(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["search", "cartpole-wall", "--smoke", *SMALL, "--workers", "1", "--no-replay"]
    assert main([*argv, "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    s = summary["search"]
    assert len(s["history"]) == 2 and s["samples_evaluated"] == 8
    assert s["best_cost"] <= s["nominal_cost"] and summary["final_cost"] == s["best_cost"]
    for name in ("search.png", "search.npz", "contacts.png", "solution.npz"):
        assert (out / name).is_file(), name
    assert "samples/s" in capsys.readouterr().out


def test_solve_with_a_search_section_polishes_and_selects(tmp_path, dask_scheduler):
    out = tmp_path / "run"
    argv = ["solve", "cartpole-wall", "--smoke", *SMALL, "--set", "search.polish=2"]
    assert main([*argv, "--scheduler", dask_scheduler, "--no-replay", "--out", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())["search"]
    polish = s["polish"]
    # the two best samples, then the task's own guess (search.polish_guess)
    assert [r["index"] for r in polish["results"]] == [0, 1, 2] and polish["chosen"] in (0, 1, 2)
    assert [r["start"] for r in polish["results"]] == ["sample", "sample", "guess"]
    best = polish["results"][0]
    assert best["final_cost"] <= s["best_cost"]  # iLQR from the best sample lowers its cost


def test_ctrl_c_keeps_the_best_sample(tmp_path, monkeypatch, dask_scheduler):
    from hydroilqr.studies import search as studies_search

    real = studies_search.DaskEvaluator.__call__

    def interrupt_second(self, commands, *args):
        if self.calls == 1:
            raise KeyboardInterrupt
        return real(self, commands, *args)

    monkeypatch.setattr(studies_search.DaskEvaluator, "__call__", interrupt_second)
    out = tmp_path / "run"
    argv = ["search", "cartpole-wall", *SMALL, "--set", "search.iterations=5"]
    assert main([*argv, "--scheduler", dask_scheduler, "--no-replay", "--out", str(out)]) == 130
    s = json.loads((out / "summary.json").read_text())["search"]
    assert s["interrupted"] and len(s["history"]) == 1


def test_bad_search_input_is_one_line(tmp_path, capsys):
    rc = main(["search", "cartpole-wall", "--set", "search.samples=1"])
    assert_one_line(rc, *capsys.readouterr(), "search.samples")
    rc = main(["search", "cartpole-wall", "--workers", "0"])
    out, err = capsys.readouterr()
    assert rc == 2 and err.count("\n") == 1 and "--workers" in err
    rc = main(["search", "cartpole-wall", *SMALL, "--scheduler", "tcp://127.0.0.1:9"])
    out, err = capsys.readouterr()
    assert rc == 2 and "Traceback" not in err and err.strip().count("\n") == 0
    assert "--scheduler tcp://127.0.0.1:9" in err
    rc = main(["solve", "cartpole-wall", "--set", "search.method=cem", "--starts", "2"])
    out, err = capsys.readouterr()
    assert rc == 2 and "search: section" in err


def test_every_worker_lost_is_one_line_and_keeps_the_best(
    tmp_path, monkeypatch, capsys, dask_scheduler
):
    """Every Dask worker gone mid-search (``gather_within`` gives up): the best sample so far
    is written, one line on stderr says why, exit 3."""
    from hydroilqr.studies import search as studies_search

    real = studies_search.gather_within
    calls = []

    def lose_second(client, futures, patience=60.0, poll=1.0):
        calls.append(1)
        if len(calls) == 2:
            raise studies_search.WorkersLost("every Dask worker was gone for 60 s")
        return real(client, futures, patience, poll)

    monkeypatch.setattr(studies_search, "gather_within", lose_second)
    out = tmp_path / "run"
    argv = ["search", "cartpole-wall", *SMALL, "--set", "search.iterations=5"]
    assert main([*argv, "--scheduler", dask_scheduler, "--no-replay", "--out", str(out)]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "every Dask worker was gone" in err[0] and str(out) in err[0]
    s = json.loads((out / "summary.json").read_text())["search"]
    assert s["workers_lost"] and len(s["history"]) == 2 and s["history"][1]["failed"] == 4


def test_the_pusher_puck_builtin_checks_and_smoke_solves(tmp_path, dask_scheduler):
    """The built-in with a search: section: `check` passes it, and `solve --smoke` runs its
    (smoke-sized) search and polish and writes the result set with both."""
    from hydroilqr.problem.files import list_tasks
    from hydroilqr.solver.search import restart_seed

    assert "pusher-puck" in list_tasks()
    assert main(["check", "pusher-puck"]) == 0
    out = tmp_path / "run"
    argv = ["solve", "pusher-puck", "--smoke", "--scheduler", dask_scheduler, "--no-replay"]
    assert main([*argv, "--out", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())["search"]
    assert s["settings"]["space"] == "position"
    # a smoke solve (0.5 s of motion) cannot meet the goal: its one restart (--smoke keeps
    # at most one of search.restarts) searches again and polishes a sample, not the guess
    assert [r["seed"] for r in s["restarts"]] == [restart_seed(0, 1)]
    results = s["polish"]["results"]
    assert [(r["start"], r.get("search", 0)) for r in results] == [
        ("sample", 0),
        ("guess", 0),
        ("sample", 1),
    ]
