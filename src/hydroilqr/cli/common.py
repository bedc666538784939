"""What every command shares: the consoles, warnings, and the task arguments."""

from __future__ import annotations

import argparse
import math
import sys

from rich.console import Console

from hydroilqr.problem import inputs
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.guess import GUESS_KEYWORDS
from hydroilqr.problem.load import load_task

# Piped or logged output gets a wide console, so names that users copy into task files
# (block, joint and geometry names in tables) are not cut to fit 80 columns.
# Piped: tables at 160 columns, prose unbroken (a log or a grep sees each sentence whole).
console = Console(
    stderr=False,
    highlight=False,
    width=None if sys.stdout.isatty() else 160,
    soft_wrap=not sys.stdout.isatty(),
)
# Warnings go to stderr, so they stay visible when a run's report on stdout is piped or kept.
err_console = Console(
    stderr=True,
    highlight=False,
    width=None if sys.stderr.isatty() else 160,
    soft_wrap=not sys.stderr.isatty(),
)


def warn(message: str) -> None:
    """Prints ``warning: message`` on stderr (rich markup allowed)."""
    err_console.print(f"[yellow]warning:[/yellow] {message}")


def add_task_args(p: argparse.ArgumentParser, positional: bool = True) -> None:
    if positional:
        p.add_argument("task", nargs="?", help="built-in task name or a task YAML file")
    p.add_argument("--task-file", help="a task YAML file (same as giving its path as TASK)")
    p.add_argument("--config", help="YAML file merged over the task")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a task key, e.g. solver.max_iterations=20 (repeatable)",
    )
    p.add_argument("--smoke", action="store_true", help="shrink the task (tests, quick tries)")


def add_task_list_args(p: argparse.ArgumentParser) -> None:
    """TASK... (default: every built-in task), --smoke and --set for every task: the commands
    that run several tasks (results, robustness)."""
    p.add_argument(
        "tasks",
        nargs="*",
        metavar="TASK",
        help="built-in task names or task files (default: every built-in task)",
    )
    p.add_argument("--smoke", action="store_true", help="shrink the tasks (tests, quick tries)")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a key of every task (repeatable)",
    )


def task_name_from_args(args) -> str | None:
    """TASK or --task-file (not both: which one was meant would be a guess)."""
    task, task_file = getattr(args, "task", None), getattr(args, "task_file", None)
    if task and task_file:
        raise ConfigError(f"give a task name or --task-file, not both ({task!r}, {task_file!r})")
    return task_file or task


def load_task_from_args(args, extra_overrides: list[str] | None = None):
    """The task the arguments name, validated. Its files are read and checked before Drake
    is loaded, so bad input is refused at once."""

    name = task_name_from_args(args)
    if not name:
        raise ConfigError("no task given (try `hydroilqr tasks`)")
    overrides = list(args.set or []) + list(extra_overrides or [])
    cfg = load_task(name, overrides, args.config, args.smoke)
    guess = cfg.initial_guess
    if isinstance(guess, str) and guess not in GUESS_KEYWORDS and cfg.resolve_path(guess).exists():
        # (the cap that fits the task's size is applied when the guess is read)
        guess = cfg.resolve_path(cfg.initial_guess)
        inputs.check_file(guess, "initial_guess:", inputs.MAX_ARRAY_FILE_BYTES)
    from hydroilqr.metrics import validate_task
    from hydroilqr.model.task import Task

    task = Task(cfg)
    validate_task(task)
    return task


def command_line(args) -> str | None:
    """The command line that is running (recorded as ``environment.command`` in results)."""
    return getattr(args, "command_line", None)


#: Exit code of a command whose results were written but whose task goal was not met.
GOAL_NOT_MET = 4


def print_goal(goal: dict | None, smoke: bool, what: str = "") -> int:
    """The PASS/FAIL line of a task's goal (``hydroilqr.metrics.goals``) and the exit code it
    gives: GOAL_NOT_MET when a declared goal is not met. A smoke-sized run is reported but not
    judged (its goal is the full task's)."""
    from hydroilqr.metrics.goals import verdict_line

    if not goal or goal.get("met") is None:
        return 0
    line = verdict_line(goal) + (f" ({what})" if what else "")
    if smoke:
        console.print(f"{line} (smoke-sized run: not judged)", soft_wrap=True)
        return 0
    colour = "green" if goal["met"] else "red"
    console.print(f"[{colour}]{line}[/{colour}]", soft_wrap=True)
    return 0 if goal["met"] else GOAL_NOT_MET


# studies/cluster.py's CONNECT_SECONDS (not imported here: the parsers are built without Dask)
CONNECT_DEFAULT = 15.0
MAX_CONNECT_SECONDS = 3600.0


def add_connect_timeout(p: argparse.ArgumentParser) -> None:
    """``--connect-timeout``, beside a command's ``--scheduler``."""
    p.add_argument(
        "--connect-timeout",
        type=float,
        metavar="SECONDS",
        help="with --scheduler: how long it has to answer before the command stops with one "
        f"line naming it (default {CONNECT_DEFAULT:g})",
    )


def connect_seconds(args) -> float | None:
    """``--connect-timeout`` checked (None when not given: the cluster's default)."""
    seconds = args.connect_timeout
    if seconds is None:
        return None
    if not args.scheduler:
        raise ConfigError("--connect-timeout goes with --scheduler")
    if not (math.isfinite(seconds) and 0 < seconds <= MAX_CONNECT_SECONDS):
        raise ConfigError(
            f"--connect-timeout: must be a number of seconds above 0 and at most "
            f"{MAX_CONNECT_SECONDS:g}, got {seconds:g}"
        )
    return seconds


def scheduler_arg(args):
    """``--scheduler`` with its ``--connect-timeout`` (checked), as the studies take it: the
    address, a ``Scheduler`` with the deadline, or None (a local cluster)."""
    seconds = connect_seconds(args)
    if seconds is None:
        return args.scheduler
    from hydroilqr.studies.cluster import Scheduler  # (Dask is loaded by the command)

    return Scheduler(args.scheduler, seconds)
