"""The sections of dotted overrides that vary a task: ``continuation`` stages, ``ensemble``
members and ``mismatch`` cases, and what ``--truth-set`` may change."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.overrides import override_text, parse_override
from hydroilqr.problem.paths import anchor_mapping
from hydroilqr.problem.task import TaskConfig

# What a "real" (simulated) system may differ in from the controller's model: --truth-set.
TRUTH_SECTIONS = ("models", "package_map", "scene", "geometry", "plant", "actuators")
# Keys of the simulated plant that playback's own options set.
PLAYBACK_OWN = {
    "plant.time_step": "--truth-time-step",
    "plant.contact_approximation": "--truth-contact",
}


# Keys of the simulated plant that MPC's own option sets.
MPC_OWN = {"plant.time_step": "--plant-time-step (mpc.plant_time_step)"}


def check_truth_overrides(overrides: list[str], playback: bool = False, mpc: bool = False) -> None:
    """ConfigError for a --truth-set key the simulated plant does not use (solver, cost, ...);
    with ``playback`` (``mpc``), also for a key playback (the closed loop) sets with its own
    options (playback: the time step and contact approximation; MPC: the time step)."""
    own, who = (PLAYBACK_OWN, "playback") if playback else (MPC_OWN, "the closed loop")
    top = {f.name for f in dataclasses.fields(TaskConfig)}
    for text in overrides:
        key, value = parse_override(text)
        first = key.split(".")[0]
        if first in top and first not in TRUTH_SECTIONS:
            raise ConfigError(
                f"--truth-set {key}: the simulated plant only uses {', '.join(TRUTH_SECTIONS)} "
                "(and geometry/scene shorthands)"
            )
        if not (playback or mpc):
            continue
        nested = value if key == "plant" and isinstance(value, dict) else {}
        for k, option in own.items():
            if key == k or k.split(".")[1] in nested:
                raise ConfigError(f"--truth-set {k}: {who} sets it with {option}")


# Keys a continuation stage or an ensemble member cannot override (the time grid and start).
_FIXED_KEYS = ("continuation", "receding_horizon", "smoke", "name", "horizon", "num_steps")
_FIXED_KEYS += (
    "initial_state",
    "initial_guess",
    "ensemble",
    "ensemble_weight",
    "ensemble_warm_start",
    "mismatch",
)


def _check_overrides(section: str, i: int, item: Any, why: str, fixed=()) -> None:
    """``section[i]``: a non-empty mapping of dotted keys, none of which changes the time grid
    or the start (nor a key of ``fixed``); ConfigError saying ``why`` otherwise."""
    if not isinstance(item, dict) or not item:
        raise ConfigError(
            f"{section}[{i}]: expected a mapping of dotted keys to values, e.g. "
            "{ball_collision.hydroelastic_modulus: 5.0e+5}"
        )
    for key in item:
        first = str(key).split(".")[0]
        if first in _FIXED_KEYS + tuple(fixed) or str(key) == "plant.time_step":
            raise ConfigError(f"{section}[{i}]: {key} cannot change {why}")


def validate_continuation(cfg: TaskConfig) -> None:
    """Each stage: a mapping of dotted keys that leave the time grid and start alone."""
    why = "between stages (every stage solves the task's time grid from its initial state)"
    for i, stage in enumerate(cfg.continuation):
        _check_overrides("continuation", i, stage, why)
    if cfg.continuation and cfg.receding_horizon is not None:
        raise ConfigError("continuation: for single solves (not with receding_horizon)")


def validate_ensemble(cfg: TaskConfig) -> None:
    """Each member: a mapping of dotted keys that leave the time grid, start and solver alone;
    single solves only; a finite weight >= 0."""
    why = "in an ensemble member (every member shares the task's time grid, start and solver)"
    for i, member in enumerate(cfg.ensemble):
        _check_overrides("ensemble", i, member, why, ("solver", "mpc"))
    if not (math.isfinite(cfg.ensemble_weight) and cfg.ensemble_weight >= 0):
        raise ConfigError(f"ensemble_weight: must be >= 0, got {cfg.ensemble_weight}")
    if cfg.ensemble and cfg.receding_horizon is not None:
        raise ConfigError("ensemble: for single solves (not with receding_horizon)")
    if cfg.ensemble and cfg.continuation:
        raise ConfigError("ensemble: not supported together with continuation (use one of them)")


def validate_mismatch(cfg: TaskConfig) -> None:
    """Each case: a name usable on the command line and a mapping of dotted keys of the
    sections the simulated plant uses (as --truth-set)."""
    if not isinstance(cfg.mismatch, dict):
        raise ConfigError("mismatch: expected a mapping of names to mappings of dotted keys")
    for name, case in cfg.mismatch.items():
        ok = isinstance(name, str) and name and all(c.isalnum() or c in "+-_" for c in name)
        if not ok or name.startswith("-"):
            raise ConfigError(
                f"mismatch: {name!r}: a name of letters, digits and + - _ only, not starting with -"
            )
        if not isinstance(case, dict) or not case:
            raise ConfigError(
                f"mismatch.{name}: expected a mapping of dotted keys to values, e.g. "
                "{ball.friction: 0.14}"
            )
        try:
            check_truth_overrides([override_text(k, v) for k, v in case.items()], playback=True)
        except ConfigError as e:
            raise ConfigError(f"mismatch.{name}: {str(e).removeprefix('--truth-set ')}") from None


def mismatch_overrides(cfg: TaskConfig, name: str) -> list[str]:
    """The ``KEY=VALUE`` truth overrides of the task's mismatch case ``name``, relative paths
    in it made absolute (relative to the task file); ConfigError if it has none."""
    if name not in cfg.mismatch:
        if not cfg.mismatch:
            raise ConfigError(
                f"--mismatch {name}: {cfg.name} names no mismatch cases (the task as solved, in "
                "its summary.json, has no mismatch: section); --truth-set KEY=VALUE changes the "
                "real system directly"
            )
        known = ", ".join(cfg.mismatch)
        raise ConfigError(f"--mismatch {name}: {cfg.name} has no such case (it has: {known})")
    case = anchor_mapping(cfg.mismatch[name], Path(cfg.base_dir) if cfg.base_dir else None)
    return [override_text(k, v) for k, v in case.items()]


def validate_variants(cfg: TaskConfig) -> None:
    """The continuation stages, ensemble members and mismatch cases of a task."""
    validate_continuation(cfg)
    validate_ensemble(cfg)
    validate_mismatch(cfg)
