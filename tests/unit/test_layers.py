"""The layers of docs/architecture.md hold (issue 35): every package imports only packages
below it, counting imports inside functions, so the packages form no import circle; and the
command line loads no Drake before it has checked its input."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[2] / "src" / "hydroilqr"

# Bottom to top; a package may import the packages of lower rank (peers not each other).
RANK = {
    "problem": 0,  # configuration types, loading, validation, bounded reads, errors
    "io": 1,  # atomic files and result sets, figures, the environment
    "model": 2,  # plant, state, derivatives, cost, task-space terms, ensembles, Task
    "solver": 3,  # iLQR and what drives it (continuation, receding horizon, ensembles)
    "metrics": 3,  # metric registry, families, goals
    "control": 4,  # MPC and playback: they return data
    "output": 5,  # result sets: writers, per-run plots, reports, replays
    "studies": 6,  # sweeps, multi-start, robustness, bench, check, the results page
    "cli": 7,  # one module per command
}


def package_imports(src: Path) -> dict[tuple[str, str], list[str]]:
    """(importing package, imported package) -> the modules where it happens, for every
    ``hydroilqr.*`` import anywhere in a module (inside functions too)."""
    edges: dict[tuple[str, str], list[str]] = {}
    for f in sorted(src.rglob("*.py")):
        parts = f.relative_to(src).with_suffix("").parts
        if len(parts) < 2:  # hydroilqr/__init__.py, __main__.py: the package's entry points
            continue
        mine = parts[0]
        tree = ast.parse(f.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                if node.level:  # relative: resolved against this module's package
                    base = list(parts[: len(parts) - node.level])
                    names = [".".join(["hydroilqr", *base, node.module or ""])]
                else:
                    names = [node.module or ""]
                if names[0] == "hydroilqr":  # from hydroilqr import metrics
                    names = [f"hydroilqr.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            for name in names:
                p = name.split(".")
                if p[0] == "hydroilqr" and len(p) > 1 and p[1] in RANK and p[1] != mine:
                    edges.setdefault((mine, p[1]), []).append(str(f.relative_to(src)))
    return edges


def violations(src: Path) -> list[str]:
    return [
        f"{a} imports {b} ({', '.join(sorted(set(where)))})"
        for (a, b), where in sorted(package_imports(src).items())
        if RANK.get(a, -1) <= RANK[b]
    ]


def test_every_package_imports_only_lower_layers():
    packages = {p.name for p in SRC.iterdir() if (p / "__init__.py").exists()}
    assert packages == set(RANK), "a package the layer table does not place"
    assert violations(SRC) == []


def test_the_problem_layer_imports_no_package_above_it():
    assert not [e for e in package_imports(SRC) if e[0] == "problem"]


def test_a_deliberate_upward_import_is_caught(tmp_path):
    for pkg in ("problem", "model"):
        (tmp_path / pkg).mkdir()
        (tmp_path / pkg / "__init__.py").write_text("")
    (tmp_path / "model" / "plant.py").write_text("from hydroilqr.problem import task\n")
    (tmp_path / "problem" / "task.py").write_text(
        "def late():\n    from hydroilqr.model.plant import Dynamics\n    return Dynamics\n"
    )
    assert violations(tmp_path) == ["problem imports model (problem/task.py)"]


# Inside problem/, bottom to top: a module imports modules of its rank or lower only. The
# sections (one module per task-file section) know nothing of how a task file is loaded.
PROBLEM_RANK = {
    "errors": 0,
    "capabilities": 0,
    "checks": 1,  # small checks the sections share
    "inputs": 1,  # bounded reads of user files
    **dict.fromkeys(
        ["goal", "guess", "solver", "receding", "search", "terms", "playback", "plant"], 2
    ),
    "cost": 3,  # holds the terms
    "mpc": 3,  # holds its goal
    "task": 4,  # TaskConfig: every section
    "typed": 5,  # the loading pipeline: typed building, ...
    "paths": 5,
    "files": 6,  # ... YAML files and extends, ...
    "overrides": 7,  # ... dotted keys, ...
    "variants": 8,  # ... continuation, ensemble, mismatch (dotted overrides themselves), ...
    "smoke": 8,
    "load": 9,  # ... where the library takes a task in (and validates it)
    "schema": 9,
}


def problem_imports(src: Path) -> list[tuple[str, str]]:
    """(module, imported module) for every import of a module of problem/ by another."""
    edges = []
    for f in sorted((src / "problem").glob("*.py")):
        tree = ast.parse(f.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(
                "hydroilqr.problem."
            ):
                edges.append((f.stem, node.module.split(".")[2]))
    return edges


def test_the_sections_of_problem_import_nothing_of_the_loading_pipeline():
    modules = {f.stem for f in (SRC / "problem").glob("*.py")} - {"__init__"}
    assert modules == set(PROBLEM_RANK), "a module of problem/ the rank table does not place"
    upward = [(a, b) for a, b in problem_imports(SRC) if PROBLEM_RANK[a] < PROBLEM_RANK[b]]
    assert upward == []


@pytest.mark.parametrize("module", ["hydroilqr.cli", "hydroilqr.problem.load"])
def test_the_command_line_and_the_config_load_no_drake(module):
    heavy = "('pydrake', 'matplotlib')"
    code = f"import sys, {module}; print(sorted(m for m in {heavy} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
