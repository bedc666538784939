"""``hydroilqr search``: a task's sampling search alone, its best sample written as a result set."""

from __future__ import annotations

import time
from pathlib import Path

from hydroilqr.cli.common import (
    add_connect_timeout,
    add_task_args,
    command_line,
    console,
    err_console,
    load_task_from_args,
    print_goal,
    scheduler_arg,
)
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.load import worker_ref
from hydroilqr.problem.search import check_searchable

HELP = "sample the task's plan across basins (its search: section) and write the best sample"


def setup(p) -> None:
    add_task_args(p)
    p.add_argument(
        "--out",
        help="output directory (default runs/TASK-search, ...-smoke; with --throughput "
        "runs/TASK-throughput, for throughput.json)",
    )
    p.add_argument(
        "--scheduler", metavar="ADDRESS", help="an existing Dask scheduler (default: a local one)"
    )
    add_connect_timeout(p)
    p.add_argument("--workers", type=int, help="local worker processes (default: cores)")
    p.add_argument("--no-replay", action="store_true", help="skip writing replay.html")
    p.add_argument(
        "--throughput",
        metavar="COUNTS",
        help="instead of searching: samples per second of the task's rollouts with each number "
        "of local workers, side by side (e.g. 1,2), and the overhead of a batch",
    )


def task_ref(args, extra: list[str]) -> dict:
    """What a worker loads the task from (Drake objects do not travel)."""
    return worker_ref(args.task_file or args.task, [*args.set, *extra], args.config, args.smoke)


def searched_task(args):
    """(task, extra overrides): a task without a ``search:`` section searches with the
    defaults (the section is added, so --smoke shrinks it as it would a written one)."""
    task = load_task_from_args(args)
    check_searchable(task.config)
    if task.config.search is not None:
        return task, []
    extra = ["search.method=cem"]
    console.print("no search: section in the task: the defaults (docs/task-format.md)")
    return load_task_from_args(args, extra), extra


def check_workers(args) -> None:
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers: must be at least 1, got {args.workers}")
    if args.workers is not None and args.scheduler:
        raise ConfigError("--workers starts a local cluster; drop it with --scheduler")
    scheduler_arg(args)  # (--connect-timeout checked)


def run(args) -> int:
    task, extra = searched_task(args)  # (before Drake is loaded)
    check_workers(args)
    if args.throughput:
        return _throughput(task, args, extra)
    from hydroilqr.output import report
    from hydroilqr.output.progress import SearchProgress
    from hydroilqr.solver.search import total_iterations
    from hydroilqr.studies.search import run_search

    out = Path(args.out or f"runs/{task.name}-search{'-smoke' if args.smoke else ''}")
    report.output_dir(out, task.name)
    sc = task.config.search
    where = args.scheduler or "a local Dask cluster"
    console.print(
        f"[bold]{task.name}[/bold]: {sc.method} over {sc.knots} knots (order {sc.order}, "
        f"{sc.space} space), {sc.samples} samples x {sc.iterations} iterations, seed {sc.seed}, "
        f"on {where} -> {out}"
    )
    t0 = time.perf_counter()
    with SearchProgress(total_iterations(task.config), console) as prog:
        srun = run_search(task_ref(args, extra), scheduler_arg(args), args.workers, prog.update)
    wall = time.perf_counter() - t0
    print_search_line(srun, wall)
    summary = write(task, srun, out, args, wall)
    if srun.lost:
        return workers_lost(srun, out, "the best sample found before")
    if srun.interrupted:
        console.print(f"interrupted: {out} holds the best sample found before Ctrl+C")
        print_goal(summary["goal"], args.smoke, "the best sample kept at Ctrl+C")
        return 130
    return print_goal(summary["goal"], args.smoke, "the best sample, as searched")


def workers_lost(srun, out: Path, kept: str) -> int:
    """One line on stderr when every Dask worker was lost (``SearchRun.lost``): exit 3."""
    err_console.print(f"hydroilqr: {srun.lost}; {out} holds {kept}", soft_wrap=True)
    return 3


def print_search_line(srun, wall: float) -> None:
    r = srun.result
    if r.windows:  # (a window's nominal prices that window only)
        head = f"search: {len(r.windows)} windows, the stitched plan's cost {r.best.cost:.6g},"
    else:
        head = f"search: best cost {r.best.cost:.6g} (nominal {r.costs[0, 0]:.6g})"
    console.print(
        f"{head} after "
        f"{len(r.history)} iterations, {r.samples} samples in {r.seconds:.1f} s "
        f"({r.samples / max(r.seconds, 1e-9):.1f} samples/s on {srun.workers} worker(s)); "
        f"{wall:.1f} s in all",
        soft_wrap=True,
    )
    for rs in getattr(srun, "restarts", []):
        console.print(
            f"restart {rs.restart} (seed {rs.seed}): best cost {rs.result.best.cost:.6g}, "
            f"{rs.result.samples} samples in {rs.result.seconds:.1f} s",
            soft_wrap=True,
        )


def write(task, srun, out: Path, args, wall: float) -> dict:
    """The result set of the search's outcome (the chosen plan), with the search's record
    and plot."""
    from hydroilqr import metrics as metrics_mod
    from hydroilqr.output.results import write_solve

    summary = write_solve(
        task,
        srun.chosen_solution,
        out,
        replay=not args.no_replay,
        wall_seconds=wall,
        command=command_line(args),
        extra_summary={"search": srun.record()},
        search_costs=srun.result.costs,
    )
    for line in metrics_mod.summary_lines(summary["metrics"]):
        console.print(line, soft_wrap=True)
    console.print(f"wrote {out}/ (summary.json, solution.npz, search.png, ...)")
    return summary


def _throughput(task, args, extra: list[str]) -> int:
    from hydroilqr.io.environment import environment
    from hydroilqr.output import report
    from hydroilqr.studies.search import throughput

    if args.scheduler:
        raise ConfigError("--throughput measures local clusters; drop --scheduler")
    try:
        counts = [int(c) for c in args.throughput.split(",")]
    except ValueError:
        raise ConfigError(
            f"--throughput: expected worker counts such as 1,2, got {args.throughput!r}"
        ) from None
    if not counts or min(counts) < 1 or max(counts) > 256:
        raise ConfigError(f"--throughput: 1 to 256 workers each, got {args.throughput!r}")
    samples = task.config.search.samples
    out = Path(args.out or f"runs/{task.name}-throughput")
    report.output_dir(out, task.name)
    console.print(f"{task.name}: {samples} samples x 3 rounds per worker count {counts}")
    rows = throughput(task_ref(args, extra), counts, samples)
    base = rows[0]["samples_per_second"]
    for r in rows:
        console.print(
            f"  {r['workers']} worker(s): {r['samples_per_second']:.1f} samples/s "
            f"({r['samples_per_second'] / base:.2f}x), batch overhead "
            f"{1e3 * r['batch_overhead_seconds']:.1f} ms, "
            f"{1e3 * r['cpu_seconds_per_sample']:.1f} CPU ms per sample, each worker got "
            f"{100 * r['cpu_share']:.0f}% of a core"
        )
    doc = {"task": task.name, "rows": rows, "environment": environment(command_line(args))}
    report.write_json(out / "throughput.json", doc)
    console.print(f"wrote {out}/throughput.json")
    return 0
