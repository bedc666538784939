"""Result sets replace each other whole: killed at any step of a commit, a failed or full
disk run, symlinks in the run directory (output/rundir.py)."""

import errno
import json
import os
import subprocess
import sys

import pytest

from hydroilqr.io import rundir

OLD = {"summary.json": "old-summary", "solution.npz": "old-solution", "convergence.png": "old"}


NEW = {"summary.json": "new-summary", "solution.npz": "new-solution", "replay.html": "new"}


def _write_set(d, files):
    for name, text in files.items():
        (d / name).write_text(text)


def _old_run(out):
    out.mkdir()
    _write_set(out, OLD)
    (out / "playback-pd").mkdir()
    (out / "playback-pd" / "playback.json").write_text("old-playback")
    (out / "notes.txt").write_text("mine")  # not a result: never touched


def _state(out) -> str:
    """'old' or 'new' when out holds exactly one complete set, else what it holds."""
    rundir.recover(out)
    names = {p.name for p in out.iterdir() if not p.name.startswith(".")} - {"notes.txt"}
    texts = {n: (out / n).read_text() for n in names if (out / n).is_file()}
    if texts == OLD and names == set(OLD) | {"playback-pd"}:
        return "old"
    if texts == NEW and names == set(NEW):
        return "new"
    return f"mixed: {sorted(names)}"


RETIRE = ["summary.json", "solution.npz", "convergence.png", "replay.html", "playback-pd"]


STEPS = ["staged", "journal", *[f"retire:{i}" for i in range(5)]]


STEPS += [*[f"install:{i}" for i in range(3)], "installed"]


def test_commit_replaces_the_set_and_its_playbacks(tmp_path):
    out = tmp_path / "run"
    _old_run(out)
    with rundir.result_set(out, RETIRE) as st:
        _write_set(st, NEW)
        assert _state(out) == "old"  # nothing changes until the set is complete
    assert _state(out) == "new"
    assert (out / "notes.txt").read_text() == "mine"
    assert not (out / rundir.STAGE).exists() and not (out / rundir.PREVIOUS).exists()


@pytest.mark.parametrize("error", [RuntimeError("metric failed"), OSError(errno.ENOSPC, "full")])
def test_a_failure_while_writing_leaves_the_earlier_set(tmp_path, error):
    out = tmp_path / "run"
    _old_run(out)
    with pytest.raises(type(error)):
        with rundir.result_set(out, RETIRE) as st:
            (st / "solution.npz").write_text("new-solution")
            raise error
    assert _state(out) == "old"
    assert not (out / rundir.STAGE).exists()


@pytest.mark.parametrize("step", STEPS)
def test_killed_at_any_step_of_a_commit_leaves_one_complete_set(tmp_path, step):
    out = tmp_path / "run"
    _old_run(out)
    script = (
        "import sys\nfrom pathlib import Path\nfrom hydroilqr.io import rundir\n"
        f"out = Path({str(out)!r})\n"
        f"with rundir.result_set(out, {RETIRE!r}) as st:\n"
        f"    for n, t in {NEW!r}.items():\n"
        "        (st / n).write_text(t)\n"
    )
    env = {**os.environ, rundir.KILL_ENV: step}
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True)
    assert proc.returncode == -9, proc.stderr  # killed where asked
    before_journal = step in ("staged",)
    assert _state(out) == ("old" if before_journal else "new")
    assert (out / "notes.txt").read_text() == "mine"


def test_symlinks_in_a_run_directory_are_never_followed(tmp_path):
    out = tmp_path / "run"
    _old_run(out)
    target = tmp_path / "elsewhere"
    target.mkdir()
    (target / "keep.txt").write_text("precious")
    (out / "playback-pd").rename(tmp_path / "pb")
    (out / "playback-pd").symlink_to(target)  # a playback-* that is a link
    with rundir.result_set(out, RETIRE) as st:
        _write_set(st, NEW)
    assert (target / "keep.txt").read_text() == "precious"
    assert not (out / "playback-pd").exists()


def test_journal_is_json_naming_both_sides(tmp_path):
    out = tmp_path / "run"
    _old_run(out)
    st = rundir.stage(out)
    _write_set(st, NEW)
    os.environ[rundir.KILL_ENV] = ""
    try:
        rundir.commit(out, RETIRE)
    finally:
        del os.environ[rundir.KILL_ENV]
    assert not (out / rundir.JOURNAL).exists()
    assert json.dumps(sorted(NEW))  # the set installed
    assert _state(out) == "new"


@pytest.mark.parametrize(
    "journal",
    [
        {"retire": ["../beside"], "install": []},
        {"retire": [], "install": ["../beside"]},
        {"retire": ["/ABS/beside"], "install": []},
        {"retire": ["summary.json"], "install": ["."]},
        ["not", "a", "journal"],
        {"retire": [1], "install": []},
    ],
)
def test_a_journal_naming_paths_outside_the_run_moves_nothing(tmp_path, journal):
    """Issue 39: a .commit placed in a run directory (not written by a commit) never moves
    or deletes anything outside it; the next commit replaces it."""
    beside = tmp_path / "beside"
    beside.mkdir()
    (beside / "keep.txt").write_text("outside")
    out = tmp_path / "run"
    _old_run(out)
    text = json.dumps(journal).replace("/ABS", str(tmp_path))
    (out / rundir.JOURNAL).write_text(text)
    (out / rundir.STAGE).mkdir()
    (out / rundir.STAGE / "beside").mkdir()  # (an install of it would replace beside/)
    assert rundir.recover(out) is False
    assert (beside / "keep.txt").read_text() == "outside"
    assert _state(out) == "old"
    with rundir.result_set(out, [*OLD, "playback-pd"]) as st:
        _write_set(st, NEW)
    assert _state(out) == "new" and (beside / "keep.txt").read_text() == "outside"


def test_a_previous_or_stage_that_links_outside_is_never_used(tmp_path):
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "summary.json").write_text("outside")
    out = tmp_path / "run"
    _old_run(out)
    os.symlink(outside, out / rundir.PREVIOUS)
    (out / rundir.JOURNAL).write_text(json.dumps({"retire": ["summary.json"], "install": []}))
    assert rundir.recover(out) is False
    assert (outside / "summary.json").read_text() == "outside"
    assert (out / "summary.json").read_text() == OLD["summary.json"]


def test_plot_file_names_stay_in_the_output_directory():
    from hydroilqr.io.files import file_name

    assert file_name("ball") == "ball.png"
    assert file_name("../escape_ball") == "escape_ball.png"
    assert file_name("a/b") == "a_b.png" and file_name("..") == "object.png"
    assert file_name(".hidden") == "hidden.png" and file_name("x..y") == "x_y.png"


def test_a_journal_that_cannot_be_written_leaves_no_stage(tmp_path, monkeypatch):
    """Issue 39: a disk too full for the journal left .partial behind."""
    out = tmp_path / "run"
    _old_run(out)

    def full(path, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(rundir, "atomic_write", full)
    with pytest.raises(OSError), rundir.result_set(out, [*OLD, "playback-pd"]) as st:
        _write_set(st, NEW)
    assert not (out / rundir.STAGE).exists() and _state(out) == "old"
