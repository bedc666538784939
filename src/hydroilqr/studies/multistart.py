"""Multi-start: one task solved from several perturbed initial guesses, the best one kept.

Contact-implicit solves land in different basins for small differences (even the last bits
of the linear algebra), so one solve says little about how lucky it was. ``run_multistart``
solves the task ``starts`` times as independent Dask jobs (a local cluster by default, an
existing scheduler when given): start 0 from the task's own initial guess, start k > 0 from
that guess plus a smooth random perturbation drawn from ``numpy.random.default_rng([seed,
k])`` (reproducible, independent of which worker runs it):

    U0_k[i, j] = U0[i, j] + noise * scale_j * s_kj(t_i),

where ``s_kj`` interpolates standard-normal values at ``knots`` evenly spaced times and
``scale_j`` is the RMS of column j of the guess, else a tenth of actuator j's effort limit,
else 1. The best start is the one that meets the task's goal, then has the lowest cost.
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from distributed import as_completed

from hydroilqr import metrics as metrics_mod
from hydroilqr.metrics.goals import evaluate
from hydroilqr.model.task import Task
from hydroilqr.solver.api import solve
from hydroilqr.studies.cluster import kill_workers, open_client

KNOTS = 5


def perturbation(U0: np.ndarray, effort_limits: np.ndarray, noise: float, seed: int, k: int):
    """The perturbed guess of start ``k`` (start 0: ``U0`` itself). U0: [N, nu].

    Smooth seeded noise (``KNOTS`` normal samples per input, interpolated over the horizon)
    times ``noise`` times each input's scale: its RMS over the guess; for an input the guess
    leaves at zero, its effort limit (1 without a finite limit), so that starts from a still
    (zero) guess differ by a tenth of what the actuator can do at the default noise 0.1."""
    U0 = np.asarray(U0, float)
    if k == 0 or noise == 0.0 or U0.size == 0:
        return U0.copy()
    N, nu = U0.shape
    rng = np.random.default_rng([int(seed), int(k)])
    rms = np.sqrt(np.mean(U0**2, axis=0))
    lim = np.asarray(effort_limits, float)
    fallback = np.where(np.isfinite(lim) & (lim > 0), lim, 1.0)
    scale = np.where(rms > 1e-12, rms, fallback)
    knots = rng.standard_normal((KNOTS, nu))
    s = np.stack(
        [np.interp(np.linspace(0, 1, N), np.linspace(0, 1, KNOTS), knots[:, j]) for j in range(nu)],
        axis=1,
    )
    return U0 + noise * scale * s


def guess_start(task, noise: float = 0.0, seed: int = 0, k: int = 0) -> np.ndarray:
    """Start ``k``'s controls: the task's initial guess (a receding task's: its first
    window's), [N, nu], perturbed as ``perturbation`` of run ``k`` with ``noise`` (k = 0 or
    noise 0: as is). What iLQR alone starts from in multi-start and robustness, and the
    search's polish of the task's own guess (``search.polish_guess``)."""
    rh = task.config.receding_horizon
    U0 = task.initial_guess(rh.window_steps if rh is not None else task.config.steps)
    limits = getattr(task.dynamics, "effort_limits", np.full(U0.shape[1], np.inf))
    return perturbation(U0, limits, noise, seed, k)


@dataclass
class StartResult:
    """One start: its index, its solution (None if it failed) and what it achieved."""

    index: int
    solution: Any = None
    metrics: dict = field(default_factory=dict)
    goal: dict = field(default_factory=dict)
    error: str = ""
    seconds: float = 0.0

    @property
    def cost(self) -> float:
        if self.solution is None:
            return math.inf
        c = float(self.solution.final_cost)
        return c if math.isfinite(c) else math.inf

    def record(self) -> dict:
        sol = self.solution
        return {
            "index": self.index,
            "final_cost": self.cost if math.isfinite(self.cost) else None,
            "status": getattr(sol, "status", None) or (sol.reason if sol else "failed"),
            "iterations": sol.iterations if sol is not None else 0,
            "goal_met": self.goal.get("met"),
            "seconds": self.seconds,
            **({"error": self.error} if self.error else {}),
        }


def solve_start(task_ref: dict, k: int, seed: int, noise: float) -> StartResult:
    """Runs on a worker: loads the task (Drake objects do not travel), solves from the
    perturbed guess, computes metrics and the goal. Never raises: a failure is recorded."""

    t0 = time.perf_counter()
    res = StartResult(index=k)
    try:
        task = Task.load(
            task_ref["name"], task_ref["overrides"], task_ref["config"], task_ref["smoke"]
        )
        U0 = guess_start(task, noise, seed, k)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            res.solution = solve(task, U0=U0)
        res.metrics = metrics_mod.compute(task, res.solution)
        res.goal = evaluate(task.config.goal, res.metrics)
    except Exception as e:  # noqa: BLE001 - a failed start is data; the others go on
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        res.error = f"{type(e).__name__}: {first}"[:300]
    res.seconds = time.perf_counter() - t0
    return res


def best_index(results: list[StartResult]) -> int | None:
    """The start that met the goal (if any did), then with the lowest finite cost."""
    ok = [r for r in results if math.isfinite(r.cost)]
    if not ok:
        return None
    return min(ok, key=lambda r: (r.goal.get("met") is not True, r.cost)).index


def spread(results: list[StartResult]) -> dict:
    """Best / median / worst final cost over the starts that finished, and goal counts."""
    costs = sorted(r.cost for r in results if math.isfinite(r.cost))
    met = [r.goal.get("met") for r in results]
    return {
        "starts": len(results),
        "finished": len(costs),
        "best_cost": costs[0] if costs else None,
        "median_cost": float(np.median(costs)) if costs else None,
        "worst_cost": costs[-1] if costs else None,
        "goal_met": sum(m is True for m in met),
        "goal_declared": any(m is not None for m in met),
    }


def run_multistart(
    task_ref: dict,
    starts: int,
    seed: int = 0,
    noise: float = 0.1,
    scheduler: str | None = None,
    workers: int | None = None,
    on_start=None,
) -> tuple[list[StartResult], int | None]:
    """Solves ``starts`` starts as Dask jobs; returns all results (by index) and the best
    index. ``task_ref``: {name, overrides, config, smoke}, as the task was loaded.
    ``on_start(result)`` is called as each start finishes (progress display)."""

    client, cluster = open_client(scheduler, workers)
    results: list[StartResult] = []
    try:
        futures = [
            client.submit(solve_start, task_ref, k, seed, noise, pure=False, key=f"start-{k}")
            for k in range(starts)
        ]
        for fut in as_completed(futures):
            r = fut.result()
            results.append(r)
            if on_start is not None:
                on_start(r)
    except KeyboardInterrupt:
        if cluster is not None:
            kill_workers(cluster)  # (the unfinished starts are abandoned)
        raise Interrupted(sorted(results, key=lambda r: r.index)) from None
    finally:
        _close(client, cluster)
    results.sort(key=lambda r: r.index)
    return results, best_index(results)


class Interrupted(KeyboardInterrupt):
    """Ctrl+C during a multi-start: ``results`` holds the starts that had finished (the
    others were stopped with the cluster)."""

    def __init__(self, results: list[StartResult]):
        super().__init__(f"{len(results)} start(s) had finished")
        self.results = results


def _close(client, cluster) -> None:
    """Closes the client and an embedded cluster (stopping unfinished starts), quietly."""

    logging.getLogger("distributed").setLevel(logging.CRITICAL)
    try:
        client.close(timeout=5)
    except TimeoutError:
        pass  # (a busy machine: the cluster below is ended either way)
    finally:
        if cluster is not None:
            try:
                cluster.close(timeout=5)
            except TimeoutError:  # its work is done: end its workers rather than fail the run
                kill_workers(cluster)
