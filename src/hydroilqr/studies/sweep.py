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

Its parts: ``sweep_points.py`` (values, point ids, one point's solve, the table's rows) and
``sweep_plots.py``; their public names are importable from here.
"""

from __future__ import annotations

import json
import math
import os
import time
from concurrent.futures import CancelledError
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from distributed import as_completed

from hydroilqr import metrics as metrics_mod
from hydroilqr.io.environment import code_version, environment
from hydroilqr.metrics import validate_task
from hydroilqr.model.task import Task
from hydroilqr.output.report import output_dir
from hydroilqr.output.results import write_sweep_point
from hydroilqr.output.studies import (
    COMPUTED_LOG,
    write_sweep_plots,
    write_sweep_spec,
    write_sweep_tables,
)
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.inputs import MAX_JSON_BYTES, read_bounded
from hydroilqr.problem.load import portable_override, portable_task
from hydroilqr.problem.overrides import parse_override
from hydroilqr.problem.paths import cwd_path
from hydroilqr.studies.cluster import open_client
from hydroilqr.studies.sweep_plots import goal_panels, plot_sweep
from hydroilqr.studies.sweep_points import (
    EVENT_TOPIC,
    EXTRA_COLUMNS,
    MAX_POINTS,
    POINT_COLUMNS,
    _error_text,
    check_numeric_params,
    columns,
    grid,
    load_point,
    parse_values,
    point_id,
    point_intact,
    solve_point,
    sweep_table,
    table_rows,
)

__all__ = [
    "EVENT_TOPIC",
    "EXTRA_COLUMNS",
    "MAX_POINTS",
    "POINT_COLUMNS",
    "SweepMonitor",
    "check_numeric_params",
    "columns",
    "goal_panels",
    "grid",
    "load_point",
    "parse_values",
    "plot_sweep",
    "point_id",
    "point_intact",
    "run_sweep",
    "solve_point",
    "table_rows",
    "sweep_table",
]


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
            old["set"] = sorted(portable_override(v) for v in old["set"])
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
    task_arg = portable_task(task)
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
    write_sweep_spec(out, spec)

    sw = _Sweep(task_arg, cfg_arg, bool(smoke), overrides, keys, points, out, spec, metric_cols)
    todo = sw.load_done(retry_failed, monitor)
    sw.load_earlier()
    sw.load_log()
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
    log: str | None = None  # computed.log: one line per point computed by any run

    def __post_init__(self) -> None:
        self.points_dir = self.out / "points"
        self.ids = [point_id(p) for p in self.points]

    def load_done(self, retry_failed: bool, monitor: SweepMonitor) -> list[int]:
        """Reads the points already computed into ``rows``; the indices of those to compute."""
        todo: list[int] = []
        for i, pid in enumerate(self.ids):
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

    def load_log(self) -> None:
        """computed.log of earlier runs (None: no run computed a point here yet)."""
        path = self.out / COMPUTED_LOG
        if path.exists():
            self.log = read_bounded(path, "computed log", MAX_JSON_BYTES).decode(errors="replace")

    def write_tables(self, rows: list[dict]) -> None:
        missing = len(self.points) - len(self.rows)
        cols, trs, doc = sweep_table(self.spec, self.keys, rows, missing, self.metric_cols)
        write_sweep_tables(self.out, cols, trs, doc, self.log)


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
    sw.log = (sw.log or "") + f"{sw.ids[i]}\t{row.get('status')}\t{time.time():.0f}\n"
    monitor.finished(sw.ids[i], row, sw.keys)
    sw.write_tables(sw.ordered())
    return True


def _plot(sw: _Sweep, params: list[tuple[str, list]], all_rows: list[dict], task_cfg) -> list:
    """sweep.png and the sweep plots of the task's metrics (e.g. the cart-pole's
    snapshots.png); the names written."""
    return write_sweep_plots(sw.out, lambda d: _draw(d, sw, params, all_rows, task_cfg))


def _draw(directory: Path, sw: _Sweep, params, all_rows: list[dict], task_cfg) -> list:
    """Draws the sweep's plots into ``directory``; their names."""
    keys = sw.keys
    grid_values = [
        sorted({r[f"param:{k}"] for r in all_rows}, key=float) if sw.earlier_rows else v
        for k, v in params
    ]
    panels = goal_panels(task_cfg.goal)
    panels += [p for p in metrics_mod.sweep_panels(task_cfg.metrics) if p[0] not in task_cfg.goal]
    plot_sweep(
        directory / "sweep.png", task_cfg.name, keys, all_rows, grid_values, panels, task_cfg.goal
    )
    wrote = ["sweep.png"]
    for name, plot in metrics_mod.sweep_plots(task_cfg.metrics):
        if plot(directory / name, sw.points_dir, task_cfg, keys, all_rows):
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
