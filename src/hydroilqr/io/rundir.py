"""Result sets that replace each other whole: staged, then committed through a journal.

A command writes its results into ``out/.partial/`` (the stage). Only when every file is
there does ``commit`` replace the earlier set, in three steps recorded by a journal
``out/.commit`` (written atomically before the first step):

1. retire: the earlier set's entries (``retire``: files, plots, ``playback-*`` directories
   derived from the earlier plan) are renamed into ``out/.previous/``;
2. install: the staged entries are renamed into ``out/``;
3. the journal is removed, then ``.previous`` and the stage are deleted.

While a commit runs, a visible file ``REPLACING-RESULTS.txt`` (``MARKER``) says so: a user who
lists a directory whose commit a kill cut short sees it, and what finishes the commit, instead
of only the hidden entries.

Renames within one directory are atomic and need no free space. A process killed at any
instant leaves either no journal (the earlier set is complete in ``out/``; the stage is
discarded on the next run) or a journal with a complete stage and ``.previous``, which
``recover`` (run by every command before it reads or writes ``out``) rolls forward. So a
reader that recovers first sees the earlier complete set or the new complete one, never a
mix and never nothing. Deletion never follows symbolic links (``_remove``), and entries that
are not results (a user's notes, a symlink) are left where they are.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from hydroilqr.io.files import atomic_write
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.inputs import MAX_ARRAY_FILE_BYTES, MAX_JSON_BYTES, check_npz, read_bounded

STAGE = ".partial"
PREVIOUS = ".previous"
JOURNAL = ".commit"
MARKER = "REPLACING-RESULTS.txt"
MARKER_TEXT = """\
hydroilqr was replacing the results in this directory when it stopped (killed, or the machine
went down). Both sets are complete: the new one in .partial/, the earlier one in .previous/
(hidden), and .commit says what goes where. The next hydroilqr command that reads this
directory (`hydroilqr playback DIR`, a plan named by mpc.warm_start_plan) or writes into it
(`--out DIR`) finishes the replacement first, installing the new set, and removes this file.
Nothing needs to be moved by hand.
"""
KILL_ENV = "HYDROILQR_KILL_AT"  # fault injection for tests: a step name below


def _fault(step: str) -> None:
    """Test hook: SIGKILL this process at ``step`` when HYDROILQR_KILL_AT names it."""
    if os.environ.get(KILL_ENV) == step:
        os.kill(os.getpid(), signal.SIGKILL)


def _remove(path: Path) -> None:
    """Deletes a file, a symlink (the link, never its target) or a directory tree (without
    following the symlinks inside it)."""
    if path.is_symlink() or path.is_file():
        path.unlink(missing_ok=True)
    elif path.is_dir():
        shutil.rmtree(path, ignore_errors=True)


def _exists(path: Path) -> bool:
    return path.exists() or path.is_symlink()


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def stage(out: Path) -> Path:
    """A fresh, empty stage in ``out`` (after recovering an interrupted commit)."""
    out = Path(out)
    recover(out)
    st = out / STAGE
    _remove(st)
    st.mkdir(parents=True)
    return st


def commit(out: Path, retire: list[str]) -> list[str]:
    """Replaces the entries ``retire`` of ``out`` (those that exist) with the staged set;
    returns the installed names. The stage must be complete."""
    out = Path(out)
    st = out / STAGE
    new = sorted(p.name for p in st.iterdir())
    old = sorted({n for n in [*retire, *new] if n not in (STAGE, PREVIOUS, JOURNAL, MARKER)})
    _fsync_dir(st)
    _fault("staged")
    atomic_write(out / MARKER, MARKER_TEXT)
    atomic_write(out / JOURNAL, json.dumps({"retire": old, "install": new}))
    _fault("journal")
    _roll_forward(out)
    return new


MAX_JOURNAL_BYTES = 1 << 20


def _plain_name(name: object) -> bool:
    """A name of an entry directly in the run directory (no path, not a commit's own)."""
    return (
        isinstance(name, str)
        and name not in ("", ".", "..", STAGE, PREVIOUS, JOURNAL, MARKER)
        and "/" not in name
        and "\\" not in name
        and "\0" not in name
    )


def _read_journal(out: Path) -> dict:
    """The journal's plan, ValueError unless it is one this module wrote: a regular file (not
    a link), JSON {retire: [names], install: [names]} of entries directly in ``out``, with a
    stage and a previous set that are directories of ``out`` itself (not links), so a journal
    or directory placed there by anything else moves or deletes nothing outside ``out``."""
    path = out / JOURNAL
    if path.is_symlink():
        raise ValueError(f"{path}: a symbolic link, not a journal")
    plan = json.loads(read_bounded(path, "commit journal", MAX_JOURNAL_BYTES))
    if not isinstance(plan, dict) or set(plan) != {"retire", "install"}:
        raise ValueError(f"{path}: not a commit journal")
    for key in ("retire", "install"):
        names = plan[key]
        if not isinstance(names, list) or not all(_plain_name(n) for n in names):
            raise ValueError(f"{path}: {key} names an entry outside {out}")
    for d in (out / STAGE, out / PREVIOUS):
        if d.is_symlink() or (_exists(d) and not d.is_dir()):
            raise ValueError(f"{d}: not a directory of {out}")
    return plan


def _roll_forward(out: Path) -> None:
    """Completes the commit its journal describes (idempotent: safe to repeat after a kill)."""
    plan = _read_journal(out)
    prev, st = out / PREVIOUS, out / STAGE
    prev.mkdir(exist_ok=True)
    for i, name in enumerate(plan["retire"]):
        # (on a repeat, a name already installed is the new entry: it stays)
        installed = name in plan["install"] and not _exists(st / name)
        if _exists(out / name) and not installed:
            _remove(prev / name)
            os.rename(out / name, prev / name)
        _fault(f"retire:{i}")
    for i, name in enumerate(plan["install"]):
        if _exists(st / name):
            os.rename(st / name, out / name)
        _fault(f"install:{i}")
    _fsync_dir(out)
    (out / JOURNAL).unlink()
    _fault("installed")
    _remove(out / MARKER)
    _remove(prev)
    _remove(st)


def recover(out: Path) -> bool:
    """Finishes an interrupted commit in ``out`` (True if there was one) and removes what a
    finished one left behind. A stage without a journal is kept for its owner (a
    receding-horizon run's checkpoint lives there) until the next ``stage``."""
    out = Path(out)
    if _exists(out / JOURNAL):
        try:
            _roll_forward(out)
        except (OSError, ValueError, KeyError):
            # not a journal of ours (or unreadable): nothing moves; the next commit
            # replaces it
            return False
        return True
    for leftover in (PREVIOUS, MARKER):  # (a commit done, or killed before its journal)
        if _exists(out / leftover):
            _remove(out / leftover)
    return False


def discard(out: Path) -> None:
    """Removes the stage (a failed run's partial results); the earlier set is untouched."""
    _remove(Path(out) / STAGE)


@contextmanager
def result_set(out: Path, retire: list[str], keep_stage_on_error: bool = False):
    """``with result_set(out, retire) as st:`` write the new set into ``st``; on normal exit
    it replaces ``retire`` in ``out``, on an exception the earlier set stays as it was (the
    stage is discarded unless ``keep_stage_on_error``)."""
    st = stage(out)
    try:
        yield st
    except BaseException:
        if not keep_stage_on_error:
            discard(out)
        raise
    try:
        commit(out, retire)
    except BaseException:
        # no journal (it could not be written, e.g. a full disk): nothing was replaced, so
        # the new set goes; with one, recover() completes the commit, which needs the stage
        if not _exists(Path(out) / JOURNAL) and not keep_stage_on_error:
            discard(out)
        raise


def solution_file(path: str | Path) -> Path:
    """A run directory's solution.npz; ``path`` itself if it is a file; else ``path`` with
    ``.npz`` appended if that exists (what ``Solution.save(path)`` writes)."""
    path = Path(path)
    if path.is_dir():
        # a commit a killed run left half done: completed first (as every command does), so
        # the reader gets the new complete set, not a missing file
        if _exists(path / JOURNAL) or _exists(path / MARKER):
            recover(path)
        return path / "solution.npz"
    if not path.exists() and path.suffix != ".npz" and path.with_name(path.name + ".npz").exists():
        return path.with_name(path.name + ".npz")
    return path


def read_run_arrays(path: str | Path, names: tuple[str, ...], key: str) -> tuple[dict, Path]:
    """Arrays ``names`` of a solved run's solution.npz (``path``: the run directory or the
    file), and the file's path; ConfigError naming ``key`` (the option that pointed there) if
    they cannot be read."""
    path = solution_file(path)
    try:
        check_npz(path, key, MAX_ARRAY_FILE_BYTES)
        with np.load(path, allow_pickle=False) as d:
            return {n: np.asarray(d[n]) for n in names}, path
    except ConfigError:
        raise
    except Exception as e:  # noqa: BLE001 - missing, torn or foreign file
        raise ConfigError(f"{key}: cannot read {path} ({type(e).__name__})") from None


# Files that mark a directory as holding some task's results (each has a "task" field).
RESULT_MARKERS = ("summary.json", "mpc.json", "playback.json", "sweep_spec.json", "bench.json")


def previous_task(out: Path) -> str | None:
    """Name of the task whose results ``out`` holds (None: no results there)."""
    for marker in RESULT_MARKERS:
        path = Path(out) / marker
        if not path.exists():
            continue
        try:
            task = json.loads(read_bounded(path, "results file", MAX_JSON_BYTES)).get("task")
        except (OSError, ValueError, AttributeError):
            continue
        if task:
            return str(task)
    return None
