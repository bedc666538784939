"""The command-line entry point: `python -m hydroilqr`, one-line errors, the debug variable."""

from __future__ import annotations

import pytest


def test_python_dash_m_runs_the_command_line():
    import subprocess
    import sys

    r = subprocess.run(
        [sys.executable, "-m", "hydroilqr", "tasks"], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0 and "cartpole-wall" in r.stdout


def test_a_failed_command_leaves_no_empty_output_directory(tmp_path, monkeypatch):
    from hydroilqr.cli import main
    from hydroilqr.model.plant import SimulationError
    from hydroilqr.solver import api

    def fail(*a, **k):
        raise SimulationError("contact solver did not converge")

    monkeypatch.setattr(api, "solve", fail)
    new = tmp_path / "new" / "run"
    assert main(["solve", "cartpole-wall", "--smoke", "--no-replay", "--out", str(new)]) == 3
    assert not (tmp_path / "new").exists()  # nor the parent made for it
    kept = tmp_path / "kept"
    kept.mkdir()
    (kept / "notes.txt").write_text("mine")
    assert main(["solve", "cartpole-wall", "--smoke", "--no-replay", "--out", str(kept)]) == 3
    assert (kept / "notes.txt").exists()  # a directory the user made stays


def test_debug_variable_shows_tracebacks_for_config_errors(monkeypatch):
    from hydroilqr.cli import main
    from hydroilqr.problem.errors import ConfigError

    monkeypatch.setenv("HYDROILQR_DEBUG", "1")
    with pytest.raises(ConfigError):
        main(["check", "cartpole-wall", "--set", "solver.max_iterations=-1"])


def test_an_ascii_text_encoding_is_named_in_the_import_error():
    """pydrake 1.51 cannot import under LC_ALL=C with PYTHONUTF8=0; the package says what to
    set instead of Drake's bare "initialization failed"."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "LC_ALL": "C", "PYTHONUTF8": "0"}
    p = subprocess.run(
        [sys.executable, "-c", "import hydroilqr"], env=env, capture_output=True, text=True
    )
    assert p.returncode != 0
    assert "PYTHONUTF8=1" in p.stderr.strip().splitlines()[-1]


def test_a_solve_writes_its_replay_without_meshcats_listening_line(tmp_path):
    """The replay file is written through a Meshcat server; its INFO line ("Meshcat listening
    for connections at ...") is not the user's business without --view."""
    import subprocess
    import sys

    from tests.conftest import write_task

    task = write_task(tmp_path, num_steps=10, solver={"max_iterations": 1})
    out = tmp_path / "run"
    r = subprocess.run(
        [sys.executable, "-m", "hydroilqr", "solve", str(task), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    assert (out / "replay.html").is_file()
    assert "Meshcat" not in r.stdout + r.stderr


def test_meshcats_info_line_alone_is_held_back(monkeypatch, caplog):
    """Around the server's start only: Drake's level is as it was afterwards, and a level the
    user raised (ERROR) is not lowered to WARNING meanwhile."""
    import logging

    from hydroilqr.output import replay

    drake = logging.getLogger("drake")
    before = drake.level
    try:
        for level in (logging.INFO, logging.ERROR):
            drake.setLevel(level)
            seen = []
            monkeypatch.setattr(replay, "_MESHCAT", None)  # a new server
            monkeypatch.setattr(
                drake, "setLevel", lambda v, f=drake.setLevel, s=seen: [s.append(v), f(v)]
            )
            assert replay.meshcat_instance().web_url().startswith("http")
            monkeypatch.undo()
            assert seen == [max(level, logging.WARNING), level] and drake.level == level
        assert not [r for r in caplog.records if "Meshcat listening" in r.getMessage()]
    finally:
        drake.setLevel(before)
