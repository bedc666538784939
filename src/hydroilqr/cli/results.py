"""``hydroilqr results``: solve built-in tasks and write the generated results page."""

from __future__ import annotations

HELP = "solve built-in tasks and write the results page (docs/results.md, results.json)"


def setup(p) -> None:
    p.add_argument(
        "tasks",
        nargs="*",
        metavar="TASK",
        help="built-in task names or task files (default: every built-in task)",
    )
    p.add_argument("--smoke", action="store_true", help="shrink the tasks (tests, quick tries)")
    p.add_argument("--out", default="docs", help="directory for results.md/.json (default docs)")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a key of every task (repeatable)",
    )


def run(args) -> int:
    from hydroilqr.cli.common import console
    from hydroilqr.studies.results import DEFAULT_TASKS, generate

    paths = generate(
        tasks=args.tasks or DEFAULT_TASKS,
        out=args.out,
        smoke=args.smoke,
        overrides=args.set,
        command=args.command_line,
        progress=console.print,
    )
    console.print(f"wrote {paths['md']}, {paths['json']}")
    return 0
