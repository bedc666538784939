"""``hydroilqr sweep``: solve a task over a grid of parameter values on Dask."""

from __future__ import annotations

import atexit
import logging
import sys

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from hydroilqr.cli.common import (
    add_connect_timeout,
    add_task_args,
    command_line,
    console,
    scheduler_arg,
    task_name_from_args,
)
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.load import load_task

HELP = "solve a task over a grid of parameter values on Dask (e.g. paper Fig. 7)"


def setup(p) -> None:
    add_task_args(p)
    p.add_argument(
        "--param",
        action="append",
        metavar="KEY",
        help="numeric task key to sweep, e.g. tip.hydroelastic_modulus (twice for a grid)",
    )
    p.add_argument(
        "--values",
        action="append",
        metavar="SPEC",
        help="V1,V2,... or logspace:A:B:N or linspace:A:B:N (one per --param)",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="existing Dask scheduler, e.g. tcp://host:8786 (default: a local "
        "cluster, one single-threaded worker process per core)",
    )
    add_connect_timeout(p)
    p.add_argument("--workers", type=int, help="worker processes of the local cluster")
    p.add_argument(
        "--retry-failed",
        action="store_true",
        help="on resume, also recompute points recorded as failed",
    )
    p.add_argument(
        "--out", help="output directory, resumable (default runs/TASK-sweep, runs/TASK-smoke-sweep)"
    )


def run(args) -> int:
    task = task_name_from_args(args)
    if not task:
        raise ConfigError("no task given (try `hydroilqr tasks`)")
    out = args.out or _default_out(task, args)
    keys, specs = args.param or [], args.values or []
    if len(keys) != len(specs):
        raise ConfigError("give one --values after each --param")
    from hydroilqr.studies.sweep import parse_values, run_sweep

    params = [(k, parse_values(v)) for k, v in zip(keys, specs)]
    if args.workers is not None and args.workers < 1:
        raise ConfigError("--workers: must be at least 1")
    scheduler = scheduler_arg(args)
    try:
        res = run_sweep(
            task,
            params,
            out,
            sets=args.set,
            config_file=args.config,
            smoke=args.smoke,
            scheduler=scheduler,
            workers=args.workers,
            retry_failed=args.retry_failed,
            command=command_line(args),
            monitor=ProgressBar(),
        )
    except KeyboardInterrupt:
        _quiet_cluster_teardown()
        raise KeyboardInterrupt(
            f"finished points are kept in {out}: the same command continues the sweep"
        ) from None
    if res["failed"]:
        print(
            f"hydroilqr: {res['failed']} of the sweep's points failed (their errors are in the "
            "error column of sweep.csv; --retry-failed recomputes them)",
            file=sys.stderr,
        )
        return 1
    return 0


def _default_out(task: str, args) -> str:
    """runs/NAME-sweep, NAME the task's name (as solve and mpc use)."""

    name = load_task(task, args.set, args.config, args.smoke).name
    return f"runs/{name}{'-smoke' if args.smoke else ''}-sweep"


class ProgressBar:  # a studies.sweep.SweepMonitor (not imported: Drake loads with it)
    """Rich progress bar: done / running / failed (running from worker start events), and a
    line per finished point above it."""

    def __init__(self):
        self.progress = None
        self.total = self.done = self.failed = 0
        self.running: set[str] = set()
        self.finished_ids: set[str] = set()
        self.id = None

    def message(self, text: str) -> None:
        console.print(text)

    def begin(self, total: int, done: int, failed: int) -> None:
        self.progress = Progress(
            TextColumn("[bold]points"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("running {task.fields[running]}  failed {task.fields[failed]}"),
            TimeElapsedColumn(),
            console=console,
            transient=False,
        )
        self.total, self.done, self.failed = total, done, failed
        self.progress.__enter__()
        self.id = self.progress.add_task(
            "points", total=self.total, completed=self.done, running=0, failed=self.failed
        )

    def end(self) -> None:
        if self.progress is not None:
            self.progress.__exit__(None, None, None)
            self.progress = None

    def started(self, pid: str) -> None:
        if pid not in self.finished_ids:
            self.running.add(pid)
            self._refresh()

    def finished(self, pid: str, row: dict, param_keys: list[str]) -> None:
        self.finished_ids.add(pid)
        self.running.discard(pid)
        self.done += 1
        self.failed += 0 if row.get("status") == "ok" else 1
        self._refresh()
        self.progress.console.print(describe(row, param_keys))

    def _refresh(self) -> None:
        if self.progress is not None:
            self.progress.update(
                self.id, completed=self.done, running=len(self.running), failed=self.failed
            )


def describe(row: dict, param_keys: list[str]) -> str:
    vals = ", ".join(f"{k}={row.get(f'param:{k}'):.4g}" for k in param_keys)
    if row.get("status") != "ok":
        return f"{vals}: [red]failed[/red] ({row.get('error')})"
    extra = ""
    if row.get("max_overlap_m") is not None:
        extra = f", overlap {row['max_overlap_m'] * 1000:.2f} mm"
        if row.get("tunnelled"):
            extra += " [red]tunnelled[/red]"
    status = row.get("solve_status") or ("converged" if row.get("converged") else "stopped")
    return (
        f"{vals}: cost {row['final_cost']:.5g}{extra}, status {status} after "
        f"{row['iterations']} iterations (stop test: {row.get('reason')}), "
        f"{row['wall_seconds']:.1f} s on worker {row.get('worker')}"
        + ("" if row.get("goal_met") is None else f", goal {'PASS' if row['goal_met'] else 'FAIL'}")
    )


def _quiet_cluster_teardown() -> None:
    """After Ctrl+C, close what is left of an embedded Dask cluster here, quietly: interrupted
    while it was starting, Dask's own exit hook would print a long traceback."""

    try:
        from distributed.deploy import spec
    except ImportError:
        return
    logging.getLogger("distributed").setLevel(logging.CRITICAL)
    from hydroilqr.studies.cluster import kill_workers

    for cluster in list(getattr(spec.SpecCluster, "_instances", ())):
        try:
            kill_workers(cluster)  # (their unfinished points are abandoned)
            cluster.close(timeout=5)
        except BaseException:  # noqa: BLE001 - a half-started cluster: nothing more to do
            pass
    hook = getattr(spec, "close_clusters", None)
    if hook is not None:
        atexit.unregister(hook)
