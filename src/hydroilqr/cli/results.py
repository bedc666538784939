"""``hydroilqr results``: solve built-in tasks and write the generated results page."""

from __future__ import annotations

from hydroilqr.cli.common import add_task_list_args

HELP = "solve built-in tasks and write the results page (results.md, results.json)"


def setup(p) -> None:
    add_task_list_args(p)
    p.add_argument(
        "--out",
        default="runs/results",
        help="directory for results.md/.json (default runs/results; the repository's own "
        "page is --out docs)",
    )


def run(args) -> int:
    from hydroilqr.cli.common import console
    from hydroilqr.studies.results import DEFAULT_TASKS, estimate, generate

    tasks = args.tasks or DEFAULT_TASKS
    took = estimate(tasks, args.smoke)
    console.print(
        f"results: {len(tasks)} task(s) solved one after another into {args.out}"
        + (f"; {took}" if took else "")
    )
    paths = generate(
        tasks=tasks,
        out=args.out,
        smoke=args.smoke,
        overrides=args.set,
        command=args.command_line,
        progress=console.print,
    )
    console.print(f"wrote {paths['md']}, {paths['json']}")
    return 0
