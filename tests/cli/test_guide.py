"""Bring your own robot (issue 9): tasks built purely from YAML around models the project did
not write (Drake's acrobot and planar gripper + brick, shipped in the drake wheel), `check`,
and the guide's own commands and Python snippets, run in document order in a temp directory."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from hydroilqr import Task, cli, solve
from hydroilqr.metrics import validate_task
from hydroilqr.studies.check import check_task

ROOT = Path(__file__).resolve().parents[2]


EXAMPLES = ROOT / "examples"


GUIDE = ROOT / "docs" / "guide.md"


# ---------------------------------------------------------------------------------- the guide
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)


def guide_steps() -> list[tuple[str, str]]:
    """Runnable pieces of docs/guide.md in order: ("file", yaml), ("cmd", line), ("python", src).

    YAML blocks whose first line is ``# file: NAME`` are written to NAME; each line of a
    ``bash`` block that starts with ``hydroilqr`` is a command; ``python`` blocks are executed.
    """
    steps = []
    for lang, body in FENCE.findall(GUIDE.read_text()):
        if lang == "yaml" and body.startswith("# file: "):
            steps.append(("file", body))
        elif lang == "bash":
            steps += [
                ("cmd", ln.strip())
                for ln in body.splitlines()
                if ln.strip().startswith("hydroilqr ")
            ]
        elif lang == "python":
            steps.append(("python", body))
    return steps


def test_acrobot_from_yaml_check():
    task = Task.from_yaml(EXAMPLES / "acrobot-swingup.yaml")
    validate_task(task)
    facts = check_task(task)
    names = [b["name"] for b in facts["blocks"]]
    assert names[:2] == ["angles", "rates"]  # task groups first
    assert {"shoulder", "elbow", "shoulder.v", "elbow.v"} <= set(names)
    assert [a["name"] for a in facts["actuators"]] == ["elbow"]
    assert {g["kind"] for g in facts["geometries"]} == {"none"}
    assert facts["one_step_ok"] and facts["max_speed"] < 10
    assert facts["warnings"] == []


def test_gripper_brick_from_yaml_check_and_smoke_solve():
    task = Task.from_yaml(EXAMPLES / "gripper-brick.yaml", smoke=True)
    facts = check_task(task, rollout_steps=10)
    assert len(facts["actuators"]) == 6
    assert all(a["effort_limit"] == 75 for a in facts["actuators"])
    kinds = {(g["name"], g["body"]): g["kind"] for g in facts["geometries"]}
    assert kinds[("tip_sphere_collision", "finger1_tip_link")] == "compliant"
    assert kinds[("box_collision", "brick_link")] == "rigid"
    # All three fingertips touch the brick at x0, with hydroelastic polygons.
    tips = [
        c
        for c in facts["contacts"]
        if {c["a"], c["b"]} == {"tip_sphere_collision", "box_collision"}
    ]
    assert len(tips) == 3 and all(c["faces"] > 0 for c in tips)
    sol = solve(task)
    assert sol.final_cost < sol.costs[0]
    # the brick turns towards the 0.6 rad goal
    angle = task.dynamics.layout.block("brick_angle").coords[0]
    assert sol.X[-1, angle] > sol.X[0, angle]


def test_check_command_output(capsys):
    rc = cli.main(["check", str(EXAMPLES / "gripper-brick.yaml")])
    out = capsys.readouterr().out
    assert rc == 0
    for text in (
        "state blocks",
        "actuators",
        "collision geometries",
        "candidate collision pairs",
        "hydroelastic polygons",
        "simulation: one step ok",
        "check passed",
    ):
        assert text in out, text


def test_guide_has_runnable_steps():
    kinds = [k for k, _ in guide_steps()]
    assert kinds.count("file") >= 2 and kinds.count("cmd") >= 3 and kinds.count("python") >= 1
    assert kinds.index("file") < kinds.index("cmd")


def test_guide_commands_run(tmp_path, monkeypatch, capsys):
    """Runs the guide top to bottom; solves are made smoke-sized (``--smoke`` appended)."""
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "guide"}  # the guide's Python blocks continue one another
    for kind, text in guide_steps():
        if kind == "file":
            name = text.splitlines()[0].split(":", 1)[1].strip()
            (tmp_path / name).write_text(text)
        elif kind == "cmd":
            argv = text.split()[1:]
            if argv[0] == "solve" and "--smoke" not in argv:
                argv += ["--smoke", "--no-replay"]
            rc = cli.main(argv)
            cap = capsys.readouterr()
            assert rc == 0, f"{text}: {cap.err}"
            assert cap.err.strip() == "", f"{text}: {cap.err}"
        else:
            exec(compile(text, str(GUIDE), "exec"), namespace)
    # what the guide says a run directory holds
    for f in ("solution.npz", "summary.json", "convergence.png", "replay.html"):
        assert (tmp_path / "runs" / "acrobot-smoke" / f).exists(), f
    assert (tmp_path / "acrobot-solution.npz").exists()


@pytest.mark.parametrize("example", sorted(p.name for p in EXAMPLES.glob("*.yaml")))
def test_examples_validate(example):
    task = Task.from_yaml(EXAMPLES / example, smoke=True)
    validate_task(task)
    assert np.all(np.isfinite(task.x0))
