"""The ``cost:`` section: quadratic weights, the nominal, a reference to track, and the
task-space terms (problem/terms.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from hydroilqr.problem.checks import check_magnitude, check_weight
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.terms import TermConfig, validate_term

NOMINAL_TIMES = ("step", "horizon_end")


@dataclass
class CostConfig:
    Q: dict[str, Any] = field(default_factory=dict)
    R: Any = 0.0
    Qf: dict[str, Any] = field(default_factory=dict)
    nominal: dict[str, Any] = field(default_factory=dict)
    nominal_rate: dict[str, Any] = field(default_factory=dict)
    # The time (s) the rate stops: x_nom(t) = nominal + rate * min(t, nominal_rate_until)
    # (None: never).
    nominal_rate_until: float | None = None
    # Blocks (or components) whose ``nominal`` is an offset from their value in the task's
    # initial state (unnamed in ``nominal``: an offset of 0, i.e. stay where they start).
    nominal_relative_to_start: list[str] = field(default_factory=list)
    # When the nominal is taken: "step" (each step's own time, x_nom(t_k)) or "horizon_end"
    # (every step of a solve against x_nom(t_N), the nominal at the end of its horizon: a goal
    # ahead that moves with each receding-horizon window, as in the paper's cheetah code).
    nominal_time: str = "step"
    # Multiply the running weights Q and R by the time step (as the paper's public code does:
    # running cost dt·(x̃ᵀQx̃ + uᵀRu), terminal cost x̃ᵀQ_f x̃ unscaled).
    running_cost_dt: bool = False
    # A solved run (its directory or solution.npz) to track: its states, interpolated in time,
    # are the nominal of the blocks in reference_blocks (empty: every block); after its end
    # the last state is held. Other blocks keep nominal / nominal_rate.
    reference: str = ""
    reference_blocks: list[str] = field(default_factory=list)
    # Task-space terms (TermConfig): named residuals of points, velocities, heights and
    # distances, beside the quadratic terms above.
    terms: list[TermConfig] = field(default_factory=list)


def validate_cost(cost: CostConfig) -> None:
    """The nominal's time base; finite numbers in Q, Qf (non-negative) and nominal_rate."""
    if cost.nominal_time not in NOMINAL_TIMES:
        raise ConfigError(
            f"cost.nominal_time: expected one of {', '.join(NOMINAL_TIMES)}, "
            f"got {cost.nominal_time!r}"
        )
    until = cost.nominal_rate_until
    if until is not None and (
        isinstance(until, bool)
        or not isinstance(until, (int, float))
        or not math.isfinite(until)
        or until < 0
    ):
        raise ConfigError(f"cost.nominal_rate_until: expected a time >= 0 (s), got {until!r}")
    rel = cost.nominal_relative_to_start
    if not isinstance(rel, list) or not all(isinstance(n, str) for n in rel):
        raise ConfigError(
            f"cost.nominal_relative_to_start: expected a list of block names, got {rel!r}"
        )
    for section in ("Q", "Qf", "nominal_rate"):
        for k, v in getattr(cost, section).items():
            vals = v if isinstance(v, list) else [v]
            for x in vals:
                check_weight(x, v, f"cost.{section}.{k}", section != "nominal_rate")
    # (the nominal's and R's types are checked against the model in model/cost.py)
    named = [(f"cost.nominal.{k}", v) for k, v in cost.nominal.items()]
    named += list(cost.R.items()) if isinstance(cost.R, dict) else [("cost.R", cost.R)]
    for key, v in named:
        for x in v if isinstance(v, list) else [v]:
            check_magnitude(x, key)
    names: set[str] = set()
    for i, term in enumerate(cost.terms):
        validate_term(term, f"cost.terms[{i}]", names)


def has_cost_terms(cost: CostConfig) -> bool:
    """Some weight of Q, Qf, R or a task-space term is positive (a malformed R counts: its own
    check says why)."""

    def positive(w: Any) -> bool:
        if isinstance(w, dict):
            return any(positive(v) for v in w.values())
        if isinstance(w, (list, tuple)):
            return any(positive(v) for v in w)
        try:
            return float(w) > 0
        except (TypeError, ValueError):
            return True

    return any(positive(w) for w in (cost.Q, cost.Qf, cost.R)) or any(
        positive(t.weight) for t in cost.terms
    )
