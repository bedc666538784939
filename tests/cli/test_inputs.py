"""Initial-guess files given to the command line: paths, lengths, empty files."""

from __future__ import annotations

import numpy as np
import pytest

from hydroilqr import cli
from tests.conftest import BASE, assert_one_line, edit, write_case


def test_short_initial_guess_file_is_an_error(tmp_path, capsys):
    (tmp_path / "U.csv").write_text("0.1\n0.2\n")  # 2 rows, the task has 5 steps
    path = write_case(tmp_path, edit(initial_guess="U.csv"))
    rc = cli.main(["solve", "--task-file", str(path), "--no-replay", "--out", str(tmp_path / "o")])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "has 2 rows; the task needs 5")
    (tmp_path / "U.csv").write_text("0.1\n")  # one row: a constant control
    from hydroilqr.model.task import Task

    np.testing.assert_allclose(Task.load(str(path)).initial_guess(5), np.full((5, 1), 0.1))


def test_command_line_guess_path_is_relative_to_the_working_directory(tmp_path, monkeypatch):
    from hydroilqr.model.task import Task

    task_dir, work = tmp_path / "tasks", tmp_path / "work"
    task_dir.mkdir()
    work.mkdir()
    path = write_case(task_dir, BASE)
    (work / "U.csv").write_text("0.3\n")
    monkeypatch.chdir(work)
    task = Task.load(str(path), overrides=["initial_guess=U.csv"])
    np.testing.assert_allclose(task.initial_guess(5), np.full((5, 1), 0.3))


def test_empty_guess_file_is_one_line(tmp_path, capsys):
    (tmp_path / "empty.csv").write_text("")
    path = write_case(tmp_path, edit(initial_guess="empty.csv"))
    rc = cli.main(["solve", str(path), "--out", str(tmp_path / "o"), "--no-replay"])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, "empty.csv is empty")


def test_command_line_paths_inside_override_sections_are_relative_to_the_working_directory(
    tmp_path, monkeypatch
):
    from hydroilqr.model.task import Task

    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    overrides = ["mismatch={a: {models.0.file: m.urdf}}", "mismatch.b={models.0.file: n.urdf}"]
    cfg = Task.load("kinova-left", overrides=overrides).config
    assert cfg.mismatch["a"]["models.0.file"] == str(work / "m.urdf")
    assert cfg.mismatch["b"]["models.0.file"] == str(work / "n.urdf")
    kin = Task.load("kinova-left", overrides=["ensemble=[{models.1.file: b.sdf}]"]).config
    assert kin.ensemble == [{"models.1.file": str(work / "b.sdf")}]
    # a task file's own relative paths stay relative to it
    base = Task.load("kinova-left").config
    assert base.mismatch["mass-20"]["models.1.file"] == "../models/kinova_gen3/ball_light.sdf"


@pytest.mark.parametrize("name", ["secret.txt", "secret.csv", "secret.npz"])
def test_an_unreadable_guess_file_is_named_never_quoted(tmp_path, capsys, name):
    """Issue 39: the error line says where the file is wrong, not what it holds."""
    from tests.conftest import write_task

    secret = tmp_path / name
    secret.write_text("1,2\npassword hunter2,3\n")
    task = write_task(tmp_path, initial_guess=str(secret))
    rc = cli.main(["solve", str(task), "--out", str(tmp_path / "o")])
    cap = capsys.readouterr()
    assert_one_line(rc, cap.out, cap.err, f"initial_guess: could not read {secret}")
    assert "hunter2" not in cap.err and "password" not in cap.err
