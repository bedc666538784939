"""``hydroilqr sweep``: a parameter study, one independent iLQR solve per point on Dask.

    hydroilqr sweep cartpole-wall --param tip.hydroelastic_modulus \\
        --values logspace:1e3:1e9:13 --out runs/sweep

Each point is a task on a Dask distributed cluster (an embedded ``LocalCluster`` with one
single-threaded worker process per core by default, or ``--scheduler ADDRESS``). Workers get
only strings and numbers (task name/file, overrides) and build their own Drake objects.

Output directory:

    points/<id>.json   one finished point (written atomically; its presence = done)
    points/<id>.npz    the point's trajectory X, U, t and its costs (+ tip/pin/cart positions
                       and the contact pair's signed distance, with the cartpole_wall metric)
    sweep.csv/json     the table, rebuilt from points/ after every finished point
    sweep.png          metric(s) against the parameter (paper Fig. 7 for cartpole-wall)
    snapshots.png      configurations of maximum overlap (tasks with the cartpole_wall metric)
    computed.log       one line per point computed by a run (resume leaves finished ones alone)

Rerunning the same command in the same directory computes only the points without a file.
"""

from __future__ import annotations

import csv
import hashlib
import io
import itertools
import json
import math
import os
import time
import warnings
from concurrent.futures import CancelledError
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from distributed import as_completed, get_worker

from hydroilqr import metrics as metrics_mod
from hydroilqr.io.environment import code_version, environment
from hydroilqr.io.figures import pyplot, savefig
from hydroilqr.io.files import atomic_write, content_hash
from hydroilqr.metrics import validate_task
from hydroilqr.metrics.goals import judge
from hydroilqr.model.task import Task
from hydroilqr.output.report import json_safe, output_dir
from hydroilqr.output.results import POINT_HASH, write_sweep_point
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.files import TASKS_DIR, task_file
from hydroilqr.problem.inputs import MAX_ARRAY_FILE_BYTES, MAX_JSON_BYTES, check_npz, read_bounded
from hydroilqr.problem.load import load_task
from hydroilqr.problem.overrides import parse_override
from hydroilqr.problem.paths import cwd_path
from hydroilqr.solver import api
from hydroilqr.studies.cluster import open_client

plt = pyplot()

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


def point_id(values: dict[str, Any], spelled: dict[str, str] | None = None) -> str:
    """Stable file name for a point: readable prefix + hash of the exact values. ``spelled``:
    the values' text as hashed (default: numbers in one form, since 1000000 and 1e6 build the
    same task; sweeps before 2026-11-23 hashed ``repr`` of the value as typed)."""
    canon = json.dumps(
        spelled or {k: repr(_canonical(v)) for k, v in values.items()},
        sort_keys=True,
    )
    digest = hashlib.sha1(canon.encode()).hexdigest()[:10]
    label = "_".join(f"{k.split('.')[-1][:12]}{v:.4g}" for k, v in values.items())
    label = "".join(c if c.isalnum() or c in "._-+" else "-" for c in label)
    return f"{label}_{digest}"


def _older_ids(values: dict[str, Any]) -> list[str]:
    """The ids an older sweep gave these values (each number hashed as typed: int or float)."""

    forms = []
    for v in values.values():
        f = {repr(v)}
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            f.add(repr(float(v)))
            if float(v).is_integer():
                f.add(repr(int(v)))
        forms.append(sorted(f))
    keys = list(values)
    ids = {point_id(values, dict(zip(keys, combo))) for combo in itertools.product(*forms)}
    return sorted(ids - {point_id(values)})


def _adopt_older_point(points_dir: Path, values: dict[str, Any], pid: str) -> None:
    """Renames an older sweep's files for these values to the current id (kept, not redone)."""
    if (points_dir / f"{pid}.json").exists():
        return
    for old in _older_ids(values):
        r = load_point(points_dir, old)
        if r is None:
            continue
        r["id"] = pid
        if (points_dir / f"{old}.npz").exists():
            os.replace(points_dir / f"{old}.npz", points_dir / f"{pid}.npz")
        atomic_write(points_dir / f"{pid}.json", json.dumps(r, indent=1))
        (points_dir / f"{old}.json").unlink()
        return


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


def write_tables(
    out: Path,
    spec: dict,
    param_keys: list[str],
    rows: list[dict],
    pending: int,
    metric_columns: tuple[list, list] = ([], []),
) -> None:
    # Sorted by the swept values (points of earlier runs and of an extended grid interleave).
    trs = sorted(
        table_rows(param_keys, rows),
        key=lambda r: tuple(
            (r[k] is None, r[k] if isinstance(r[k], (int, float)) else 0) for k in param_keys
        ),
    )
    cols = columns(param_keys, rows, metric_columns)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols + ["id"], extrasaction="ignore")
    w.writeheader()
    for r in trs:
        w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in cols + ["id"]})
    atomic_write(out / "sweep.csv", buf.getvalue())
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
    atomic_write(out / "sweep.json", json.dumps(json_safe(doc), indent=1))


# ------------------------------------------------------------------------------------------
# Plots
# ------------------------------------------------------------------------------------------


def _log_axis(vals: list) -> bool:
    v = [float(x) for x in vals if x is not None]
    return bool(v) and min(v) > 0 and max(v) / min(v) >= 100


def goal_panels(goal: dict) -> list[tuple[str, str]]:
    """(metric, axis label) of each goal check with a fixed bound, its bounds in the label."""
    return [
        (name, f"{name}\n(goal: {check.describe()})")
        for name, check in goal.items()
        if check.min is not None or check.max is not None
    ]


def _bounds(goal: dict, metric: str) -> list[float]:
    check = goal.get(metric)
    return [] if check is None else [b for b in (check.min, check.max) if b is not None]


def plot_sweep(
    path: Path,
    task_name: str,
    param_keys: list[str],
    rows: list[dict],
    grid_values: list[list],
    metric_panels: list[tuple[str, str]] = (),
    goal: dict | None = None,
) -> None:
    """sweep.png: each of ``metric_panels`` ((key, axis label), from the task's metrics) that
    some point reports, and the final cost, against the first parameter (a series per value
    of the second)."""
    key = param_keys[0]
    other = param_keys[1] if len(param_keys) > 1 else None
    shown = [(k, lab) for k, lab in metric_panels if any(r.get(k) is not None for r in rows)]
    panels = [k for k, _ in shown] + ["final_cost"]
    labels = {**dict(shown), "final_cost": "final cost"}  # circles: "not converged" in legend
    fig, axes = plt.subplots(
        len(panels), 1, figsize=(6.2, 2.7 * len(panels) + 0.4), sharex=True, squeeze=False
    )
    series = (
        [(None, rows)]
        if other is None
        else [(v, [r for r in rows if r.get(f"param:{other}") == v]) for v in grid_values[1]]
    )
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, metric in zip(axes[:, 0], panels):
        labelled: set[str] = set()  # each marker kind in the legend once, whichever series

        def once(kind: str, labelled=labelled) -> str | None:
            if kind in labelled:
                return None
            labelled.add(kind)
            return kind

        for j, (ov, rs) in enumerate(series):
            ok = sorted((r for r in rs if r.get("status") == "ok"), key=lambda r: r[f"param:{key}"])
            xs = [r[f"param:{key}"] for r in ok]
            ys = [r.get(metric) for r in ok]
            c = colors[j % len(colors)]
            lab = None if ov is None else f"{other} = {ov:.4g}"
            ax.plot(xs, [np.nan if y is None else y for y in ys], "o-", color=c, ms=5, label=lab)
            tun = [(x, y) for x, y, r in zip(xs, ys, ok) if r.get("tunnelled") and y is not None]
            if tun:
                ax.plot(
                    *zip(*tun),
                    "x",
                    color="red",
                    ms=11,
                    mew=2.5,
                    label=once("tunnelled"),
                )
            nconv = [
                (x, y) for x, y, r in zip(xs, ys, ok) if not r.get("converged") and y is not None
            ]
            if nconv:
                ax.plot(
                    *zip(*nconv),
                    "o",
                    mfc="none",
                    mec="k",
                    ms=10,
                    label=once("not converged"),
                )
            bad = [r[f"param:{key}"] for r in rs if r.get("status") != "ok"]
            for x in bad:
                ax.axvline(x, color="gray", ls=":", lw=1.2, label=once("failed"))
        for b in _bounds(goal or {}, metric):  # the goal's bound on this metric
            ax.axhline(b, color="C3", ls="--", lw=1, label=once("goal bound"))
        ax.set_ylabel(labels.get(metric, metric))
        # log when the values span decades (overlap: 0.2 mm stiff, 100 mm tunnelled); not
        # when one is 0 (no contact), which a log axis would drop
        vals = [r.get(metric) for r in rows if r.get("status") == "ok"]
        vals = [v for v in vals if v is not None]
        if vals and min(vals) > 0 and max(vals) / min(vals) > 20:
            ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    ax = axes[-1, 0]
    if _log_axis(grid_values[0]):
        ax.set_xscale("log")
    ax.set_xlabel(key + (" [Pa]" if key.endswith("hydroelastic_modulus") else ""))
    axes[0, 0].set_title(f"{task_name}: sweep of {key}")
    savefig(fig, path)


# ------------------------------------------------------------------------------------------
# The driver
# ------------------------------------------------------------------------------------------


class SweepMonitor:
    """What ``run_sweep`` reports while it runs; this base class ignores all of it (the command
    line's subclass draws a progress bar)."""

    def message(self, text: str) -> None:
        """A line for the user (rich markup): the plan, the cluster, notes, the summary."""

    def begin(self, total: int, done: int, failed: int) -> None:
        """Points are about to be computed: ``done`` of ``total`` are already (``failed`` of
        them failed)."""

    def started(self, pid: str) -> None:
        """A worker started point ``pid`` (as far as the cluster reports it)."""

    def finished(self, pid: str, row: dict, param_keys: list[str]) -> None:
        """Point ``pid`` finished with table row ``row`` (``row["status"]``: "ok" or not)."""

    def end(self) -> None:
        """No more points are computed in this run (also after an error or Ctrl+C)."""


def _absolute_set(entry: str) -> str:
    """A recorded ``KEY=VALUE`` with a relative file path made absolute (against the working
    directory), as this version records it."""
    try:
        k, v = parse_override(entry)
    except ConfigError:
        return entry
    absolute = cwd_path(k, v)
    return entry if absolute == v else f"{k}={absolute}"


def _check_same_sweep(out: Path, spec: dict) -> None:
    """ConfigError if ``out`` holds the points of another sweep (its sweep_spec.json differs
    in task, --config, --smoke, --set or the swept keys), or a spec too torn to tell."""
    spec_file, points_dir = out / "sweep_spec.json", out / "points"
    keys = [p["key"] for p in spec["params"]]
    if not spec_file.exists():
        return
    try:
        old = json.loads(read_bounded(spec_file, "sweep spec", MAX_JSON_BYTES))
    except (ValueError, OSError):
        old = None
    if not isinstance(old, dict) and any(points_dir.iterdir()):
        raise ConfigError(
            f"{spec_file}: unreadable, so the points in {points_dir} cannot be matched to "
            "this sweep; remove the directory or choose another --out"
        )
    if isinstance(old, dict):
        if "solver.threads=1" in old.get("set", []) and "solver.threads=1" not in spec["set"]:
            old["set"] = [v for v in old["set"] if v != "solver.threads=1"]  # older files
        if isinstance(old.get("set"), list):  # older files kept relative paths as given
            old["set"] = sorted(_absolute_set(v) for v in old["set"])
        same = {k: old.get(k) for k in ("task", "config_file", "smoke", "set")}
        new = {k: spec.get(k) for k in same}
        old_keys = [p["key"] for p in old.get("params", [])]
        if same != new or old_keys != keys:
            names = {"config_file": "--config", "smoke": "--smoke", "set": "--set"}
            differ = [names.get(k, k) for k in same if same[k] != new[k]]
            differ += ["--param"] if old_keys != keys else []
            raise ConfigError(
                f"{out} holds a different sweep ({', '.join(differ)} differ; it has task "
                f"{old.get('task')}, --param {', '.join(old_keys)}, --set "
                f"{old.get('set') or 'none'}, smoke {old.get('smoke')}): choose another --out"
            )


def run_sweep(
    task: str,
    params: list[tuple[str, list]],
    out: str | Path,
    *,
    sets: list[str] | None = None,
    config_file: str | None = None,
    smoke: bool = False,
    scheduler: str | None = None,
    workers: int | None = None,
    retry_failed: bool = False,
    plots: bool = True,
    command: str | None = None,
    monitor: SweepMonitor | None = None,
) -> dict:
    """Runs (or resumes) a sweep; returns {"rows", "computed", "skipped", "failed"}.
    ``command``: the command line, recorded in sweep_spec.json; ``monitor``: receives the
    progress (by default nothing is shown)."""
    monitor = monitor or SweepMonitor()
    keys = _check_params(params)
    path = task_file(task)
    task_arg = task if path.parent.resolve() == TASKS_DIR.resolve() else str(path.resolve())
    cfg_arg = str(Path(config_file).resolve()) if config_file else None
    overrides, user_set = _sweep_overrides(sets)
    points = _sweep_points(params)
    task_cfg = _first_and_last(task_arg, overrides, cfg_arg, smoke, points)

    metric_cols = metrics_mod.sweep_columns(task_cfg.metrics)
    check_numeric_params(task_arg, overrides, cfg_arg, smoke, params)

    out = Path(out)

    output_dir(out, task_cfg.name)
    (out / "points").mkdir(parents=True, exist_ok=True)
    spec = {
        "task": task_cfg.name,
        "task_arg": task_arg,
        "config_file": cfg_arg,
        "smoke": bool(smoke),
        "set": user_set,  # as given (solver.threads=1 is added unless set)
        "params": [{"key": k, "values": v} for k, v in params],
        "environment": environment(command),  # of this process (points: see their code column)
    }
    _check_same_sweep(out, spec)
    atomic_write(out / "sweep_spec.json", json.dumps(spec, indent=1))

    sw = _Sweep(task_arg, cfg_arg, bool(smoke), overrides, keys, points, out, spec, metric_cols)
    todo = sw.load_done(retry_failed, monitor)
    sw.load_earlier()
    n_failed0 = sum(r.get("status") != "ok" for r in sw.rows.values())
    monitor.message(
        f"[bold]sweep[/bold] {task_cfg.name}: "
        + " x ".join(f"{k} ({len(v)})" for k, v in params)
        + f" = {len(points)} points; {len(sw.rows)} already done, {len(todo)} to compute"
        + f" -> {out}"
    )
    computed = 0
    lost = 0  # points whose futures the scheduler cancelled or lost

    code = code_version()
    if todo:
        computed, lost = _compute(sw, todo, scheduler, workers, monitor, n_failed0, code)
    all_rows = sw.ordered()  # this grid's points and those kept from earlier runs
    sw.write_tables(all_rows)
    if lost:
        raise ConfigError(
            f"the Dask scheduler went away (or cancelled the work): {lost} point(s) not "
            "computed; run the same command again to compute them (finished points are kept)"
        )
    wrote = ["sweep.csv", "sweep.json"]
    if plots and all_rows:
        wrote += _plot(sw, params, all_rows, task_cfg)
    return _finish(sw, all_rows, computed, wrote, monitor)


def _check_params(params: list[tuple[str, list]]) -> list[str]:
    """The swept keys: one or two, each once."""
    if not params:
        raise ConfigError("give at least one --param KEY --values ...")
    keys = [k for k, _ in params]
    if len(set(keys)) != len(keys):
        raise ConfigError("--param: the same key twice")
    if len(params) > 2:
        raise ConfigError("--param: at most two parameters (a grid)")
    return keys


def _sweep_overrides(sets: list[str] | None) -> tuple[dict[str, Any], list[str]]:
    """The --set overrides every point gets (one solver thread unless set), and the user's
    own, as recorded in sweep_spec.json."""
    overrides: dict[str, Any] = {}
    for s in sets or []:
        k, v = parse_override(s)
        # a relative file path is the user's working directory's, here and on remote workers
        overrides[k] = cwd_path(k, v)
    user_set = sorted(f"{k}={v}" for k, v in overrides.items())
    # One thread per solve: the cluster already runs one worker process per core.
    if not any(k == "solver.threads" for k in overrides):
        overrides["solver.threads"] = 1
    return overrides, user_set


def _sweep_points(params: list[tuple[str, list]]) -> list[dict]:
    """The grid's points (at most MAX_POINTS)."""
    n = math.prod(len(v) for _, v in params)
    if n > MAX_POINTS:  # each point is a solve with its own directory and a row of the table
        raise ConfigError(
            f"--values: {n} points; at most {MAX_POINTS} in one sweep (fewer values, or split "
            "the range over several sweeps into the same --out)"
        )
    return grid(params)


def _first_and_last(task_arg: str, overrides: dict, cfg_arg, smoke: bool, points: list):
    """Fails fast on a bad key/value: builds the first and last point here; the last's
    TaskConfig."""

    for p in (points[0], points[-1]):
        t = Task.load(task_arg, {**overrides, **p}, cfg_arg, smoke)
        validate_task(t)
    return t.config


@dataclass
class _Sweep:
    """One run of a sweep: what its points are solved from, their rows (this grid's, and
    ``earlier_rows`` kept from earlier runs with other values) and where the tables go."""

    task_arg: str
    cfg_arg: str | None
    smoke: bool
    overrides: dict[str, Any]
    keys: list[str]
    points: list[dict]
    out: Path
    spec: dict
    metric_cols: list
    rows: dict[str, dict] = field(default_factory=dict)
    earlier_rows: list[dict] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.points_dir = self.out / "points"
        self.ids = [point_id(p) for p in self.points]

    def load_done(self, retry_failed: bool, monitor: SweepMonitor) -> list[int]:
        """Reads the points already computed into ``rows``; the indices of those to compute."""
        todo: list[int] = []
        for i, pid in enumerate(self.ids):
            _adopt_older_point(self.points_dir, self.points[i], pid)
            r = load_point(self.points_dir, pid)
            if r is not None and not point_intact(self.points_dir, r):
                monitor.message(
                    f"[yellow]note:[/yellow] point {pid}: its files are damaged; recomputed"
                )
                r = None
            if r is not None and not (retry_failed and r.get("status") != "ok"):
                self.rows[pid] = r
            else:
                todo.append(i)
        return todo

    def load_earlier(self) -> None:
        """Points of earlier runs of this sweep with other values stay in the table (a sweep
        is extended, or re-run on a subset, without losing what it already computed)."""
        earlier = {}
        for f in sorted(self.points_dir.glob("*.json")):
            if f.stem in self.ids or f.name.startswith("."):
                continue
            r = load_point(self.points_dir, f.stem)
            if r is not None and all(f"param:{k}" in r for k in self.keys):
                earlier[f.stem] = r
        keys = self.keys
        self.earlier_rows = sorted(
            earlier.values(), key=lambda r: [float(r[f"param:{k}"]) for k in keys]
        )

    def ordered(self) -> list[dict]:
        return [self.rows[pid] for pid in self.ids if pid in self.rows] + self.earlier_rows

    def write_tables(self, rows: list[dict]) -> None:
        missing = len(self.points) - len(self.rows)
        write_tables(self.out, self.spec, self.keys, rows, missing, self.metric_cols)


def _compute(sw: _Sweep, todo: list[int], scheduler, workers, monitor, n_failed0, code):
    """Solves the points ``todo`` on Dask, saving each as it finishes; (computed, lost)."""
    if scheduler and workers:
        monitor.message(
            f"[yellow]note:[/yellow] --workers {workers} is ignored with --scheduler (the "
            "cluster's own workers run the points)"
        )
    client, cluster = open_client(scheduler, workers)
    try:
        nthreads = sum(client.nthreads().values())
        where = scheduler or f"local cluster, {len(client.nthreads())} worker processes"
        monitor.message(f"dask: {where}, {nthreads} threads")
        monitor.begin(len(sw.points), len(sw.rows), n_failed0)
        try:
            _subscribe(client, monitor)
            futures = _submit(client, sw, todo)
            computed = lost = 0
            for fut in as_completed(list(futures)):
                if _record(sw, fut, futures[fut], monitor, code):
                    computed += 1
                else:
                    lost += 1
            try:
                client.unsubscribe_topic(EVENT_TOPIC)
            except Exception:  # noqa: BLE001
                pass
        finally:
            monitor.end()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return computed, lost


def _subscribe(client, monitor: SweepMonitor) -> None:
    """Tells ``monitor`` when a worker starts a point (if the scheduler relays events)."""

    def on_event(event):
        msg = event[1] if isinstance(event, tuple) else event
        if isinstance(msg, dict) and msg.get("state") == "running":
            monitor.started(msg.get("id"))

    try:
        client.subscribe_topic(EVENT_TOPIC, on_event)
    except Exception:  # noqa: BLE001 - running count is cosmetic
        pass


def _submit(client, sw: _Sweep, todo: list[int]) -> dict:
    """future -> index of its point, for each point of ``todo``."""
    futures = {}
    for i in todo:
        f = client.submit(
            solve_point,
            sw.task_arg,
            sw.cfg_arg,
            sw.smoke,
            sw.overrides,
            sw.points[i],
            sw.ids[i],
            pure=False,
            key=f"hydroilqr-point-{sw.ids[i]}-{os.getpid()}-{time.time_ns()}",
        )
        futures[f] = i
    return futures


def _record(sw: _Sweep, fut, i: int, monitor: SweepMonitor, code: str) -> bool:
    """Saves point ``i``'s result (a failed row if its worker raised), logs it and rewrites
    the tables; False if the scheduler cancelled or lost it."""
    try:
        result = fut.result()
    except CancelledError:
        # the scheduler went away (or cancelled it): the point was not computed,
        # so it stays missing and a plain rerun computes it
        return False
    except Exception as e:  # noqa: BLE001 - e.g. the worker died (KilledWorker)
        result = {
            "row": {
                "id": sw.ids[i],
                **{f"param:{k}": v for k, v in sw.points[i].items()},
                "status": "failed",
                "error": _error_text(e),
            },
            "arrays": {},
        }
    result["row"].setdefault("code", code)
    write_sweep_point(sw.points_dir, result)
    row = result["row"]
    sw.rows[sw.ids[i]] = row
    with open(sw.out / "computed.log", "a") as fh:
        fh.write(f"{sw.ids[i]}\t{row.get('status')}\t{time.time():.0f}\n")
    monitor.finished(sw.ids[i], row, sw.keys)
    sw.write_tables(sw.ordered())
    return True


def _plot(sw: _Sweep, params: list[tuple[str, list]], all_rows: list[dict], task_cfg) -> list:
    """sweep.png and the sweep plots of the task's metrics (e.g. the cart-pole's
    snapshots.png); the names written."""
    keys = sw.keys
    grid_values = [
        sorted({r[f"param:{k}"] for r in all_rows}, key=float) if sw.earlier_rows else v
        for k, v in params
    ]
    panels = goal_panels(task_cfg.goal)
    panels += [p for p in metrics_mod.sweep_panels(task_cfg.metrics) if p[0] not in task_cfg.goal]
    plot_sweep(
        sw.out / "sweep.png", task_cfg.name, keys, all_rows, grid_values, panels, task_cfg.goal
    )
    wrote = ["sweep.png"]
    for name, plot in metrics_mod.sweep_plots(task_cfg.metrics):
        if plot(sw.out / name, sw.points_dir, task_cfg, keys, all_rows):
            wrote.append(name)
    return wrote


def _finish(sw: _Sweep, all_rows: list[dict], computed: int, wrote: list, monitor) -> dict:
    """Reports the sweep's counts (and mixed code versions); run_sweep's result."""
    failed = sum(sw.rows[pid].get("status") != "ok" for pid in sw.ids if pid in sw.rows)
    versions = {r.get("code") for r in all_rows if r.get("code")}
    if len(versions) > 1:
        monitor.message(
            f"[yellow]note:[/yellow] the points were computed by {len(versions)} code "
            f"versions ({', '.join(sorted(versions))}); see the code column"
        )
    n, earlier = len(sw.points), sw.earlier_rows
    monitor.message(
        f"{n} points ({computed} computed now, "
        f"{n - computed} from earlier runs), {failed} failed"
        + (f"; the table also keeps {len(earlier)} points of earlier runs" if earlier else "")
        + f"; wrote {', '.join(wrote)} in {sw.out}"
    )
    return {
        "rows": all_rows,
        "computed": computed,
        "skipped": n - computed,
        "failed": failed,
    }
