"""``hydroilqr results``: solve built-in tasks and write the generated results page."""

from __future__ import annotations

from hydroilqr.cli.common import add_task_list_args

HELP = "solve built-in tasks and write the results page (docs/results.md, results.json)"


def setup(p) -> None:
    add_task_list_args(p)
    p.add_argument("--out", default="docs", help="directory for results.md/.json (default docs)")


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
