"""Task goals: PASS/FAIL checks on a run's metrics.

A task file may declare what success means in the physical world, as bounds on the metrics
its run reports (``summary.json``'s ``metrics``, ``mpc.json``, ``playback.json``)::

    goal:
      target_error_m: {max: 0.03}              # the ball ends within 3 cm of its target
      max_ball_height_gain_m: {min: 0.10}
      diagonal_pair_overlap: {above: lateral_pair_overlap}   # compared with another metric
      duty_factor.FL: {min: 0.2}               # a dotted name reaches into a nested metric

Each check holds when every bound it gives holds: ``min`` (value ≥ min), ``max`` (value ≤ max),
``above`` (value > the named metric), ``below`` (value < the named metric), either by a
``margin`` (default 0; ``{above: lateral_pair_overlap, margin: 0.2}``: value > other + 0.2).
A metric the run did not report, or that is not a finite number, fails its check (with the
reason). The goal is met when every check holds; a task without checks has no goal (``met``
is ``None``).
"""

from __future__ import annotations

import difflib
import math
from types import SimpleNamespace
from typing import Any

import numpy as np

from hydroilqr.metrics.registry import compute
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.goal import GoalCheck


def lookup(metrics: dict, name: str) -> Any:
    """The metric at a dotted ``name`` (``duty_factor.FL``), or None when absent. A key that
    itself contains dots is found before descending."""
    if name in metrics:
        return metrics[name]
    head, _, rest = name.partition(".")
    while rest:
        if head in metrics and isinstance(metrics[head], dict):
            found = lookup(metrics[head], rest)
            if found is not None:
                return found
        more, _, rest = rest.partition(".")
        head = f"{head}.{more}"
    return None


def _number(value: Any) -> float | None:
    if isinstance(value, bool):
        return float(value)
    if isinstance(value, (int, float)) and math.isfinite(float(value)):
        return float(value)
    return None


def evaluate_check(name: str, check: GoalCheck, metrics: dict) -> dict:
    """One check's record: metric, bounds, value, passed, and why it failed."""
    value = _number(lookup(metrics, name))
    record: dict[str, Any] = {"metric": name, "require": check.describe(), "value": value}
    if value is None:
        raw = lookup(metrics, name)
        why = "not reported by this run" if raw is None else f"not a finite number ({raw!r})"
        return {**record, "passed": False, "why": why}
    failures = []
    slack = [value - check.min] if check.min is not None else []
    slack += [check.max - value] if check.max is not None else []
    if check.min is not None and not value >= check.min:
        failures.append(f"{value:.4g} < {check.min:g}")
    if check.max is not None and not value <= check.max:
        failures.append(f"{value:.4g} > {check.max:g}")
    for other, sign in ((check.above, 1.0), (check.below, -1.0)):
        if other is None:
            continue
        ref = _number(lookup(metrics, other))
        if ref is None:
            failures.append(f"{other} not reported")
            continue
        record[other] = ref
        slack.append(sign * (value - ref) - check.margin)
        if not sign * (value - ref) > check.margin:
            bound = f"{ref:.4g}"
            if check.margin:
                bound += f" {'+' if sign > 0 else '-'} {check.margin:g}"
            failures.append(f"{value:.4g} {'<=' if sign > 0 else '>='} {other} {bound}")
    record["passed"] = not failures
    # how far inside its nearest bound the value is (negative: beyond it), in its units
    record["slack"] = float(min(slack)) if slack else None
    if failures:
        record["why"] = "; ".join(failures)
    return record


def evaluate(goal: dict[str, GoalCheck], metrics: dict) -> dict:
    """``{"met": bool | None, "checks": [...]}`` for a run's metrics (``met`` None: no goal)."""
    checks = [evaluate_check(name, check, metrics) for name, check in goal.items()]
    met = all(c["passed"] for c in checks) if checks else None
    return {"met": met, "checks": checks}


def judge(config, metrics: dict) -> dict:
    """The goal record a run writes, ``{"met", "checks", "judged"}``: the goal of the task
    ``config`` (a TaskConfig) evaluated on ``metrics``; ``judged`` is false for a smoke-sized
    run (``config.smoke_run``: its goal is the full task's, reported but not judged)."""
    return {**evaluate(config.goal, metrics), "judged": not config.smoke_run}


def judge_loop(config, metrics: dict) -> dict:
    """The goal record of a closed loop (``mpc.json``): ``mpc.goal`` where the task declares
    one, else its ``goal``, evaluated on the loop's ``metrics``; ``source`` names which."""
    goal, source = (config.mpc.goal, "mpc.goal") if config.mpc.goal else (config.goal, "goal")
    return {**evaluate(goal, metrics), "judged": not config.smoke_run, "source": source}


def verdict_line(result: dict) -> str:
    """``goal: PASS (2/2 checks)`` or ``goal: FAIL (1/2): target_error_m 0.067 > 0.03``."""
    checks = result.get("checks") or []
    if result.get("met") is None:
        return "goal: none declared"
    passed = sum(c["passed"] for c in checks)
    if result["met"]:
        return f"goal: PASS ({passed}/{len(checks)} checks)"
    failed = "; ".join(
        f"{c['metric']} {c.get('why', '')}".strip() for c in checks if not c["passed"]
    )
    return f"goal: FAIL ({passed}/{len(checks)} checks): {failed}"


def reported_names(metrics: dict, prefix: str = "") -> set[str]:
    """Every dotted name a goal could use in ``metrics`` (nested dicts flattened)."""
    names = set()
    for k, v in metrics.items():
        name = f"{prefix}{k}"
        names.add(name)
        if isinstance(v, dict):
            names |= reported_names(v, f"{name}.")
    return names


def check_names(task) -> None:
    """ConfigError, before any solve, for a goal on a metric the task's metrics never report
    (a misspelled name would otherwise fail only after the solve). The names come from the
    task's metrics computed on a two-step rollout of its initial guess; if that probe cannot
    be computed, the names are checked after the solve instead."""
    goals = [("goal", task.config.goal), ("mpc.goal", task.config.mpc.goal)]
    if not any(goal for _, goal in goals):
        return
    names = _probe_names(task)
    if names is None:
        return
    for where_goal, goal in goals:
        _check_goal_names(task, goal, where_goal, names)


def _check_goal_names(task, goal: dict, key: str, names: set[str]) -> None:
    for name, check in goal.items():
        for ref, where in (
            (name, f"{key}.{name}"),
            (check.above, f"{key}.{name}.above"),
            (check.below, f"{key}.{name}.below"),
        ):
            if ref is not None and ref not in names:
                close = difflib.get_close_matches(ref, sorted(names), n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                raise ConfigError(
                    f"{where}: {ref!r} is not a metric of this task's metrics "
                    f"({', '.join(task.config.metrics)}){hint}"
                )


def _probe_names(task) -> set[str] | None:
    try:
        dyn = task.dynamics
        U = task.initial_guess(2)
        X = dyn.rollout(task.x0, U)
        probe = SimpleNamespace(t=dyn.dt * np.arange(3), X=X, U=U, extra={}, costs=[0.0])
        return reported_names(compute(task, probe))
    except Exception:  # noqa: BLE001 - a probe only: the goal is checked after the solve
        return None
