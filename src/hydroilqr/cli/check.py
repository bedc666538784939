"""``hydroilqr check``: validate a task and report its layout and contacts."""

from __future__ import annotations

from hydroilqr.cli.common import add_task_args, console, load_task_from_args, task_name_from_args

HELP = "validate a task and report its layout and contacts"


def setup(p) -> None:
    add_task_args(p)


def run(args) -> int:
    from hydroilqr.problem.check import check_task

    task = load_task_from_args(args)
    if not args.smoke:  # the task's `smoke:` section must work too (tests rely on it)
        from hydroilqr.problem.task import Task

        Task.load(task_name_from_args(args), list(args.set or []), args.config, True).validate()
    check_task(task, console)
    return 0
