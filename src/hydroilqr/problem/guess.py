"""The ``initial_guess:`` key: a keyword, a file, or a path of configurations
(``PositionGuess``, model/guess.py turns it into controls)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from hydroilqr.problem.errors import ConfigError

GUESS_KEYWORDS = ("zeros", "gravity_compensation", "hold")


@dataclass
class PositionGuess:
    """``initial_guess`` as a path of configurations (model/guess.py): the controls come from a
    tracking rollout on the task's own plant that follows it. Either ``waypoints`` (each
    ``{t: SECONDS, BLOCK: value, ...}``, in increasing time; a waypoint that does not name a
    block keeps the previous one's value) or ``target`` (one configuration, reached at the
    task's end). The path starts from the initial state at t = 0 and holds after its last
    point; with ``period`` > 0 (s, after the last waypoint) it returns to the initial state's
    values at t = period and repeats."""

    waypoints: list[dict[str, Any]] = field(default_factory=list)
    target: dict[str, Any] = field(default_factory=dict)
    period: float = 0.0
    # Realize the path's unactuated coordinates with virtual forces (solver/realize.py);
    # none: the tracking rollout moves them only as far as the actuators do.
    realize: Realize | None = None


@dataclass
class Realize:
    """``initial_guess.realize``: before the solve, virtual forces act on the unactuated
    coordinates the path names (one actuator each, on their joints); the tracking rollout uses
    them, then one iLQR stage per ``weights`` entry solves the task with the virtual forces
    costed by that weight (their R), each stage warm-starting the next; the task itself is
    then solved on its own plant, without them, from the last stage's plan (its actuators'
    controls, rolled out under that stage's feedback gains)."""

    weights: list[float] = field(default_factory=lambda: [1.0e-3, 1.0e-2, 1.0e-1, 1.0, 10.0, 100.0])
    iterations: int = 5  # iLQR iterations per stage


def validate_position_guess(g: PositionGuess, key: str = "initial_guess") -> None:
    """One of waypoints / target; times positive, increasing and inside the period; block
    names are checked when the plant is built (model/guess.py)."""
    if bool(g.waypoints) == bool(g.target):
        raise ConfigError(f"{key}: give waypoints (a list of {{t: s, BLOCK: value}}) or target")
    if g.period < 0 or not math.isfinite(g.period):
        raise ConfigError(f"{key}.period: must be >= 0 (0: no repetition), got {g.period}")
    if g.target and g.period:
        raise ConfigError(f"{key}.period: only with waypoints")
    if g.target and "t" in g.target:
        raise ConfigError(f"{key}.target: has no time (it is reached at the task's end)")
    last = 0.0
    for i, wp in enumerate(g.waypoints):
        t = wp.get("t")
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t):
            raise ConfigError(f"{key}.waypoints[{i}].t: expected a time in seconds, got {t!r}")
        if t <= last:
            raise ConfigError(
                f"{key}.waypoints[{i}].t: {t:g} s must be after the previous point ({last:g} s)"
            )
        if g.period and t >= g.period:
            raise ConfigError(f"{key}.waypoints[{i}].t: {t:g} s must be before period {g.period:g}")
        if len(wp) < 2:
            raise ConfigError(f"{key}.waypoints[{i}]: names no block")
        _check_configuration(wp, f"{key}.waypoints[{i}]")
        last = float(t)
    _check_configuration(g.target, f"{key}.target")
    if g.realize is not None:
        validate_realize(g.realize, f"{key}.realize")


def validate_realize(r: Realize, key: str) -> None:
    """At least one stage; finite, positive, non-decreasing weights; iterations >= 1. Which
    coordinates the path names is checked when the plant is built (model/guess.py)."""
    w = r.weights
    if not w:
        raise ConfigError(f"{key}.weights: give at least one stage's weight, e.g. [1.0e-3, 10]")
    for i, x in enumerate(w):
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) or x <= 0:
            raise ConfigError(f"{key}.weights[{i}]: expected a finite number > 0, got {x!r}")
    if any(b < a for a, b in zip(w, w[1:])):
        raise ConfigError(
            f"{key}.weights: must not decrease (a continuation drives the virtual forces "
            f"to zero), got {w}"
        )
    if isinstance(r.iterations, bool) or r.iterations < 1:
        raise ConfigError(f"{key}.iterations: must be >= 1, got {r.iterations}")


def _check_configuration(point: dict[str, Any], key: str) -> None:
    """Each block's value of a waypoint or target is a number or a flat list of numbers."""
    for name, v in point.items():
        if name == "t":
            continue
        values = v if isinstance(v, list) else [v]
        if not values or not all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
            for x in values
        ):
            raise ConfigError(
                f"{key}.{name}: expected a number or a list of numbers (one per component), "
                f"got {v!r}"
            )


def validate_realize_use(cfg) -> None:
    """``initial_guess.realize`` is for a single solve from the guess: not with a receding
    horizon, an ensemble or a search (whose samples replace the guess)."""
    if cfg.initial_guess.realize is None:
        return
    for key, on in (
        ("receding_horizon", cfg.receding_horizon is not None),
        ("ensemble", bool(cfg.ensemble)),
        ("search", cfg.search is not None),
    ):
        if on:
            raise ConfigError(
                f"initial_guess.realize: for a single solve from the guess, not with {key}"
            )
