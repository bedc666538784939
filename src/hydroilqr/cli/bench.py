"""``hydroilqr bench``: iteration times of the paper's method against the fastest
configuration."""

from __future__ import annotations

import logging

from hydroilqr.cli.common import command_line, console
from hydroilqr.problem.errors import ConfigError

HELP = "iteration times: the paper's method vs the fastest configuration"


def setup(p) -> None:
    p.add_argument("task", nargs="+", help="built-in task names or task YAML files")
    p.add_argument(
        "--iterations", type=int, default=10, help="iLQR iterations per method (default 10)"
    )
    p.add_argument("--threads", type=int, default=0, help="threads for batched FD (0 = all)")
    p.add_argument(
        "--block", type=int, default=1, help="iterations per alternation block (default 1)"
    )
    p.add_argument("--smoke", action="store_true", help="shrink the tasks (tests)")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a task key for both methods (repeatable)",
    )
    p.add_argument(
        "--fast",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a task key of the fast configuration only (repeatable)",
    )
    p.add_argument(
        "--no-accuracy",
        action="store_true",
        help="skip the derivative-accuracy and thread-scaling sections",
    )
    p.add_argument(
        "--no-same-iterates",
        action="store_true",
        help="skip timing the paper's method at the fast run's iterates",
    )
    p.add_argument(
        "--out", help="output directory (default runs/bench, runs/bench-smoke with --smoke)"
    )


def run(args) -> int:
    from hydroilqr.studies.bench import run_bench

    if args.iterations < 1:
        raise ConfigError("--iterations: must be at least 1")
    if args.block < 1:
        raise ConfigError("--block: must be at least 1")
    out = args.out or ("runs/bench-smoke" if args.smoke else "runs/bench")
    # The paper's method runs on TAMSI on purpose: Drake's deprecation notice for it is in the
    # docs, not printed on every bench run (a solve with tamsi, or run_bench from Python, shows it).
    drake_log, quiet = logging.getLogger("drake"), _NoTamsiNotice()
    drake_log.addFilter(quiet)
    try:
        doc = run_bench(
            args.task,
            out,
            args.iterations,
            args.threads,
            args.smoke,
            args.set,
            args.fast,
            args.block,
            not args.no_accuracy,
            not args.no_same_iterates,
            command=command_line(args),
            on_message=console.print,
        )
    finally:
        drake_log.removeFilter(quiet)
    print_table(list(doc["tasks"].values()))
    console.print(f"wrote {out}/bench.json, iterations.png")
    return 0


class _NoTamsiNotice(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return "TAMSI solver is deprecated" not in record.getMessage()


def print_table(rows: list[dict]) -> None:
    """bench's report: the table of iteration times, then notes per task."""
    _print_times(rows)
    _print_skipped(rows)
    _print_limits(rows)
    _print_short_runs(rows)
    _print_same_iterates(rows)
    _print_accuracy(rows)


def _print_times(rows: list[dict]) -> None:
    head = (
        f"{'task':<18} {'N':>4} {'(a) paper s/it (p10-p90)':>26} "
        f"{'(b) fast s/it (p10-p90)':>26} {'a/b':>6} {'deriv a/b':>9} "
        f"{'cost a':>10} {'cost b':>10} {'diff':>7} {'faces a/b':>9} "
        + " ".join(
            f"{h:>{w}}"
            for h, w in (
                ("(a') s/it", 9),
                ("a'/b", 6),
                ("mean", 6),
                ("cost a'", 10),
                ("diff a'", 7),
            )
        )
    )
    console.print(
        "iLQR iteration time: (a) paper method vs (b) fast configuration; (a') the paper's "
        "method on (b)'s contact solver (a'/b of the medians; mean: of the whole runs' times, "
        "the same number of iterations each)"
    )
    console.print(head, style="bold", soft_wrap=True)
    for r in rows:
        a, b = r.get("paper", {}), r.get("fast", {})
        if "skipped" in a and "median_s" in b:
            console.print(_row_without_a(r), soft_wrap=True)
            continue
        if "median_s" not in a or "median_s" not in b:
            console.print(
                f"{r['task']:<18} {r['steps']:>4} {a.get('error', 'ok')} | {b.get('error', 'ok')}",
                soft_wrap=True,
            )
            continue
        ra = f"{a['median_s']:.4f} ({a['p10_s']:.4f}-{a['p90_s']:.4f})"
        rb = f"{b['median_s']:.4f} ({b['p10_s']:.4f}-{b['p90_s']:.4f})"
        da = f"{a['phase_share']['derivatives']:.0%}/{b['phase_share']['derivatives']:.0%}"
        fa = f"{a['polygons']['max_faces']}/{b['polygons']['max_faces']}"
        console.print(
            f"{r['task']:<18} {r['steps']:>4} {ra:>26} {rb:>26} {r['speedup_median']:>5.1f}x "
            f"{da:>9} {a['final_cost']:>10.5g} {b['final_cost']:>10.5g} "
            f"{r['cost_rel_diff']:>+7.2%} {fa:>9} {_same_solver_cells(r)}",
            soft_wrap=True,
        )


def _row_without_a(r: dict) -> str:
    """A table row where (a) did not run (a Drake without TAMSI): (b) and (a') only."""
    b = r["fast"]
    rb = f"{b['median_s']:.4f} ({b['p10_s']:.4f}-{b['p90_s']:.4f})"
    fb = f"-/{b['polygons']['max_faces']}"
    return (
        f"{r['task']:<18} {r['steps']:>4} {'-':>26} {rb:>26} {'-':>6} {'-':>9} {'-':>10} "
        f"{b['final_cost']:>10.5g} {'-':>7} {fb:>9} {_same_solver_cells(r)}"
    )


def _print_skipped(rows: list[dict]) -> None:
    """Why (a) did not run (once: the reason is this Drake's, the same for every task)."""
    notes = {r["paper"]["skipped"] for r in rows if "skipped" in r.get("paper", {})}
    for note in sorted(notes):
        console.print(f"(a) not run: {note}", soft_wrap=True)


def _same_solver_cells(r: dict) -> str:
    """The (a') columns of a table row ('-' where (a') did not run or failed)."""
    c = r.get("paper_same_solver", {})
    if "median_s" not in c or "speedup_same_solver_median" not in r:
        return f"{'-':>9} {'-':>6} {'-':>6} {'-':>10} {'-':>7}"
    return (
        f"{c['median_s']:>9.4f} {r['speedup_same_solver_median']:>5.1f}x "
        f"{r['speedup_same_solver_total']:>5.1f}x "
        f"{c['final_cost']:>10.5g} {r['cost_rel_diff_same_solver']:>+7.2%}"
    )


def _print_limits(rows: list[dict]) -> None:
    """Per task: where the fastest possible iteration on this machine lies (limit analysis)."""
    for r in rows:
        lim = r.get("limits")
        if lim and "fast_share_of_limit" in lim:
            lin = ", ".join(f"{k} {v:.3f}" for k, v in lim["linearization_all_steps_s"].items())
            console.print(
                f"{r['task']} limit: rollout {lim['rollout_s']:.4f} s; exact partials of all "
                f"{lim['steps']} steps in s: {lin}; backward pass {lim['backward_pass_s']:.4f} s; "
                f"fastest iteration on {lim['cores']} cores {lim['limit_s']:.4f} s "
                f"({lim['keypoints']} keypoints, {lim['cheapest_path']}); (b) reaches "
                f"{lim['fast_share_of_limit']:.0%} of it",
                soft_wrap=True,
            )


def _print_short_runs(rows: list[dict]) -> None:
    for r in rows:
        a, b = r.get("paper", {}), r.get("fast", {})
        short = [
            f"{m} stopped after {x['iterations']} iterations (stop test: {x['reason']})"
            for m, x in (("(a)", a), ("(b)", b), ("(a')", r.get("paper_same_solver", {})))
            if "iterations" in x and x["iterations"] < r.get("requested_iterations", 0)
        ]
        if short:
            console.print(
                f"{r['task']}: {', '.join(short)}: its cost is compared after fewer iterations",
                soft_wrap=True,
            )


def _print_same_iterates(rows: list[dict]) -> None:
    for r in rows:
        si = r.get("same_iterates")
        if si and "speedup_median" in si:
            ph = si["paper_phase_median_s"]
            console.print(
                f"{r['task']}: at (b)'s own iterates, (a) takes {si['paper_median_s']:.4f} s per "
                f"iteration (derivatives {ph['derivatives']:.4f} s, line search "
                f"{ph['line_search']:.4f} s; max faces {max(si['paper_max_faces'])}) against "
                f"(b)'s {si['fast_median_s']:.4f} s: {si['speedup_median']:.1f}x",
                soft_wrap=True,
            )
        elif si and si.get("errors"):
            console.print(
                f"{r['task']}: (a) at (b)'s iterates failed: {si['errors'][0]}", soft_wrap=True
            )


def _print_accuracy(rows: list[dict]) -> None:
    for r in rows:
        acc = r.get("accuracy")
        if acc:
            parts = [
                f"{k}: "
                + ", ".join(
                    f"{c} {v:.1e} (median {acc[k]['median'][c]:.0e})"
                    for c, v in acc[k]["max"].items()
                )
                for k in acc
                if k not in ("reference", "contact_classes", "seconds")
            ]
            console.print(
                f"{r['task']} derivative error vs AutoDiff ({acc['contact_classes']}"
                f"): " + "; ".join(parts),
                soft_wrap=True,
            )
        th = r.get("threads")
        if th:
            console.print(
                f"{r['task']} {th['method']} FD derivative phase: "
                + ", ".join(
                    f"{n} thread(s) {s:.3f} s ({th['speedup'][n]:.2f}x)"
                    for n, s in th["seconds"].items()
                ),
                soft_wrap=True,
            )
