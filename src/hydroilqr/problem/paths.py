"""Relative file paths in a task: anchored to the file that names them (``extends``,
``--config``, smoke and continuation stages) or to the working directory (``--set``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hydroilqr.problem.guess import GUESS_KEYWORDS


def anchor_paths(data: dict[str, Any], base_dir: Path) -> None:
    """Makes the relative file paths of a task read from ``base_dir`` absolute, so a task that
    ``extends`` a file in another directory still finds that file's models and guesses."""

    def anchor(p: Any) -> Any:
        if not isinstance(p, str) or not p or p.startswith("package://"):
            return p
        path = Path(p).expanduser()
        return str(path if path.is_absolute() else base_dir / path)

    for m in data.get("models") or []:
        if isinstance(m, dict) and "file" in m:
            m["file"] = anchor(m["file"])
    if isinstance(data.get("package_map"), dict):
        data["package_map"] = {k: anchor(v) for k, v in data["package_map"].items()}
    guess = data.get("initial_guess")
    if isinstance(guess, str) and guess not in GUESS_KEYWORDS:
        data["initial_guess"] = anchor(guess)
    cost = data.get("cost")
    if isinstance(cost, dict) and isinstance(cost.get("reference"), str):
        cost["reference"] = anchor(cost["reference"])
    mpc = data.get("mpc")
    if isinstance(mpc, dict) and isinstance(mpc.get("warm_start_plan"), str):
        mpc["warm_start_plan"] = anchor(mpc["warm_start_plan"])
    # dotted overrides (smoke:, continuation stages) name paths too
    if isinstance(data.get("smoke"), dict):
        data["smoke"] = {k: cwd_path(k, v, base_dir) for k, v in data["smoke"].items()}
    for section in ("continuation", "ensemble", "mismatch"):
        if section in data:
            data[section] = cwd_path(section, data[section], base_dir)


def cwd_path(key: str, value: Any, base: Path | None = None) -> Any:
    """A relative file path given on the command line is relative to the working directory
    (``base``: to that directory instead, e.g. a task file's for its continuation stages).
    An empty path stays empty (``cost.reference`` / ``mpc.warm_start_plan``: none). The paths
    inside a whole section of overrides (``ensemble``, ``continuation``, ``mismatch`` or one
    of its cases) are anchored the same way."""
    parts = key.split(".")
    if parts[0] in ("ensemble", "continuation") and len(parts) == 1 and isinstance(value, list):
        return [anchor_mapping(v, base) for v in value]
    if parts[0] == "mismatch" and isinstance(value, dict):
        if len(parts) == 1:
            return {name: anchor_mapping(case, base) for name, case in value.items()}
        if len(parts) == 2:
            return anchor_mapping(value, base)
    is_path = (
        key in ("initial_guess", "cost.reference", "mpc.warm_start_plan")
        or parts[0] == "package_map"
        or (parts[0] == "models" and parts[-1] == "file")
    )
    if (
        not is_path
        or not isinstance(value, str)
        or not value
        or value in GUESS_KEYWORDS
        or value.startswith("package://")
        or Path(value).expanduser().is_absolute()
    ):
        return value
    return str((base or Path.cwd()) / Path(value).expanduser())


def anchor_mapping(overrides: Any, base: Path | None) -> Any:
    """A mapping of dotted overrides with its relative paths anchored (``cwd_path``)."""
    if not isinstance(overrides, dict):
        return overrides
    return {k: cwd_path(str(k), v, base) for k, v in overrides.items()}
