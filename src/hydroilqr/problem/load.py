"""Where the library takes a task in: ``load_task`` (a built-in name or a file), ``build_task``
(YAML data), ``task_from_dict`` (a resolved task) and ``with_overrides``; each builds the
typed task, then ``validate`` checks every section once."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

from hydroilqr.problem.cost import validate_cost
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.files import (
    TASKS_DIR,
    extend,
    load_raw,
    merge,
    task_file,
    without_other_length,
)
from hydroilqr.problem.goal import validate_goal
from hydroilqr.problem.guess import PositionGuess, validate_position_guess, validate_realize_use
from hydroilqr.problem.mpc import validate_mpc
from hydroilqr.problem.overrides import horizon_wins, override_items, parse_override, set_dotted
from hydroilqr.problem.paths import anchor_paths, cwd_path
from hydroilqr.problem.plant import validate_plant
from hydroilqr.problem.receding import validate_receding_horizon
from hydroilqr.problem.search import validate_search
from hydroilqr.problem.smoke import apply_smoke, shrink_search, smoke_section
from hydroilqr.problem.solver import validate_solver
from hydroilqr.problem.task import TaskConfig, validate_task
from hydroilqr.problem.typed import build_dataclass
from hydroilqr.problem.variants import validate_variants


def portable_task(name_or_path: str) -> str:
    """The task argument as a process started in another directory (a Dask worker of
    ``--scheduler``) reads it: a built-in's name as it is, a task file's path made absolute."""
    path = task_file(name_or_path)
    return name_or_path if path.parent.resolve() == TASKS_DIR.resolve() else str(path.resolve())


def portable_override(entry: str) -> str:
    """A ``KEY=VALUE`` override with the relative file path it names made absolute against
    the working directory (as ``with_overrides`` reads it here); any other entry as it is."""
    try:
        key, value = parse_override(entry)
    except ConfigError:
        return entry
    absolute = cwd_path(key, value)
    return entry if absolute == value else f"{key}={absolute}"


def worker_ref(name: str, overrides, config: str | None = None, smoke: bool = False, **extra):
    """What a Dask worker loads a task from (Drake objects do not travel), its files named so
    that a worker started in another directory reads the same ones: ``{name, overrides,
    config, smoke, **extra}`` (``portable_task``, ``portable_override``, ``config``
    absolute)."""
    return {
        **extra,
        "name": portable_task(name),
        "overrides": [portable_override(o) for o in overrides],
        "config": str(Path(config).resolve()) if config else None,
        "smoke": bool(smoke),
    }


def with_overrides(
    cfg: TaskConfig, overrides: list[str] | dict[str, Any] | str, paths_from: Path | None = None
) -> TaskConfig:
    """A copy of a loaded task with overrides applied (validated again): ``key=value``
    strings, or a dict of dotted keys to values. Relative file paths in them are relative to
    the working directory, or to ``paths_from``."""
    d = cfg.to_dict()
    items = override_items(overrides)
    horizon_wins(d, items)
    for key, value in items:
        set_dotted(d, key, cwd_path(key, value, paths_from))
    return task_from_dict(d, cfg.base_dir)


def load_task(
    name_or_path: str,
    overrides: list[str] | dict[str, Any] | None = None,
    config_file: str | None = None,
    smoke: bool = False,
) -> TaskConfig:
    """Loads a built-in task or task file, merges ``config_file`` and ``key=value`` overrides.

    With ``smoke``, the task's own ``smoke`` overrides (or generic ones) shrink it first.
    """
    path = task_file(name_or_path)
    return build_task(load_raw(path), path.resolve().parent, overrides, config_file, smoke, path)


def build_task(
    data: dict[str, Any],
    base_dir: str | Path,
    overrides: list[str] | dict[str, Any] | str | None = None,
    config_file: str | None = None,
    smoke: bool = False,
    path: Path | None = None,
) -> TaskConfig:
    """A TaskConfig from a task's YAML data (paths in it relative to ``base_dir``), with the
    same ``config_file``, ``smoke`` and overrides handling as ``load_task``."""
    data = copy.deepcopy(data)
    base_dir = Path(base_dir).resolve()
    label = path.name if path is not None else "task"
    if path is None and isinstance(data, dict):  # a dict's extends: relative to base_dir
        data = extend(data, base_dir, label)
    if path is not None and data.get("horizon") is not None and data.get("num_steps"):
        raise ConfigError(f"{label}: give horizon or num_steps, not both")
    if config_file:
        extra = load_raw(Path(config_file), "--config file")
        anchor_paths(extra, Path(config_file).resolve().parent)  # its paths: relative to it
        data = merge(without_other_length(data, extra), extra)
    items = override_items(overrides)

    def finish(d: dict[str, Any], shrink: dict[str, Any] | None = None) -> TaskConfig:
        d = copy.deepcopy(d)
        horizon_wins(d, items)
        for key, value in items:
            set_dotted(d, key, cwd_path(key, value))
        if shrink is not None:  # --smoke: a search section shrunk too (given keys win)
            shrink_search(d, {**shrink, **dict(items)})
        if path is not None:
            d.setdefault("name", path.stem)
        cfg = build_dataclass(TaskConfig, d, "")
        cfg.base_dir = str(base_dir)
        validate(cfg)
        return cfg

    if not smoke:
        return finish(data)
    section = smoke_section(data, items)
    small = apply_smoke(data, section)
    finish(data)  # the task's own mistakes, unprefixed, also those the smoke section hides
    try:
        cfg = finish(small, section)
    except ConfigError as e:
        raise ConfigError(f"smoke: {e}") from None
    cfg.smoke_run = True
    return cfg


def task_from_dict(data: dict[str, Any], base_dir: str = ".") -> TaskConfig:
    cfg = build_dataclass(TaskConfig, copy.deepcopy(data), "")
    cfg.base_dir = str(Path(base_dir).resolve())
    validate(cfg)
    return cfg


def validate(cfg: TaskConfig) -> None:
    """Every section's checks that do not need the model (the model-dependent ones run when
    the plant is built: model/plant.py, model/state.py), each section by its own module."""
    validate_variants(cfg)
    validate_plant(cfg)
    validate_task(cfg)
    validate_solver(cfg.solver)
    validate_mpc(cfg.mpc)
    validate_goal(cfg.goal)
    validate_cost(cfg.cost)
    validate_receding_horizon(cfg.receding_horizon)
    validate_search(cfg.search, cfg.steps, bool(cfg.goal))
    if isinstance(cfg.initial_guess, PositionGuess):
        validate_position_guess(cfg.initial_guess)
        validate_realize_use(cfg)
