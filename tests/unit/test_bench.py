"""studies.bench pure logic: ratios, phase shares, blocks, probes, contact polygons."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from hydroilqr import Task
from tests.conftest import needs_tamsi


def _fake_solution(X, iteration_seconds, phases, costs):
    from hydroilqr.solver.solution import Solution

    N = X.shape[0] - 1
    return Solution(
        X, np.zeros((N, 1)), np.zeros(0), np.zeros(0), 0.01 * np.arange(N + 1),
        np.array(costs, float), list(iteration_seconds), phases, False, "max_iterations",
        "forward",
    )  # fmt: skip


@needs_tamsi
def test_bench_ratios_cost_difference_and_phase_shares(monkeypatch):
    from hydroilqr.studies import bench

    def fake_runs(tasks, U0, iterations, block=1, shadow=None):
        X = np.tile(tasks[0].x0, (3, 1))
        paper = _fake_solution(
            X,
            [0.5, 0.7, 0.6],  # the phases add up to less: waits are not phases
            {"rollout": [0.1] * 3, "derivatives": [0.2, 0.4, 0.3],
             "backward_pass": [0.05] * 3, "line_search": [0.05] * 3},
            [20.0, 15.0, 12.0, 10.0],
        )  # fmt: skip
        fast = _fake_solution(
            X,
            [0.1, 0.2, 0.1],
            {"rollout": [0.02] * 3, "derivatives": [0.02] * 3,
             "backward_pass": [0.02] * 3, "line_search": [0.02] * 3},
            [20.0, 14.0, 13.0, 12.0],
        )  # fmt: skip
        return [paper, fast]

    monkeypatch.setattr(bench, "run_alternating", fake_runs)
    fast = ["solver.derivatives=forward"]
    r = bench.bench_task("cartpole-wall", 3, 1, smoke=True, fast=fast, accuracy=False)
    a = r["paper"]
    assert r["speedup_median"] == pytest.approx(0.6 / 0.1)  # a / b: > 1 when (b) is faster
    assert r["speedup_total"] == pytest.approx(1.8 / 0.4)
    assert r["cost_rel_diff"] == pytest.approx((12.0 - 10.0) / 10.0)  # (b - a) / |a|
    assert a["initial_cost"] == 20.0 and a["final_cost"] == 10.0
    assert a["p10_s"] == pytest.approx(np.percentile([0.5, 0.6, 0.7], 10))
    assert a["p10_s"] > 0.5
    assert a["phase_share"] == pytest.approx(
        {"rollout": 0.2, "derivatives": 0.6, "backward_pass": 0.1, "line_search": 0.1}
    )

    def one_fails(tasks, U0, iterations, block=1, shadow=None):
        res = fake_runs(tasks, U0, iterations, block)
        return [res[0], RuntimeError("diverged")]

    monkeypatch.setattr(bench, "run_alternating", one_fails)
    r = bench.bench_task("cartpole-wall", 3, 1, smoke=True, fast=fast, accuracy=False)
    assert r["fast"] == {"error": "RuntimeError: diverged"} and "speedup_median" not in r


def test_bench_alternates_blocks_of_iterations(monkeypatch):
    from hydroilqr.studies import bench

    order = []

    def fake_solve(problem, U0, settings, callbacks, max_iterations, final_gains):
        for _ in range(max_iterations):
            order.append(problem)
            for cb in callbacks:
                cb(None)
        return problem

    monkeypatch.setattr(bench, "solve", fake_solve)
    tasks = [
        SimpleNamespace(problem=lambda i=i: i, config=SimpleNamespace(solver=None)) for i in (0, 1)
    ]
    assert bench.run_alternating(tasks, np.zeros(1), 3, block=1) == [0, 1]
    assert order == [0, 1, 0, 1, 0, 1]
    order.clear()
    bench.run_alternating(tasks, np.zeros(1), 4, block=2)
    assert order == [0, 0, 1, 1, 0, 0, 1, 1]


def test_contact_polygons_and_classes():
    from hydroilqr.studies.bench import contact_state, polygons

    task = Task.load("cartpole-wall", ["num_steps=5"])
    lay = task.dynamics.layout
    X = np.tile(task.x0, (4, 1))
    X[:, lay.block("pole_angle").coords[0]] = np.pi
    X[:, lay.block("cart_position").coords[0]] = [0.0, -0.43, -0.44, 0.0]  # 2 touch the wall
    faces = [contact_state(task.dynamics, x)[0] for x in X]
    p = polygons(task.dynamics, X)
    assert p["contact_steps"] == 2 and p["max_faces"] == max(faces) > 0
    assert p["mean_faces"] == pytest.approx(np.mean(faces))
    assert np.mean(faces) < max(faces)
    assert contact_state(task.dynamics, X[1])[1] == "compliant-rigid"
    soft = Task.load(
        "cartpole-wall",
        ["num_steps=5", "wall.compliance=compliant", "wall.hydroelastic_modulus=1e7"],
    )
    assert contact_state(soft.dynamics, X[1])[1] == "compliant-compliant"
    assert contact_state(soft.dynamics, X[0]) == (0, "free")


def test_probe_and_thread_scaling_read_the_times_the_right_way_round(monkeypatch):
    from hydroilqr.studies import bench

    clock = [0.0]  # bench's perf_counter: advanced only by the fake linearize (no sleeps)

    def fake_linearize(dyn, X, U, method, eps, threads, interval=1, **kw):
        clock[0] += 0.04 if method == "autodiff" else 0.02 if threads == 1 else 0.004
        return None

    monkeypatch.setattr(bench, "time", SimpleNamespace(perf_counter=lambda: clock[0]))
    monkeypatch.setattr(bench, "linearize", fake_linearize)
    monkeypatch.setattr(bench, "num_threads", lambda n: 2)
    task = Task.load("cartpole-wall", ["num_steps=5"])
    U0 = np.zeros((5, 1))
    monkeypatch.setattr(task.dynamics, "autodiff", lambda: None)
    probe = bench.probe_derivatives(task, U0, 1, repeats=1)
    assert probe["choice"] == "forward"  # the faster
    assert probe["seconds_per_step"] == pytest.approx({"autodiff": 0.04 / 5, "forward": 0.02 / 5})
    th = bench.thread_scaling(task, None, None, 2, repeats=1)
    assert th["speedup"]["1"] == 1.0 and th["speedup"]["2"] == pytest.approx(5.0)  # t(1) / t(2)
