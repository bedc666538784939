"""The JSON Schema of task files (``hydroilqr schema``): generated from the typed
configuration, every built-in task file validates against it, a typo does not."""

from __future__ import annotations

import json

import jsonschema
import pytest

from hydroilqr.problem.files import TASKS_DIR, yaml_value
from hydroilqr.problem.load import load_task
from hydroilqr.problem.schema import task_schema


@pytest.fixture(scope="module")
def validator():
    schema = task_schema()
    jsonschema.Draft7Validator.check_schema(schema)
    return jsonschema.Draft7Validator(schema)


@pytest.mark.parametrize("path", sorted(TASKS_DIR.glob("*.yaml")), ids=lambda p: p.name)
def test_every_built_in_task_file_validates_as_written(validator, path):
    data = yaml_value(path.read_text())
    errors = [f"{list(e.absolute_path)}: {e.message}" for e in validator.iter_errors(data)]
    assert not errors, errors


@pytest.mark.parametrize("name", ["cartpole-wall", "kinova-forward", "cheetah-trot-1.0"])
def test_a_resolved_task_validates(validator, name):
    """The resolved task (summary.json's config: every key, extends merged) validates too."""
    cfg = load_task(name).to_dict()
    errors = [f"{list(e.absolute_path)}: {e.message}" for e in validator.iter_errors(cfg)]
    assert not errors, errors


@pytest.mark.parametrize(
    "text, where",
    [
        ("solver: {max_iteration: 5}", ["solver"]),  # a typo'd key
        ("horizn: 1.0", []),
        ("scene: [{name: g, shape: boxx}]", ["scene", 0, "shape"]),
        ("plant: {time_step: fast}", ["plant", "time_step"]),
        ("geometry: {tip: {frictoin: 0.5}}", ["geometry", "tip"]),
        ("mpc: {pushes: []}", ["mpc"]),  # not a task-file key
        ("base_dir: /tmp", []),  # set by the loader only
    ],
)
def test_a_typo_or_a_wrong_value_fails_validation(validator, text, where):
    errors = list(validator.iter_errors(yaml_value(text)))
    assert errors and list(errors[0].absolute_path) == where


def test_every_dataclass_field_is_in_the_schema():
    """The schema follows the dataclasses: a key added to a section appears in it."""
    from hydroilqr.problem.schema import task_file_fields
    from hydroilqr.problem.solver import SolverConfig
    from hydroilqr.problem.task import TaskConfig

    schema = task_schema()
    top = set(schema["properties"])
    assert {f.name for f in task_file_fields(TaskConfig)} | {"extends"} == top
    solver = schema["definitions"]["SolverConfig"]["properties"]
    assert set(solver) == {f.name for f in task_file_fields(SolverConfig)}
    assert solver["derivative_secant_updates"] == {"type": "integer", "default": 0}
    assert solver["derivatives"]["enum"] == ["autodiff", "forward", "central"]


def test_the_schema_command_prints_it(capsys):
    from hydroilqr.cli import main

    assert main(["schema"]) == 0
    assert json.loads(capsys.readouterr().out) == task_schema()


def test_task_format_names_every_key_and_the_schema_line():
    """docs/task-format.md says it lists every key: each key of the schema appears there as a
    word (issue 39, 9), with the line an editor needs to use the schema."""
    import re
    from pathlib import Path

    doc = (Path(__file__).parents[2] / "docs" / "task-format.md").read_text()
    schema = task_schema()
    definitions = schema["definitions"].values()
    sections = [schema["properties"], *(d["properties"] for d in definitions if "properties" in d)]
    keys = {k for props in sections for k in props}
    missing = sorted(k for k in keys if not re.search(rf"(?<![\w.-]){re.escape(k)}(?![\w-])", doc))
    assert not missing, missing
    assert "# yaml-language-server: $schema=task.schema.json" in doc
