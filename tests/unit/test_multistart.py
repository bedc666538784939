"""Multi-start: reproducible perturbations, best-by-goal-then-cost, Dask jobs."""

import math

import numpy as np

from hydroilqr.studies.multistart import (
    StartResult,
    best_index,
    perturbation,
    run_multistart,
    spread,
)


class _Sol:
    def __init__(self, cost):
        self.final_cost = cost
        self.iterations = 3
        self.reason = "converged"


def test_start_zero_is_the_guess_and_others_are_seeded():
    U0 = np.ones((20, 2))
    lim = np.array([np.inf, 5.0])
    assert np.array_equal(perturbation(U0, lim, 0.1, seed=3, k=0), U0)
    a = perturbation(U0, lim, 0.1, seed=3, k=1)
    assert np.array_equal(a, perturbation(U0, lim, 0.1, seed=3, k=1))  # reproducible
    assert not np.array_equal(a, perturbation(U0, lim, 0.1, seed=3, k=2))
    assert not np.array_equal(a, perturbation(U0, lim, 0.1, seed=4, k=1))
    # smooth: a few knots interpolated, not white noise
    assert np.max(np.abs(np.diff(a, axis=0))) < 0.5 * np.max(np.abs(a - U0))


def test_zero_guess_is_perturbed_on_the_effort_limit_scale():
    U0 = np.zeros((10, 2))
    d = perturbation(U0, np.array([50.0, np.inf]), 0.1, seed=0, k=1)
    assert 0.5 < np.max(np.abs(d[:, 0])) < 20.0  # 0.1 * 50 per unit normal
    assert 0.0 < np.max(np.abs(d[:, 1])) < 0.5  # no limit: scale 1
    # starts from a still guess differ by a sizeable fraction of the actuator's limit
    starts = [perturbation(U0, np.array([50.0, np.inf]), 0.1, seed=0, k=k) for k in (1, 2, 3)]
    for a in starts[1:]:
        assert np.sqrt(np.mean((a[:, 0] - starts[0][:, 0]) ** 2)) > 0.02 * 50.0


def test_best_prefers_goal_met_then_cost():
    rs = [
        StartResult(0, _Sol(1.0), goal={"met": False}),
        StartResult(1, _Sol(5.0), goal={"met": True}),
        StartResult(2, _Sol(3.0), goal={"met": True}),
        StartResult(3, None, error="SimulationError: diverged"),
    ]
    assert best_index(rs) == 2
    s = spread(rs)
    assert (s["best_cost"], s["median_cost"], s["worst_cost"]) == (1.0, 3.0, 5.0)
    assert s["goal_met"] == 2 and s["finished"] == 3 and s["starts"] == 4
    assert rs[3].record()["status"] == "failed" and math.isinf(rs[3].cost)
    assert best_index([StartResult(0, None)]) is None


def test_multistart_runs_starts_as_dask_jobs(dask_scheduler):
    ref = {
        "name": "cartpole-wall",
        "overrides": ["solver.max_iterations=2"],
        "config": None,
        "smoke": True,
    }
    seen = []
    results, best = run_multistart(
        ref, 2, seed=1, noise=0.2, scheduler=dask_scheduler, on_start=seen.append
    )
    assert [r.index for r in results] == [0, 1] and len(seen) == 2
    assert all(r.solution is not None and not r.error for r in results)
    assert results[0].solution.U.shape == results[1].solution.U.shape
    assert results[0].cost != results[1].cost  # different starts, different plans
    assert best in (0, 1) and results[0].goal["checks"]  # the task's goal was evaluated


def test_a_start_line_names_the_status_once_and_its_own_time():
    """Issue 39, 10: a failed start reads "failed (why)", not "failed, failed,"."""
    from hydroilqr.cli.solve import start_line

    failed = {"index": 1, "final_cost": None, "status": "failed", "iterations": 0,
              "goal_met": None, "seconds": 3.21, "error": "SimulationError: blew up"}  # fmt: skip
    assert start_line(failed) == "failed (SimulationError: blew up), 3.2 s"
    ok = {"index": 0, "final_cost": 8.27, "status": "converged", "iterations": 12,
          "goal_met": True, "seconds": 19.1}  # fmt: skip
    assert start_line(ok) == "status converged after 12 iterations, cost 8.27, goal met, 19.1 s"
