"""Issue 54, item 5: mpc.png shows the object, the tracked blocks (terminal-only ones too)
and the commands, not only solve times; the terminal says how the first plan was made."""

from __future__ import annotations

import json

import yaml

from hydroilqr import Task, cli
from tests.integration.test_model_names import NUDGE


def test_mpc_plots_the_object_and_the_commands_and_says_how_the_first_plan_was_made(
    tmp_path, capsys
):
    from hydroilqr.output.plots import plotted_blocks

    spec = {**NUDGE, "mpc": {"duration": 0.1, "horizon": 0.1, "rate": 50}}
    path = tmp_path / "nudge.yaml"
    path.write_text(yaml.safe_dump(spec))
    task = Task.from_yaml(path, smoke=True)
    names = [n for n, _ in plotted_blocks(task)]
    # the object (metric_params) first, then the running cost's joints; the cube's Qf-only
    # block is the object's coordinates, shown once
    assert names[0] == "cube::base_link.position" and sorted(names[1:]) == ["elbow", "shoulder"]
    out = tmp_path / "mpc"
    rc = cli.main(["mpc", str(path), "--smoke", "--no-replay", "--out", str(out)])
    assert rc in (0, 4)
    printed = " ".join(capsys.readouterr().out.split())
    fp = json.loads((out / "mpc.json").read_text())["first_plan"]
    assert fp["from"] == "initial_guess zeros" and fp["iterations"] <= fp["max_iterations"]
    assert (
        f"first plan (before the clock starts): from the initial_guess zeros, status {fp['status']}"
        in printed
    )
    assert (out / "mpc.png").stat().st_size > 10_000
