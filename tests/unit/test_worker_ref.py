"""What a Dask worker loads a task from names the same files from any working directory: a
worker of ``--scheduler`` may run elsewhere (``problem.load.worker_ref``)."""

from __future__ import annotations

import os
from pathlib import Path

from hydroilqr.problem.files import TASKS_DIR
from hydroilqr.problem.load import load_task, worker_ref


def test_a_builtin_keeps_its_name_and_files_become_absolute(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "t.yaml").write_text(f"extends: {TASKS_DIR / 'cartpole-wall.yaml'}\n")
    (tmp_path / "c.yaml").write_text("solver: {max_iterations: 3}\n")
    ref = worker_ref("t.yaml", ["initial_guess=u.npz", "solver.max_iterations=2"], "c.yaml",
                     True, label="x")  # fmt: skip
    assert ref == {
        "label": "x",
        "name": str(tmp_path / "t.yaml"),
        "overrides": [f"initial_guess={tmp_path / 'u.npz'}", "solver.max_iterations=2"],
        "config": str(tmp_path / "c.yaml"),
        "smoke": True,
    }
    assert worker_ref("cartpole-wall", [])["name"] == "cartpole-wall"
    assert worker_ref("cartpole-wall", ["initial_guess=zeros"])["overrides"] == [
        "initial_guess=zeros"
    ]


def test_a_worker_elsewhere_loads_the_same_task(tmp_path, monkeypatch):
    (tmp_path / "here").mkdir()
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "here" / "t.yaml").write_text(
        f"extends: {TASKS_DIR / 'cartpole-wall.yaml'}\nhorizon: 0.5\n"
    )
    monkeypatch.chdir(tmp_path / "here")
    ref = worker_ref("t.yaml", ["solver.max_iterations=2"])
    here = load_task(ref["name"], ref["overrides"], ref["config"], ref["smoke"])
    monkeypatch.chdir(tmp_path / "elsewhere")
    assert not Path("t.yaml").exists() and os.getcwd() == str(tmp_path / "elsewhere")
    there = load_task(ref["name"], ref["overrides"], ref["config"], ref["smoke"])
    assert there.to_dict() == here.to_dict()
