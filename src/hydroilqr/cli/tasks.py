"""``hydroilqr tasks``: the built-in tasks."""

from __future__ import annotations

from hydroilqr.cli.common import console
from hydroilqr.problem.files import TASKS_DIR, list_tasks, load_raw

HELP = "list the built-in tasks"


def setup(p) -> None:
    pass


def run(args) -> int:
    for name in list_tasks():
        desc = load_raw(TASKS_DIR / f"{name}.yaml").get("description", "")
        console.print(f"[bold]{name:<22}[/bold] {desc}")
    return 0
