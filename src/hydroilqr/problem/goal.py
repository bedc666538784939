"""The ``goal:`` section (and ``mpc.goal``): bounds on a run's metrics (hydroilqr.metrics.goals
judges them)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from hydroilqr.problem.errors import ConfigError

BOUNDS = ("min", "max", "above", "below")  # the bounds of a goal check


@dataclass
class GoalCheck:
    """Bounds on one metric (all given bounds must hold)."""

    min: float | None = None
    max: float | None = None
    above: str | None = None  # the name of another metric that this one must exceed
    below: str | None = None  # the name of another metric that this one must stay under
    # by how much (above: value > other + margin; below: value < other - margin)
    margin: float = 0.0

    def describe(self) -> str:
        parts = []
        if self.min is not None:
            parts.append(f">= {self.min:g}")
        if self.max is not None:
            parts.append(f"<= {self.max:g}")
        extra = f" + {self.margin:g}" if self.margin else ""
        if self.above is not None:
            parts.append(f"> {self.above}{extra}")
        if self.below is not None:
            parts.append(f"< {self.below}{extra.replace('+', '-')}")
        return " and ".join(parts)


def validate_goal(goal: dict[str, GoalCheck], where: str = "goal") -> None:
    """Raises ConfigError for a check with no bound or with inverted bounds."""
    for name, check in goal.items():
        key = f"{where}.{name}"
        if not name:
            raise ConfigError(f"{where}: a check needs a metric name")
        if all(getattr(check, b) is None for b in BOUNDS):
            raise ConfigError(f"{key}: give at least one of {', '.join(BOUNDS)}")
        if check.min is not None and check.max is not None and check.min > check.max:
            raise ConfigError(f"{key}: min {check.min:g} is above max {check.max:g}")
        if check.margin:
            if check.above is None and check.below is None:
                raise ConfigError(f"{key}.margin: a margin needs above or below")
            if not math.isfinite(check.margin) or check.margin < 0:
                raise ConfigError(f"{key}.margin: expected a number >= 0, got {check.margin:g}")
