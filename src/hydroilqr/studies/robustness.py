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
goal's metric values; the pass rate of the whole goal and of each check. With ``transfer``,
each run's plan is also played back as the results page's transfer section plays the default
solve (``control.playback.HALF_SPEED``: PD+ at the paper's gains, half speed, on the finer
simulation with the other contact approximation), and the report adds the task's goal judged
on the executed motion and, for a task that moves an object, where the object comes to rest
against where the plan puts it (``resting_gap``): whether a transfer holds in the basins other
machines land in, not only in this machine's.

With ``mpc`` each run is the task's closed loop instead (``loop_run``): its ``mpc:`` settings,
lock-step (the simulation waits for each update, so a run depends on neither the machine's
load nor its speed), the first plan's initial guess perturbed as a solve's is, and the run
judged by the loop's goal (``mpc.goal``, else ``goal``) on the simulated motion.
"""

from __future__ import annotations

import logging
import math
import os
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from distributed import as_completed

from hydroilqr.control.mpc import SMOKE_UPDATES, loop_metrics, mpc_config, prepare
from hydroilqr.control.playback import HALF_SPEED, PlaybackSettings, executed_goal, playback
from hydroilqr.io.environment import environment
from hydroilqr.metrics.goals import judge_loop
from hydroilqr.model.derivatives import num_threads
from hydroilqr.model.task import Task
from hydroilqr.output.report import json_safe
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.load import load_task
from hydroilqr.studies.cluster import open_client
from hydroilqr.studies.multistart import perturbation, solve_start

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
    # Cores the solve keeps busy at most (``solve_threads``); its start and end (Unix time,
    # on its worker) and the worker's process id: how many solves ran at once is measured.
    threads: int = 0
    started: float = 0.0
    finished: float = 0.0
    worker: int = 0
    # With transfer: {"goal_met", "failed_checks", "resting_gap"} of the plan's playback, or
    # {"error"} if it could not be played back; None: not played back.
    transfer: dict | None = None
    # With search: the polished start chosen and what each met (``search_start``'s polish).
    polish: dict | None = None

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
            "threads": self.threads,
            "started": self.started,
            "finished": self.finished,
            "worker": self.worker,
            **({"error": self.error} if self.error else {}),
            **({"transfer": self.transfer} if self.transfer is not None else {}),
            **({"polish": self.polish} if self.polish is not None else {}),
        }


def solve_run(
    task_ref: dict, k: int, seed: int, noise: float, transfer: bool = False, search: bool = False
) -> RunResult:
    """Runs on a worker: multi-start's start ``k`` (the task loaded there, solved from its
    guess perturbed by run ``k``'s draw, metrics and goal), or with ``search`` the task's
    search and polish with the search's seed perturbed instead (``studies.search.
    search_start``), and with ``transfer`` its plan played back (``played_back``); a failure
    is recorded as a run that did not meet the goal."""
    started = time.time()
    if search:
        from hydroilqr.studies.search import search_start  # noqa: PLC0415 - it imports this module

        r = search_start(task_ref, k, seed, noise)
    else:
        r = solve_start(task_ref, k, seed, noise)
    sol = r.solution
    res = RunResult(task=task_ref["label"], index=k, error=r.error, seconds=r.seconds)
    res.polish = getattr(r, "polish", None)
    res.started, res.finished, res.worker = started, time.time(), os.getpid()
    try:
        cfg = load_task(
            task_ref["name"], task_ref["overrides"], task_ref["config"], task_ref["smoke"]
        )
        res.threads = solve_threads(cfg.solver)
    except ConfigError:
        pass  # (the failed solve says why)
    if sol is None:
        res.goal_met = False
        return res
    res.status, res.iterations = sol.status, int(sol.iterations)
    res.final_cost = r.cost if math.isfinite(r.cost) else None
    res.goal_met = False if r.error else r.goal.get("met")
    res.checks = r.goal.get("checks", [])
    if transfer and not r.error:
        res.transfer = played_back(task_ref, sol)
    return res


def solve_threads(solver) -> int:
    """Cores one solve with the settings ``solver`` keeps busy at most: its finite-difference
    threads (``solver.threads``, 0 = one per core), its AutoDiff or line-search worker
    processes (``autodiff_workers``, ``line_search_workers``; 1: in its own process)."""
    fd = solver.derivatives in ("forward", "central")
    derivatives = num_threads(solver.threads if fd else solver.autodiff_workers)
    return max(derivatives, num_threads(solver.line_search_workers))


def most_at_once(runs: Sequence[RunResult]) -> int:
    """The most solves that ran at the same time (from their start and end times)."""
    events = sorted(
        [(r.started, 1) for r in runs if r.finished]
        + [(r.finished, -1) for r in runs if r.finished]
    )  # (an end before a start at the same instant: not overlapping)
    most = now = 0
    for _, step in events:
        now += step
        most = max(most, now)
    return most


def loop_settings(task, smoke: bool = False):
    """The closed loop a robustness run simulates: the task's ``mpc:`` settings, lock-step;
    under ``smoke`` at most ``SMOKE_UPDATES`` updates (as ``hydroilqr mpc --smoke``)."""
    settings = mpc_config(task, realtime=False)
    if smoke and settings.rate > 0:
        settings.duration = min(settings.duration, SMOKE_UPDATES / settings.rate)
    return settings


def loop_run(task_ref: dict, k: int, seed: int, noise: float) -> RunResult:
    """Runs on a worker: the task's closed loop (``loop_settings``) whose first plan starts
    from the initial guess perturbed by run ``k``'s draw (``multistart.perturbation``), judged
    by the loop's goal; a failure (or a plant that failed mid-run) is a run that did not meet
    it. ``status``: ``ran`` or ``plant_failed``; ``iterations``: over all updates."""
    t0, started = time.perf_counter(), time.time()
    res = RunResult(task=task_ref["label"], index=k)
    try:
        task = Task.load(
            task_ref["name"], task_ref["overrides"], task_ref["config"], task_ref["smoke"]
        )
        res.threads = solve_threads(task.config.solver)
        loop = prepare(task, loop_settings(task, task_ref["smoke"]))
        U0 = loop.ctrl.U
        limits = getattr(task.dynamics, "effort_limits", np.full(U0.shape[1], np.inf))
        loop.ctrl.seed(perturbation(U0, limits, noise, seed, k))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            out = loop.run()
        goal = judge_loop(task.config, loop_metrics(task, out))
        res.status = "plant_failed" if out.failure else "ran"
        res.iterations = int(sum(out.iterations))
        res.goal_met = False if out.failure else goal.get("met")
        res.checks = goal.get("checks", [])
        res.error = out.failure
    except Exception as e:  # noqa: BLE001 - a failed run is data; the others go on
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        res.error = f"{type(e).__name__}: {first}"[:300]
        res.goal_met = False
    res.seconds = time.perf_counter() - t0
    res.started, res.finished, res.worker = started, time.time(), os.getpid()
    return res


def played_back(task_ref: dict, sol) -> dict:
    """The plan ``sol`` of the task ``task_ref`` played back at half speed (``HALF_SPEED``):
    {"goal_met": the task's goal on the executed motion, "failed_checks", "values": each
    check's executed value, "resting_gap": the object's, or None}; {"error": ...} if the
    playback failed."""
    try:
        task = Task.load(
            task_ref["name"], task_ref["overrides"], task_ref["config"], task_ref["smoke"]
        )
        pb = playback(task, sol, PlaybackSettings(**HALF_SPEED))
        goal = executed_goal(task, sol, pb)["goal"]
    except Exception as e:  # noqa: BLE001 - a failed playback is data; the runs go on
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        return {"error": f"{type(e).__name__}: {first}"[:300]}
    gap = (pb.metrics.get("object") or {}).get("resting_gap")
    return {
        "goal_met": goal.get("met"),
        "failed_checks": [c["metric"] for c in goal.get("checks", []) if not c.get("passed")],
        "values": {c["metric"]: c.get("value") for c in goal.get("checks", [])},
        "resting_gap": None if gap is None else float(gap),
    }


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
        "check_spread": check_spread(runs, names),
        "failed_runs": sum(bool(r.error) for r in runs),
        "statuses": {s: sum(r.status == s for r in runs) for s in sorted({r.status for r in runs})},
        "median_seconds": float(np.median([r.seconds for r in runs])) if runs else None,
        **({"transfer": _transfer_summary(runs)} if any(r.transfer for r in runs) else {}),
        "results": [r.record() for r in sorted(runs, key=lambda r: r.index)],
    }


def check_spread(runs: Sequence[RunResult], names: list[str]) -> dict:
    """Per goal check, how close the runs came to its bound: the values' min, median and
    max, and the worst run's value and slack (``metrics.goals``: how far inside its nearest
    bound, negative beyond it)."""
    out = {}
    for name in names:
        recs = [c for r in runs for c in r.checks if c["metric"] == name]
        values = [c["value"] for c in recs if c.get("value") is not None]
        slacks = [c for c in recs if c.get("slack") is not None]
        if not values:
            continue
        worst = min(slacks, key=lambda c: c["slack"]) if slacks else None
        out[name] = {
            "bound": recs[0].get("require"),
            "min": float(min(values)),
            "median": float(np.median(values)),
            "max": float(max(values)),
            "worst": None if worst is None else worst["value"],
            "worst_slack": None if worst is None else worst["slack"],
        }
    return out


def spread_lines(report: dict) -> list[str]:
    """One line per task and goal check: min / median / max over the runs and the worst run
    against its bound (a pass rate alone hides a run 1.3 mm inside a 20 mm limit)."""
    lines = []
    for t in report["tasks"]:
        for name, s in (t.get("check_spread") or {}).items():
            worst = (
                ""
                if s["worst"] is None
                else f"; worst {s['worst']:.4g} against {s['bound']} (slack {s['worst_slack']:.3g})"
            )
            lines.append(
                f"  {t['task']} {name}: min {s['min']:.4g}, median {s['median']:.4g}, "
                f"max {s['max']:.4g}{worst}"
            )
    return lines


def _transfer_summary(runs: Sequence[RunResult]) -> dict:
    """Over the runs played back: how many met the goal on the executed motion, each goal
    check's executed values (min, median, largest) and the object's resting gaps (median,
    largest)."""
    played = [r.transfer for r in runs if r.transfer]
    gaps = [t["resting_gap"] for t in played if t.get("resting_gap") is not None]
    return {
        "played": len(played),
        "goal_met": sum(t.get("goal_met") is True for t in played),
        "failed": sum("error" in t for t in played),
        "executed_values": _executed_spread(played),
        "median_resting_gap": float(np.median(gaps)) if gaps else None,
        "max_resting_gap": float(max(gaps)) if gaps else None,
    }


def _executed_spread(played: Sequence[dict]) -> dict:
    """Per goal check, its values on the executed motions: {min, median, max}."""
    out: dict = {}
    for t in played:
        for name, v in (t.get("values") or {}).items():
            if v is not None:
                out.setdefault(name, []).append(float(v))
    return {
        k: {"min": min(v), "median": float(np.median(v)), "max": max(v)} for k, v in out.items()
    }


def run_robustness(
    task_refs: Sequence[dict],
    runs: int = DEFAULT_RUNS,
    noise: float = DEFAULT_NOISE,
    seed: int = 0,
    scheduler: str | None = None,
    workers: int | None = None,
    on_run: Callable[[RunResult], None] | None = None,
    transfer: bool = False,
    mpc: bool = False,
    search: bool = False,
) -> dict:
    """Solves every task of ``task_refs`` ``runs`` times (all runs of all tasks as one pool of
    Dask jobs) and returns the report: ``{"noise", "seed", "runs", "tasks": [summary per
    task], "environment", "transfer"}``. A ``task_ref``: {label, name, overrides, config,
    smoke}. ``on_run(result)`` is called as each run finishes (progress display);
    ``transfer``: each plan is also played back (``played_back``); ``mpc``: each run is the
    task's closed loop (``loop_run``) instead of a solve; ``search``: each run is the task's
    search (seed ``seed + k - 1``) and polish instead of iLQR alone."""

    env = json_safe(environment())  # (the code and machine the runs start on)
    client, cluster = open_client(scheduler, workers)
    by_task: dict[str, list[RunResult]] = {ref["label"]: [] for ref in task_refs}
    n_workers = len(client.scheduler_info().get("workers", {}))
    try:
        futures = [
            client.submit(
                *((loop_run, ref, k, seed, noise) if mpc else (solve_run, ref, k, seed, noise)),
                *(() if mpc else (transfer, search)),
                pure=False,
                key=f"robust-{ref['label']}-{k}",
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
        "transfer": transfer,
        **({"search": True} if search else {}),
        "workers": n_workers,  # each runs one solve at a time
        "most_solves_at_once": most_at_once([r for rs in by_task.values() for r in rs]),
        "threads_per_solve": {
            label: max((r.threads for r in rs), default=0) for label, rs in by_task.items()
        },
        "mpc": mpc,
    }


def table(report: dict) -> str:
    """The report as a Markdown table: per task, the goal's pass rate and each check's (of
    the closed loops with ``mpc``); with transfer, the goal's pass rate on the executed
    motions and the resting gaps."""
    if report.get("transfer"):
        return _transfer_table(report)
    what = "closed loop" if report.get("mpc") else "solve"
    rows = [
        f"| task | goal met | per check | statuses | median {what} s |",
        "|---|---|---|---|---|",
    ]
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


def _transfer_table(report: dict) -> str:
    rows = [
        "| task | goal met (plan) | goal met (played back) | resting gap cm median / largest "
        "| median solve s |",
        "|---|---|---|---|---|",
    ]
    for t in report["tasks"]:
        n, tr = t["runs"], t.get("transfer") or {}
        goal = f"{t['goal_met']} of {n}" if t["goal_declared"] else "no goal"
        played = f"{tr['goal_met']} of {tr['played']}" if tr.get("played") else "none played"
        med, top = tr.get("median_resting_gap"), tr.get("max_resting_gap")
        gaps = "" if med is None else f"{100 * med:.1f} / {100 * top:.1f}"
        sec = t["median_seconds"]
        rows.append(
            f"| `{t['task']}` | {goal} | {played} | {gaps} | "
            f"{'' if sec is None else f'{sec:.1f}'} |"
        )
    return "\n".join(rows)
