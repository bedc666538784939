"""Robustness: how often a task meets its goal when its solve is perturbed by a hair.

Contact-rich solves are sensitive to last-bit differences (OpenBLAS picks other kernels on
other CPUs, another BLAS build rounds differently), and such differences can move a solve
into another local minimum. One solve on one machine says little about what a user's machine
will get. ``run_robustness`` solves each task ``runs`` times as independent Dask jobs (a local
cluster by default, an existing scheduler when given); run k (k = 1..runs) starts from the
task's own initial guess perturbed by a relative ``noise`` (default 1e-9, the size of a
last-bit difference after a few operations), drawn as in multi-start
(``multistart.perturbation``, seeded by ``[seed, k]``), so every run is reproducible on one
machine. For a receding-horizon task the first window's guess is perturbed.

The report per task: each run's status, goal PASS/FAIL, which goal checks failed and the
goal's metric values; the pass rate of the whole goal and of each check.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from distributed import as_completed

from hydroilqr.io.environment import environment
from hydroilqr.output.report import json_safe
from hydroilqr.studies.cluster import open_client
from hydroilqr.studies.multistart import solve_start

#: The default relative perturbation of the initial guess: last-bit sized.
DEFAULT_NOISE = 1e-9
#: The default number of perturbed solves per task.
DEFAULT_RUNS = 10


@dataclass
class RunResult:
    """One perturbed solve of one task."""

    task: str
    index: int
    status: str = "failed"
    iterations: int = 0
    final_cost: float | None = None
    goal_met: bool | None = None
    checks: list = field(default_factory=list)
    error: str = ""
    seconds: float = 0.0

    def record(self) -> dict:
        return {
            "task": self.task,
            "index": self.index,
            "status": self.status,
            "iterations": self.iterations,
            "final_cost": self.final_cost,
            "goal_met": self.goal_met,
            "failed_checks": [c["metric"] for c in self.checks if not c.get("passed")],
            "values": {c["metric"]: c.get("value") for c in self.checks},
            "seconds": round(self.seconds, 2),
            **({"error": self.error} if self.error else {}),
        }


def solve_run(task_ref: dict, k: int, seed: int, noise: float) -> RunResult:
    """Runs on a worker: multi-start's start ``k`` (the task loaded there, solved from its
    guess perturbed by run ``k``'s draw, metrics and goal); a failure is recorded as a run that
    did not meet the goal."""
    r = solve_start(task_ref, k, seed, noise)
    sol = r.solution
    res = RunResult(task=task_ref["label"], index=k, error=r.error, seconds=r.seconds)
    if sol is None:
        res.goal_met = False
        return res
    res.status, res.iterations = sol.status, int(sol.iterations)
    res.final_cost = r.cost if math.isfinite(r.cost) else None
    res.goal_met = False if r.error else r.goal.get("met")
    res.checks = r.goal.get("checks", [])
    return res


def summarize(label: str, runs: Sequence[RunResult]) -> dict:
    """A task's pass rate: of the whole goal and of each check, over its runs."""
    n = len(runs)
    met = sum(r.goal_met is True for r in runs)
    names: list[str] = []
    for r in runs:
        names += [c["metric"] for c in r.checks if c["metric"] not in names]
    per_check = {
        name: sum(any(c["metric"] == name and c.get("passed") for c in r.checks) for r in runs)
        for name in names
    }
    return {
        "task": label,
        "runs": n,
        "goal_declared": any(r.goal_met is not None for r in runs if not r.error),
        "goal_met": met,
        "pass_rate": met / n if n else None,
        "checks_met": per_check,
        "failed_runs": sum(bool(r.error) for r in runs),
        "statuses": {s: sum(r.status == s for r in runs) for s in sorted({r.status for r in runs})},
        "median_seconds": float(np.median([r.seconds for r in runs])) if runs else None,
        "results": [r.record() for r in sorted(runs, key=lambda r: r.index)],
    }


def run_robustness(
    task_refs: Sequence[dict],
    runs: int = DEFAULT_RUNS,
    noise: float = DEFAULT_NOISE,
    seed: int = 0,
    scheduler: str | None = None,
    workers: int | None = None,
    on_run: Callable[[RunResult], None] | None = None,
) -> dict:
    """Solves every task of ``task_refs`` ``runs`` times (all runs of all tasks as one pool of
    Dask jobs) and returns the report: ``{"noise", "seed", "runs", "tasks": [summary per
    task], "environment"}``. A ``task_ref``: {label, name, overrides, config, smoke}.
    ``on_run(result)`` is called as each run finishes (progress display)."""

    env = json_safe(environment())  # (the code and machine the runs start on)
    client, cluster = open_client(scheduler, workers)
    by_task: dict[str, list[RunResult]] = {ref["label"]: [] for ref in task_refs}
    try:
        futures = [
            client.submit(
                solve_run, ref, k, seed, noise, pure=False, key=f"robust-{ref['label']}-{k}"
            )
            for ref in task_refs
            for k in range(1, runs + 1)
        ]
        for fut in as_completed(futures):
            r = fut.result()
            by_task[r.task].append(r)
            if on_run is not None:
                on_run(r)
    finally:
        # (a closing cluster's workers log lost heartbeats as tracebacks: not the user's news)
        logging.getLogger("distributed").setLevel(logging.CRITICAL)
        client.close()
        if cluster is not None:
            cluster.close()
    return {
        "noise": noise,
        "seed": seed,
        "runs": runs,
        "tasks": [summarize(label, rs) for label, rs in by_task.items()],
        "environment": env,
    }


def table(report: dict) -> str:
    """The report as a Markdown table: per task, the goal's pass rate and each check's."""
    rows = ["| task | goal met | per check | statuses | median solve s |", "|---|---|---|---|---|"]
    for t in report["tasks"]:
        n = t["runs"]
        goal = f"{t['goal_met']} of {n}" if t["goal_declared"] else "no goal"
        checks = ", ".join(f"{k} {v}/{n}" for k, v in t["checks_met"].items())
        statuses = ", ".join(f"{k} {v}" for k, v in t["statuses"].items())
        med = t["median_seconds"]
        rows.append(
            f"| `{t['task']}` | {goal} | {checks} | {statuses} | "
            f"{'' if med is None else f'{med:.1f}'} |"
        )
    return "\n".join(rows)
