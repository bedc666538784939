"""``hydroilqr schema``: the JSON Schema of task files, for editors."""

from __future__ import annotations

import json

from hydroilqr.problem.schema import task_schema

HELP = "print the JSON Schema of task files (for editors: see docs/task-format.md)"


def setup(p) -> None:
    p.description = (
        "Prints the JSON Schema of task files, generated from the typed configuration. Save it "
        "(hydroilqr schema > task.schema.json) and start a task file with the line "
        "`# yaml-language-server: $schema=task.schema.json` for completion and checks in an "
        "editor with a YAML language server."
    )


def run(args) -> int:
    print(json.dumps(task_schema(), indent=2))
    return 0
