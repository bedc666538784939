"""``hydroilqr robustness``: how often tasks meet their goals under last-bit perturbations."""

from __future__ import annotations

import math

from hydroilqr.cli.common import (
    GOAL_NOT_MET,
    add_connect_timeout,
    add_task_list_args,
    command_line,
    console,
    scheduler_arg,
)
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.load import load_task, worker_ref
from hydroilqr.problem.search import check_searchable

HELP = "solve tasks K times from last-bit perturbed guesses on Dask; report goal pass rates"

#: The most runs per task one command may ask for (each run is a whole solve).
MAX_RUNS = 1000


def setup(p) -> None:
    add_task_list_args(p)
    p.add_argument("--runs", type=int, default=10, help="perturbed solves per task (default 10)")
    p.add_argument(
        "--noise",
        type=float,
        default=1e-9,
        help="relative perturbation of the initial guess (default 1e-9: last-bit sized)",
    )
    p.add_argument("--seed", type=int, default=0, help="the perturbations' seed (default 0)")
    p.add_argument(
        "--transfer",
        action="store_true",
        help="also play each plan back as the results page's transfer section does (PD+, half "
        "speed, finer simulation) and report the goal on the executed motion and the resting "
        "gap",
    )
    p.add_argument(
        "--mpc",
        action="store_true",
        help="run each task's closed loop instead of a solve (its mpc: settings, lock-step, "
        "the first plan's guess perturbed) and judge it by the loop's goal (mpc.goal, else "
        "goal)",
    )
    p.add_argument(
        "--search",
        action="store_true",
        help="run each task's search: section and its iLQR polish, as solve does, the search's "
        "seed set to SEED + k - 1 in run k (instead of iLQR alone from a perturbed guess)",
    )
    p.add_argument(
        "--min-rate",
        type=float,
        default=0.9,
        help="exit 4 when a task with a goal meets it in fewer than this fraction of its runs "
        "(default 0.9)",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="an existing Dask scheduler, e.g. tcp://host:8786 (default: a local cluster)",
    )
    add_connect_timeout(p)
    p.add_argument("--workers", type=int, help="worker processes of the local cluster")
    p.add_argument(
        "--out",
        default="runs/robustness",
        help="directory for robustness.json (default runs/robustness)",
    )


def _check(args) -> None:
    """Refuses arguments that cannot work, before any work."""
    if not 1 <= args.runs <= MAX_RUNS:
        raise ConfigError(f"--runs: must be between 1 and {MAX_RUNS}, got {args.runs}")
    if not (math.isfinite(args.noise) and 0 <= args.noise <= 1):
        raise ConfigError(f"--noise: must be a number in [0, 1], got {args.noise}")
    if args.seed < 0:
        raise ConfigError(f"--seed: must be >= 0, got {args.seed}")
    if not (math.isfinite(args.min_rate) and 0 <= args.min_rate <= 1):
        raise ConfigError(f"--min-rate: must be a number in [0, 1], got {args.min_rate}")
    if args.mpc and args.transfer:
        raise ConfigError("--transfer plays back a solve's plan; it does not go with --mpc")
    if args.mpc and args.search:
        raise ConfigError("--search runs a task's search and polish; it does not go with --mpc")
    if args.workers is not None and args.workers < 1:
        raise ConfigError("--workers: must be at least 1")
    if args.scheduler and args.workers is not None:
        raise ConfigError("--workers sizes the local cluster; it does not go with --scheduler")
    scheduler_arg(args)  # (--connect-timeout checked)


def _concurrency(report: dict) -> str:
    """How the runs shared the machine: workers, solves at once (measured), threads each."""
    threads = ", ".join(f"{k} {v}" for k, v in report["threads_per_solve"].items())
    return (
        f"{report['workers']} worker(s), one solve at a time each; at most "
        f"{report['most_solves_at_once']} solve(s) ran at once\n"
        f"cores one solve keeps busy (solver.threads; autodiff_workers): {threads}"
    )


def run(args) -> int:
    _check(args)
    # (late: the command's arguments are checked before Drake and Dask are loaded)
    from hydroilqr.control.mpc import prepare
    from hydroilqr.metrics import validate_task
    from hydroilqr.model.task import Task
    from hydroilqr.output.report import output_dir
    from hydroilqr.output.studies import write_robustness
    from hydroilqr.studies.results import DEFAULT_TASKS
    from hydroilqr.studies.robustness import loop_settings

    names = list(args.tasks or DEFAULT_TASKS)
    refs = []
    for name in names:  # every task loads and validates before any solve starts
        cfg = load_task(name, list(args.set), None, args.smoke)
        task = Task(cfg)
        validate_task(task)  # its metrics and goal, as solve checks them
        if args.mpc:  # its closed loop's settings, as mpc checks them
            prepare(task, loop_settings(task, args.smoke))
        if args.search and cfg.search is None:
            raise ConfigError(f"--search: {cfg.name} has no search: section")
        if args.search:
            check_searchable(cfg)
        refs.append(worker_ref(name, list(args.set), None, args.smoke, label=cfg.name))
    if len({r["label"] for r in refs}) != len(refs):
        raise ConfigError("a task is named twice")
    out = output_dir(args.out)  # created, locked and proven writable before any solve
    from hydroilqr.studies.robustness import run_robustness, spread_lines, table

    where = args.scheduler or "a local Dask cluster"
    if args.mpc:
        how = (
            f"closed loops (lock-step), first plan's guess perturbed by a relative "
            f"{args.noise:g} (seed {args.seed})"
        )
    elif args.search:
        how = f"solves, search seeds {args.seed}..{args.seed + args.runs - 1}, then iLQR polish"
    else:
        how = f"solves, guess perturbed by a relative {args.noise:g} (seed {args.seed})"
    console.print(f"robustness: {len(refs)} task(s) x {args.runs} {how}, on {where}")

    def done(r) -> None:
        rec = r.record()
        goal = {True: "goal PASS", False: "goal FAIL", None: "no goal"}[rec["goal_met"]]
        if args.smoke and rec["goal_met"] is not None:
            goal += " (smoke-sized run: not judged)"
        failed = f" ({', '.join(rec['failed_checks'])})" if rec["failed_checks"] else ""
        detail = f" [{r.error}]" if r.error else ""
        console.print(
            f"  {r.task} run {r.index}: {rec['status']}, {rec['iterations']} iterations, "
            f"{goal}{failed}, {r.seconds:.1f} s{detail}{_played(r.transfer)}"
        )

    report = run_robustness(
        refs,
        args.runs,
        args.noise,
        args.seed,
        scheduler_arg(args),
        args.workers,
        done,
        transfer=args.transfer,
        mpc=args.mpc,
        search=args.search,
    )
    report["command"] = command_line(args)
    report["smoke"] = bool(args.smoke)
    report["overrides"] = list(args.set)
    path = write_robustness(out, report)
    console.print(table(report))
    console.print(_concurrency(report))
    spread = spread_lines(report)
    if spread:
        console.print("each goal check over the runs (its units):\n" + "\n".join(spread))
    if args.smoke:
        console.print("smoke-sized runs: the pass rates above are not judged")
    console.print(f"wrote {path}")
    low = [
        t["task"]
        for t in report["tasks"]
        if t["goal_declared"] and t["pass_rate"] is not None and t["pass_rate"] < args.min_rate
    ]
    if low and not args.smoke:
        console.print(f"below the pass rate {args.min_rate:g}: {', '.join(low)}")
        return GOAL_NOT_MET
    return 0


def _played(transfer: dict | None) -> str:
    """A run's playback in its progress line ("" if not played back)."""
    if not transfer:
        return ""
    if "error" in transfer:
        return f"; playback failed [{transfer['error']}]"
    goal = {True: "PASS", False: "FAIL", None: "not judged"}[transfer.get("goal_met")]
    gap = transfer.get("resting_gap")
    rest = "" if gap is None else f", resting gap {100 * gap:.1f} cm"
    return f"; played back: goal {goal}{rest}"
