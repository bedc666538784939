"""Metric ``terms``: each task-space cost term (``cost.terms``, model/terms.py) on the solution.

At the last step of each term's window (its last running step, or the last state for a terminal
term): ``term_error.<name>`` = |r|, the unweighted residual (m for a position, height or
distance, m/s for a velocity; 0 for a bound that holds), and ``term_final.<name>`` = what the
term measures there (the point's [x, y, z] or velocity, the height or the signed distance).
A goal can check them (``term_error.reach: {max: 0.02}``). Each term's cost is in the
``default`` metric's ``cost_terms`` as ``terms.<name>``.
"""

from __future__ import annotations

from hydroilqr.metrics.registry import Metric, register
from hydroilqr.problem.errors import ConfigError


def term_metrics(task, sol) -> dict:
    terms = task.cost.task_terms
    if terms is None:
        return {}
    report = terms.report(sol.X, float(sol.t[0]), sol.t)  # (an MPC run's own time grid)
    return {
        "term_error": {name: r["error"] for name, r in report.items()},
        "term_final": {name: r["final"] for name, r in report.items()},
    }


def terms_on_guess(task) -> list[dict]:
    """Each task-space term on the rollout of the task's initial guess over its horizon (or
    first window): name, type, cost, error and final (as in ``report``); ``hydroilqr check``
    lists them. Empty for a task without terms."""
    terms = task.cost.task_terms
    if terms is None:
        return []
    X = task.dynamics.rollout(task.x0, task.initial_guess(task.steps))
    report = terms.report(X, 0.0)
    out = []
    for t in terms.terms:
        r = report.get(t.name, {"cost": 0.0, "error": None, "final": None})
        out.append(
            {
                "name": t.name,
                "type": t.cfg.type,
                "weight": t.cfg.weight,
                "stage_weights": _stage_weights(task, t.name, t.cfg.weight),
                **r,
            }
        )
    return out


def _stage_weights(task, name: str, weight) -> dict[int, object]:
    """{stage index: the term's weight there} for the continuation stages that change it (an
    approach term switched on in a first stage)."""
    out = {}
    for i, stage in enumerate(task.stages() if task.config.continuation else []):
        w = next((c.weight for c in stage.config.cost.terms if c.name == name), None)
        if w is not None and w != weight:
            out[i] = w
    return out


def validate_terms(task) -> None:
    if not task.config.cost.terms:
        raise ConfigError("metrics: the terms metric needs cost.terms (the task has none)")


def _term_errors(m: dict) -> list[str]:
    """Each task-space term's final error, in its units."""
    return [
        f"term {term} err {err:.3g}"
        for term, err in (m.get("term_error") or {}).items()
        if isinstance(err, (int, float)) and not isinstance(err, bool)
    ]


register(Metric("terms", compute=term_metrics, validate=validate_terms, headline_more=_term_errors))
