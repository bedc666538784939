"""Dotted overrides (``--set solver.max_iterations=5``, smoke, continuation, ensemble and
mismatch entries): parsed and set into a task's data, with the shorthands for geometry and
scene names and model names that contain dots."""

from __future__ import annotations

import dataclasses
import difflib
import json
from typing import Any

import yaml

from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.files import yaml_value
from hydroilqr.problem.plant import ContactProperties
from hydroilqr.problem.task import TaskConfig

# Sections whose keys are names from the model (state blocks such as ``theta.v`` or
# ``body.position``, actuators, geometries), which may themselves contain dots.
_NAME_MAPS = (
    ("cost", "Q"),
    ("cost", "Qf"),
    ("cost", "R"),
    ("cost", "nominal"),
    ("cost", "nominal_rate"),
    ("initial_state",),
    ("blocks",),
)


def _group_free_keys(parts: list[str]) -> list[str]:
    """Rejoins a model name that a dotted key split: ``cost.Q.theta.v`` sets block ``theta.v``
    of ``cost.Q``; ``geometry.a.b.friction`` sets ``friction`` of geometry ``a.b``."""
    for prefix in _NAME_MAPS:
        n = len(prefix)
        if tuple(parts[:n]) == prefix and len(parts) > n + 1:
            return [*prefix, ".".join(parts[n:])]
    if parts[0] == "geometry" and len(parts) > 3:
        return ["geometry", ".".join(parts[1:-1]), parts[-1]]
    if parts[0] == "mismatch" and len(parts) > 3:  # mismatch.CASE.ball.friction
        return ["mismatch", parts[1], ".".join(parts[2:])]
    if parts[0] == "goal" and len(parts) > 3:  # a goal on a nested metric (duty_factor.FL)
        return ["goal", ".".join(parts[1:-1]), parts[-1]]
    if parts[:2] == ["mpc", "goal"] and len(parts) > 4:  # the closed loop's, likewise
        return ["mpc", "goal", ".".join(parts[2:-1]), parts[-1]]
    return parts


def set_dotted(data: dict[str, Any], key: str, value: Any) -> None:
    parts = key.split(".")
    top = {f.name for f in dataclasses.fields(TaskConfig)}
    if parts[0] not in top:
        geometry = data.get("geometry") or {}
        scene_names = [o.get("name") for o in (data.get("scene") or []) if isinstance(o, dict)]
        if parts[0] in scene_names and parts[0] in geometry:
            raise ConfigError(
                f"{key}: {parts[0]!r} names both a scene object and a geometry entry; write "
                f"scene.{scene_names.index(parts[0])}.{'.'.join(parts[1:])} or geometry.{key}"
            )
        if scene_names.count(parts[0]) > 1:
            raise ConfigError(f"{key}: several scene objects are named {parts[0]!r}")
        if parts[0] in scene_names:
            idx = scene_names.index(parts[0])
            parts = ["scene", str(idx)] + parts[1:]
        elif len(parts) == 2:
            # Shortcut for geometry overrides: tip.hydroelastic_modulus. A geometry the task
            # already names, or a near-miss of a contact property, is taken as one too, so a
            # typo is reported against the contact properties, not the top-level keys.
            fields = [f.name for f in dataclasses.fields(ContactProperties)]
            if (
                parts[0] in geometry
                or parts[1] in fields
                or difflib.get_close_matches(parts[1], fields, n=1)
            ):
                parts = ["geometry"] + parts
    parts = _group_free_keys(parts)
    node: Any = data
    for i, p in enumerate(parts[:-1]):
        where = ".".join(parts[: i + 1])
        if isinstance(node, list):
            node = _list_element(node, p, f"{key}: no list element {where}")
            continue
        if not isinstance(node, dict):
            raise ConfigError(f"{key}: {where} is not a section")
        if node.get(p) is None:
            node[p] = {}
        node = node[p]
    if isinstance(node, list):
        try:
            node[int(parts[-1])] = value
        except (ValueError, IndexError):
            raise ConfigError(f"{key}: no list element") from None
    elif isinstance(node, dict):
        node[parts[-1]] = value
    else:
        parent = ".".join(parts[:-1])
        raise ConfigError(
            f"{key}: {parent} is a single value here; set it as a mapping instead: "
            f"--set '{parent}={{{parts[-1]}: ...}}'"
        )


def _list_element(node: list, p: str, missing: str) -> Any:
    """Element ``p`` of a list in a dotted key: an index, or the one element (a mapping) whose
    ``name`` is ``p`` (``cost.terms.reach.weight``)."""
    named = [e for e in node if isinstance(e, dict) and e.get("name") == p]
    if len(named) == 1 and not p.isdigit():
        return named[0]
    try:
        return node[int(p)]
    except (ValueError, IndexError):
        raise ConfigError(missing) from None


def parse_override(text: str) -> tuple[str, Any]:
    """``key=value`` -> (key, YAML-parsed value)."""
    if "=" not in text:
        raise ConfigError(f"override {text!r}: expected key=value")
    key, raw = text.split("=", 1)
    try:
        value = yaml_value(raw) if raw.strip() else None
    except yaml.YAMLError:
        value = raw
    return key.strip(), value


def horizon_wins(data: dict, items: list[tuple[str, Any]]) -> None:
    """A horizon given as an override wins over the task's num_steps."""
    keys = {k for k, _ in items}
    if "horizon" in keys and "num_steps" in keys:
        raise ConfigError("--set: give horizon or num_steps, not both")
    if "horizon" in keys:
        data["num_steps"] = 0


def override_items(overrides) -> list[tuple[str, Any]]:
    if isinstance(overrides, str):
        overrides = [overrides]
    if isinstance(overrides, dict):
        return list(overrides.items())
    return [parse_override(text) for text in overrides or []]


def override_text(key: str, value: Any) -> str:
    """``KEY=VALUE`` as the command line writes it (a value that is not a string as JSON)."""
    return f"{key}={value if isinstance(value, str) else json.dumps(value)}"
