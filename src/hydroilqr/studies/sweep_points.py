"""A sweep's points: parameter values and grids, point ids, one point's solve on a worker
(plain data in and out), a point's files read back, and the table's columns and rows
(``studies/sweep.py`` drives them; re-exported there)."""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from distributed import get_worker

from hydroilqr import metrics as metrics_mod
from hydroilqr.io.environment import code_version
from hydroilqr.io.files import content_hash
from hydroilqr.metrics import validate_task
from hydroilqr.metrics.goals import judge
from hydroilqr.model.task import Task
from hydroilqr.output.report import json_safe
from hydroilqr.output.results import POINT_HASH
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.inputs import MAX_ARRAY_FILE_BYTES, MAX_JSON_BYTES, check_npz, read_bounded
from hydroilqr.problem.load import load_task
from hydroilqr.solver import api

# Columns of every point; a task's metrics add theirs (metrics.sweep_columns) after final_cost,
# and their extra columns before "worker".
POINT_COLUMNS = (
    "final_cost",
    "iterations",
    "converged",
    "wall_seconds",
    "status",
    "error",
)
EXTRA_COLUMNS = (
    "initial_cost",
    "goal_met",
    "solve_status",
    "reason",
    "solve_seconds",
    "worker",
    "code",
)
EVENT_TOPIC = "hydroilqr-sweep"

# ------------------------------------------------------------------------------------------
# Values and points
# ------------------------------------------------------------------------------------------


def _number(text: str, what: str) -> float | int:
    t = text.strip()
    try:
        v = int(t)
    except ValueError:
        try:
            v = float(t)
        except ValueError:
            v = yaml.safe_load(t) if t else None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ConfigError(f"{what}: {text!r} is not a finite number")
    return v


MAX_POINTS = 10_000  # points in one sweep


def parse_values(spec: str) -> list[float | int]:
    """``1,2,3`` | ``logspace:A:B:N`` (A..B inclusive, log spaced) | ``linspace:A:B:N``."""
    spec = spec.strip()
    kind = spec.split(":", 1)[0].lower()
    if kind in ("logspace", "linspace"):
        parts = spec.split(":")
        if len(parts) != 4:
            raise ConfigError(f"--values {spec!r}: expected {kind}:START:STOP:COUNT")
        a, b = (float(_number(p, f"--values {spec!r}")) for p in parts[1:3])
        n = _number(parts[3], f"--values {spec!r}")
        if not isinstance(n, int) or n < 1:
            raise ConfigError(f"--values {spec!r}: COUNT must be a positive integer")
        if n > MAX_POINTS:  # (before numpy allocates them)
            raise ConfigError(f"--values {spec!r}: COUNT {n}; at most {MAX_POINTS} points")
        if kind == "logspace":
            if a <= 0 or b <= 0:
                raise ConfigError(f"--values {spec!r}: logspace needs positive START and STOP")
            vals = np.logspace(math.log10(a), math.log10(b), n)
        else:
            vals = np.linspace(a, b, n)
        # Exact decades where they fall (1e3, not 999.9999999999998).
        vals = [float(f"{v:.12g}") for v in vals]
        if len(set(vals)) != len(vals):
            raise ConfigError(
                f"--values {spec!r}: repeated values (START and STOP too close for COUNT)"
            )
        return vals
    vals = [_number(p, f"--values {spec!r}") for p in spec.split(",") if p.strip()]
    if not vals:
        raise ConfigError(f"--values {spec!r}: no values")
    if len(set(vals)) != len(vals):
        raise ConfigError(f"--values {spec!r}: repeated values")
    return vals


def _changed_leaves(a: Any, b: Any, path: str = "") -> list[tuple[str, Any]]:
    """(dotted path, value in ``b``) of every leaf where two config dicts differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        return [
            leaf
            for k in sorted(set(a) | set(b), key=str)
            for leaf in _changed_leaves(a.get(k), b.get(k), f"{path}.{k}" if path else str(k))
        ]
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [
            leaf
            for i, (x, y) in enumerate(zip(a, b))
            for leaf in _changed_leaves(x, y, f"{path}.{i}")
        ]
    return [] if a == b else [(path, b)]


def check_numeric_params(
    task_arg: str, overrides: dict, cfg_arg, smoke: bool, params: list[tuple[str, list]]
) -> None:
    """ConfigError if a swept key sets anything but numbers in the task (``name`` or
    ``description`` take a number as text: the sweep would solve one task over and over).
    What a key sets: the leaves in which the task differs between two of its values."""

    for key, vals in params:
        a, b = vals[0], vals[-1] if len(vals) > 1 else vals[0] + 1
        try:
            ca, cb = (
                load_task(task_arg, {**overrides, key: v}, cfg_arg, smoke).to_dict() for v in (a, b)
            )
        except ConfigError:
            continue  # an invalid value: its point fails and says why
        for where, v in _changed_leaves(ca, cb):
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ConfigError(
                    f"--param {key}: not a numeric task key (it sets {where}, a {type(v).__name__})"
                )


def grid(params: list[tuple[str, list]]) -> list[dict[str, Any]]:
    """All combinations, the first parameter varying slowest."""
    points: list[dict[str, Any]] = [{}]
    for key, vals in params:
        points = [{**p, key: v} for p in points for v in vals]
    return points


def _canonical(v: Any) -> Any:
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return float(v)
    return v


def point_id(values: dict[str, Any]) -> str:
    """Stable file name for a point: readable prefix + hash of the exact values (numbers in
    one form, since 1000000 and 1e6 build the same task)."""
    canon = json.dumps({k: repr(_canonical(v)) for k, v in values.items()}, sort_keys=True)
    digest = hashlib.sha1(canon.encode()).hexdigest()[:10]
    label = "_".join(f"{k.split('.')[-1][:12]}{v:.4g}" for k, v in values.items())
    label = "".join(c if c.isalnum() or c in "._-+" else "-" for c in label)
    return f"{label}_{digest}"


# ------------------------------------------------------------------------------------------
# The worker side: one point = one independent solve (plain data in, plain data out)
# ------------------------------------------------------------------------------------------


def _scalar(v) -> bool:
    return isinstance(v, (bool, int, float, str, np.floating, np.integer, np.bool_))


def _error_text(e: BaseException) -> str:
    """A failed point's error column: the exception's type and first line."""
    msg = str(e).strip().splitlines()[0] if str(e).strip() else ""
    return f"{type(e).__name__}: {msg}"[:500]


def solve_point(
    task_name: str,
    config_file: str | None,
    smoke: bool,
    overrides: dict[str, Any],
    values: dict[str, Any],
    pid: str,
) -> dict:
    """Runs on a worker. Never raises: a failure comes back as status "failed" + reason."""
    t0 = time.perf_counter()
    row: dict[str, Any] = {"id": pid, **{f"param:{k}": v for k, v in values.items()}}
    try:
        row["code"] = code_version()  # the worker's: a remote one may run other code
    except Exception:  # noqa: BLE001 - recorded by the client then
        pass
    try:
        worker = get_worker()
        row["worker"] = worker.name
        worker.log_event(EVENT_TOPIC, {"id": pid, "state": "running"})
    except Exception:  # noqa: BLE001 - also runs outside Dask (tests, debugging)
        row["worker"] = f"pid{os.getpid()}"
    arrays: dict[str, np.ndarray] = {}
    try:
        task = Task.load(task_name, {**overrides, **values}, config_file, smoke)
        validate_task(task, mismatch=False)  # the cases are checked once, before the jobs
        ts = time.perf_counter()
        with warnings.catch_warnings():
            # Overflow in rejected line-search trials is expected; keep worker logs quiet.
            warnings.simplefilter("ignore", RuntimeWarning)
            sol = api.solve(task)
        row["solve_seconds"] = time.perf_counter() - ts
        # a receding-horizon run's final_cost is its last window's: compare whole trajectories
        cost = float(sol.extra.get("trajectory_cost", sol.final_cost))
        row.update(
            status="ok" if math.isfinite(cost) else "failed",
            error="" if math.isfinite(cost) else "final cost is not finite",
            final_cost=cost,
            initial_cost=float(sol.stats()["initial_cost"]),  # the task model's (continuation)
            iterations=sol.iterations,
            converged=bool(sol.converged),
            solve_status=sol.status,  # solve's word for how it ended (docs/guide.md, section 4)
            reason=sol.reason,
        )
        arrays = {"X": sol.X, "U": sol.U, "t": sol.t, "costs": np.asarray(sol.costs)}
        m = metrics_mod.compute(task, sol)
        row.update({k: v for k, v in m.items() if _scalar(v)})
        # one level of named scalars too: final_error.<Qf block>, cost_terms.<term>, ...
        for k, v in m.items():
            if isinstance(v, dict):
                row.update({f"{k}.{kk}": vv for kk, vv in v.items() if _scalar(vv)})
        goal = judge(task.config, m)
        if goal["met"] is not None:  # the task's goal on this point's plan (as solve judges)
            row["goal_met"] = bool(goal["met"])
        arrays.update(metrics_mod.sweep_arrays(task, sol.X))
    except BaseException as e:  # noqa: BLE001 - a failed point is data, the sweep goes on
        if isinstance(e, (KeyboardInterrupt, SystemExit)):
            raise
        row.update(status="failed", error=_error_text(e))
    row["wall_seconds"] = time.perf_counter() - t0

    return {"row": json_safe(row), "arrays": arrays}


# ------------------------------------------------------------------------------------------
# Files
# ------------------------------------------------------------------------------------------


def point_intact(points_dir: Path, row: dict) -> bool:
    """False for a finished point whose arrays are missing, unreadable, not finite, or
    changed since written (their hash, which covers the row too; points saved before hashes
    have none: checked for readability and finite values only). Failed points have none."""

    path = points_dir / f"{row.get('id')}.npz"
    if not path.exists():
        return row.get("status") != "ok"
    try:
        check_npz(path, "point", MAX_ARRAY_FILE_BYTES)
        with np.load(path, allow_pickle=False) as d:
            arrays = {k: np.array(d[k]) for k in d.files if k != POINT_HASH}
            saved = str(d[POINT_HASH]) if POINT_HASH in d.files else None
    except Exception:  # noqa: BLE001 - torn, foreign or too large: recompute
        return False
    if saved is not None and saved != content_hash(arrays, json.dumps(row, sort_keys=True)):
        return False
    return all(a.dtype.kind not in "fc" or np.all(np.isfinite(a)) for a in arrays.values())


def load_point(points_dir: Path, pid: str) -> dict | None:
    p = points_dir / f"{pid}.json"
    try:
        return json.loads(read_bounded(p, "point", MAX_JSON_BYTES))
    except (OSError, ValueError):
        return None  # missing, or a torn file from before atomic writes: recompute


def columns(
    param_keys: list[str], rows: list[dict], metric_columns: tuple[list, list] = ([], [])
) -> list[str]:
    """Table columns: the swept keys, POINT_COLUMNS with the metrics' columns after
    final_cost, the extra columns (the metrics' before "worker") that points have, then every
    other scalar. metric_columns: ``metrics.sweep_columns`` of the task's metrics."""
    lead, extra = metric_columns
    point = list(POINT_COLUMNS)
    point[1:1] = [c for c in lead if c not in point]
    cols = list(param_keys) + point
    have = set().union(*(r.keys() for r in rows)) if rows else set()
    more = list(EXTRA_COLUMNS)
    more[more.index("worker") : more.index("worker")] = [c for c in extra if c not in more]
    cols += [c for c in more if c in have and c not in cols]
    # Then every other scalar a point reported (task metrics), in a stable order.
    plain = (bool, int, float, str, type(None))
    scalar = {
        k
        for r in rows
        for k, v in r.items()
        if not k.startswith("param:") and k != "id" and isinstance(v, plain)
    }
    cols += sorted(scalar - set(cols))
    return cols


def table_rows(param_keys: list[str], rows: list[dict]) -> list[dict]:
    out = []
    for r in rows:
        d = {k: r.get(f"param:{k}") for k in param_keys}
        d.update({k: v for k, v in r.items() if not k.startswith("param:") and k != "id"})
        d["id"] = r["id"]
        out.append(d)
    return out


def sweep_table(
    spec: dict,
    param_keys: list[str],
    rows: list[dict],
    pending: int,
    metric_columns: tuple[list, list] = ([], []),
) -> tuple[list[str], list[dict], dict]:
    """The sweep's table of ``rows`` (``pending`` points still missing): (its columns, its
    rows sorted by the swept values, sweep.json's dict); ``output.studies.write_sweep_tables``
    writes them."""
    # Sorted by the swept values (points of earlier runs and of an extended grid interleave).
    trs = sorted(
        table_rows(param_keys, rows),
        key=lambda r: tuple(
            (r[k] is None, r[k] if isinstance(r[k], (int, float)) else 0) for k in param_keys
        ),
    )
    cols = columns(param_keys, rows, metric_columns)
    failed = sum(r.get("status") != "ok" for r in rows)
    doc = {
        **spec,
        "summary": {
            "points": len(rows) + pending,
            "done": len(rows) - failed,
            "failed": failed,
            "missing": pending,
        },
        "columns": cols,
        "points": trs,
    }
    return cols, trs, doc
