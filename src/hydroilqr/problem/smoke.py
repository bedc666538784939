"""``--smoke``: a task shrunk by its ``smoke:`` overrides (or generic ones), a search section
shrunk with it."""

from __future__ import annotations

import copy
from typing import Any

from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.files import without_other_length
from hydroilqr.problem.overrides import set_dotted


def smoke_section(data: dict[str, Any], items: list) -> dict[str, Any]:
    """The overrides --smoke applies: the task's smoke section (or generic ones), changed by
    --set smoke[.KEY]=... items."""
    shrink = data.get("smoke") or _generic_smoke(data)
    keys = {k for k, _ in items}
    if {"smoke.horizon", "smoke.num_steps"} <= keys:
        raise ConfigError("--set: give smoke.horizon or smoke.num_steps, not both")
    for key, value in items:  # --set smoke[.KEY]=... changes what --smoke applies
        head, _, rest = key.partition(".")
        if head != "smoke":
            continue
        if not rest:
            shrink = value  # the whole section
        elif isinstance(shrink, dict):
            # smoke keys are dotted strings themselves; a length given here wins over the
            # section's other one (as every upper layer's does)
            shrink = {**without_other_length(shrink, {rest: value}), rest: value}
    if not isinstance(shrink, dict):
        raise ConfigError("smoke: expected a mapping of dotted keys to values")
    return shrink


def apply_smoke(data: dict[str, Any], shrink: dict[str, Any]) -> dict[str, Any]:
    """A copy of ``data`` with the smoke overrides ``shrink`` applied."""
    shrunk = without_other_length(copy.deepcopy(data), shrink)
    try:
        for key, value in list(shrink.items()):
            if key.split(".")[0] == "smoke":
                raise ConfigError(f"{key}: the smoke section cannot change itself")
            set_dotted(shrunk, key, value)
    except ConfigError as e:
        raise ConfigError(f"smoke: {e}") from None
    return shrunk


#: What --smoke makes of a ``search:`` section (keys the smoke section sets itself win).
SEARCH_SMOKE = {"samples": 6, "iterations": 2, "elites": 2, "polish": 1, "robust_runs": 1}


def shrink_search(shrunk: dict[str, Any], shrink: dict[str, Any]) -> None:
    """A smoke-sized search: a few samples and iterations, at most 3 knots, 1 restart."""
    search = shrunk.get("search")
    if not isinstance(search, dict):
        return
    for key, value in SEARCH_SMOKE.items():
        if f"search.{key}" not in shrink:
            search[key] = value
    if "search.restarts" not in shrink and isinstance(search.get("restarts"), int):
        search["restarts"] = min(search["restarts"], 1)  # (the restart still runs)
    if "search.knots" not in shrink and isinstance(search.get("knots", 8), int):
        search["knots"] = min(search.get("knots", 8), 3)


def _generic_smoke(data: dict[str, Any]) -> dict[str, Any]:
    """Default shrink for tasks without a ``smoke`` section."""
    out: dict[str, Any] = {"solver.max_iterations": 3}
    if data.get("receding_horizon"):
        out.update(
            {
                "receding_horizon.window_steps": 10,
                "receding_horizon.shift_steps": 2,
                "receding_horizon.resolves": 3,
                "receding_horizon.max_iterations": 2,
            }
        )
    else:
        out["num_steps"] = 20
    return out
