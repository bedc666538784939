"""Small checks the sections share: a list's length, a weight or number that a cost can be
computed with, and the message for an unknown name."""

from __future__ import annotations

import difflib
import math
from typing import Any

from hydroilqr.problem.errors import ConfigError

MAX_STEPS = 1_000_000  # time steps of one trajectory (a typo such as horizon: 2e6 is refused)


def check_length(values: list[float], n: int, key: str) -> None:
    if len(values) != n:
        raise ConfigError(f"{key}: expected {n} numbers, got {len(values)}")


#: The largest magnitude a cost weight or a nominal value may have: beyond it, squares and
#: sums of the cost overflow floating point long before any result could mean anything.
MAX_MAGNITUDE = 1e50


def check_magnitude(x: Any, key: str) -> None:
    if isinstance(x, (int, float)) and not isinstance(x, bool) and abs(x) > MAX_MAGNITUDE:
        raise ConfigError(
            f"{key}: {x:g} is too large to compute a cost with (at most {MAX_MAGNITUDE:g})"
        )


def check_weight(x: Any, v: Any, key: str, weight: bool) -> None:
    """``x`` (an entry of the value ``v`` at ``key``): a finite number, >= 0 for a weight."""
    if not isinstance(x, (int, float)) or isinstance(x, bool) or not math.isfinite(x):
        try:
            bad = not math.isfinite(float(x))  # "inf", "nan" given as words
        except (TypeError, ValueError):
            bad = False
        what = "finite numbers" if bad or isinstance(x, float) else "numbers"
        raise ConfigError(f"{key}: expected {what}, got {v!r}")
    if weight and x < 0:
        raise ConfigError(f"{key}: weights must be non-negative, got {x}")
    check_magnitude(x, key)


def unknown_key(name: Any, valid: list[str], what: str) -> str:
    """'unknown WHAT (did you mean X? expected one of: ...)' for a name not in ``valid``."""
    close = difflib.get_close_matches(str(name), valid, n=1)
    hint = f"did you mean {close[0]!r}? " if close else ""
    return f"unknown {what} ({hint}expected one of: {', '.join(valid)})"
