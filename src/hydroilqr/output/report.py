"""Everything a solve writes into its output directory.

solution.npz    X, U, K, kappa, t (+ statistics)          -> Solution.load
summary.json    task, converged, reason, status, iterations, final_cost, iteration_seconds,
                phase_seconds, derivatives, metrics, config (the fully resolved task),
                environment (code commit, package versions, CPU)
convergence.png cost against iteration (log scale)
replay.html     self-contained Meshcat replay with contact surfaces/forces
plus the plots of the task's metrics (``hydroilqr.metrics``: contacts.png, ball.png,
velocity.png, gait.png, ...)
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import signal
import stat
import tempfile
import threading
from pathlib import Path

import numpy as np

from hydroilqr import metrics as metrics_mod
from hydroilqr.io.files import atomic_write
from hydroilqr.io.rundir import RESULT_MARKERS, previous_task
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.inputs import read_bounded


def json_safe(obj):
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if np.isfinite(v) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def write_json(path: Path, data: dict) -> None:
    atomic_write(path, json.dumps(json_safe(data), indent=2))


class deferred_interrupt:
    """``with deferred_interrupt(): ...`` writes results without a Ctrl+C in the middle: a
    SIGINT that arrives inside is held until the block ends, then raised as KeyboardInterrupt
    (so a directory never holds half of the old results and half of the new)."""

    def __enter__(self):
        self.got = False
        self.old = None
        if threading.current_thread() is threading.main_thread():
            current = signal.getsignal(signal.SIGINT)
            # an ignored SIGINT (nohup, a background job) or a handler from outside Python
            # (None) is left as it is
            if current not in (signal.SIG_IGN, None):
                self.old = signal.signal(signal.SIGINT, self._hold)
        return self

    def _hold(self, signum, frame) -> None:
        self.got = True

    def __exit__(self, exc_type, exc, tb) -> bool:
        if self.old is not None:
            signal.signal(signal.SIGINT, self.old)
        if self.got and exc_type is None:
            raise KeyboardInterrupt("the results were written first")
        return False


# Files and directories a solve (and playbacks of its solution) write into a run directory.
SOLVE_FILES = ("summary.json", "solution.npz", "convergence.png", "replay.html", "checkpoint.npz")
SOLVE_FILES += ("search.png", "search.npz")  # a sampling search's (search, or solve after one)


def output_dir(out: str | Path, task_name: str | None = None, playback: bool = False) -> Path:
    """``out`` ready to write into: created if missing; ConfigError if it is a file or holds
    another task's results (results are never mixed or overwritten across tasks), or (unless
    ``playback``) if it is a ``playback-*`` directory of a solved run, which the next solve
    of that run clears."""

    if not str(out).strip():
        raise ConfigError("--out: an empty directory name")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: exists and is not a directory")
    if not playback and out.name.startswith("playback-") and (out.parent / "summary.json").exists():
        raise ConfigError(
            f"--out {out}: a playback directory of the run in {out.parent} (the next solve "
            "there removes it): choose another --out"
        )
    if task_name is not None:
        previous = previous_task(out)
        torn = [m for m in RESULT_MARKERS if (out / m).exists()] if previous is None else []
        if torn:  # results are there, but whose cannot be read
            raise ConfigError(
                f"{out} holds results whose {torn[0]} is unreadable: choose another --out "
                "(or delete that directory)"
            )
        if previous is not None and previous != task_name:
            what = (
                "a bench's results" if previous == "bench" else f"the results of task {previous!r}"
            )
            raise ConfigError(
                f"{out} holds {what}: choose another --out (or delete that directory)"
            )
    created = [p for p in [out, *out.parents] if not p.exists()]  # leaf first
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ConfigError(f"--out {out}: {e.strerror}") from None
    if created:  # (before the lock: a directory it cannot lock is removed too)
        _CREATED.append(created)
    _lock(out)
    return out


_CREATED: list[list[Path]] = []  # directories this process created per output (leaf first)


def discard_empty_outputs() -> None:
    """Removes the output directories this process created that hold nothing but their lock
    file (a command that failed before writing a result leaves no empty directory behind)."""

    while _CREATED:
        dirs = _CREATED.pop()
        out = dirs[0]
        try:
            if {p.name for p in out.iterdir()} <= {LOCK_NAME}:
                fd = _LOCKS.pop(str(out.resolve()), None)
                if fd is not None:  # (only a lock this process holds is removed)
                    _lock_file(out).unlink(missing_ok=True)
                    os.close(fd)
                for d in dirs:  # the output directory, then the parents made for it
                    d.rmdir()  # OSError if not empty (e.g. another run started in it)
        except OSError:
            pass


# Locks. A process holds an flock on DIR/.hydroilqr.lock while it writes DIR (exclusive) or
# plays the plan in DIR (shared), until ``release_locks`` at the end of the command (or until
# the process ends: the system releases an flock even on kill -9, leaving the file). The last
# holder removes the file: it unlinks it only under an exclusive lock, so no other process
# holds it then; one that opened the file just before finds, once it has the lock, that the
# file it locked is no longer the one at the path, and locks the path's new file instead
# (``_hold``). So removing the file never lets two writers in.
_LOCKS: dict[str, int] = {}  # directory -> open lock file, held until the command ends
LOCK_NAME = ".hydroilqr.lock"


def _lock_file(directory: str | Path) -> Path:
    return Path(directory) / LOCK_NAME


class _Held(Exception):
    """Another process holds a conflicting lock."""


class _Foreign(Exception):
    """The lock file's path holds something hydroilqr never makes there: a symbolic link
    (even a dangling one), a hard link to another file, or a special file. It is never
    followed, written or truncated (a file outside the directory could change)."""


def _open_lock_file(path: Path) -> int:
    """The lock file at ``path`` opened (created if missing) without following a link;
    _Foreign if the path is not a lock file of ours."""

    flags = os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC
    if path.is_symlink():
        raise _Foreign
    try:
        fd = os.open(path, flags, 0o644)
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise _Foreign from None
        raise
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode) or st.st_nlink != 1:
        os.close(fd)
        raise _Foreign
    return fd


def _foreign_lock(path: Path):
    return ConfigError(
        f"{path}: not a lock file hydroilqr made (a link or a special file): remove it and "
        "run again"
    )


def _is_file_at(fd: int, path: Path) -> bool:
    """Whether the open file ``fd`` is still the file at ``path`` (not removed or replaced)."""

    try:
        st = os.stat(path)
    except FileNotFoundError:
        return False
    here = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (here.st_dev, here.st_ino)


def _hold(path: Path, shared: bool, fd: int | None = None) -> int:
    """An flock on the lock file ``path`` (``fd``: already open on it, e.g. a shared lock to
    upgrade), on the file that is at ``path`` once it is held; OSError if it cannot be opened,
    _Held if another process holds it."""

    mode = (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB
    for _ in range(100):  # each retry follows a holder's release: this ends at once
        if fd is None:
            fd = _open_lock_file(path)
        try:
            fcntl.flock(fd, mode)
        except OSError:
            os.close(fd)
            raise _Held from None
        if _is_file_at(fd, path):
            return fd
        os.close(fd)  # its holder removed it on release: lock the path's new file
        fd = None
    raise _Held


def _lock(out: Path) -> None:
    """One run per output directory at a time: an exclusive flock on ``out/.hydroilqr.lock``,
    held until ``release_locks`` (or the process ends, even by kill -9), or until
    ``discard_empty_outputs`` removes a directory this process created for nothing. Also
    proves the directory is writable before any work is done."""

    key = str(Path(out).resolve())
    if key in _LOCKS:
        return
    path = _lock_file(out)
    # An existing lock file opens for writing even in a directory made read-only since (a run
    # directory kept as it was): that alone would let the solve run, then fail on its files.
    _probe_writable(out)
    try:  # this process reads it too (playback --out RUN): upgrade
        fd = _hold(path, shared=False, fd=_READ_LOCKS.pop(key, None))
    except _Held:
        raise ConfigError(
            f"{out} is in use by another hydroilqr run{_holder(path)}: wait for it or choose "
            "another --out"
        ) from None
    except _Foreign:
        raise _foreign_lock(path) from None
    except OSError as e:
        raise ConfigError(f"--out {out}: not writable ({e.strerror})") from None
    try:
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
    except OSError as e:  # e.g. a full disk: the file this process made is not left behind
        _release(path, fd)
        raise ConfigError(f"--out {out}: not writable ({e.strerror})") from None
    _LOCKS[key] = fd


def _holder(path: Path) -> str:
    """Who holds the lock file ``path``, as the refusal says it."""
    try:
        other = read_bounded(path, "lock file", 4096).decode(errors="replace").strip()
    except (OSError, ValueError):
        other = ""
    if other.isdigit():  # (a process id; anything else in the file is not quoted)
        return f" (process {other}, or a playback reading its plan)"
    return " (a playback reading its plan)"


def _probe_writable(out: Path) -> None:
    """ConfigError unless a file can be created (and removed) in ``out``."""

    try:
        fd, probe = tempfile.mkstemp(prefix=".hydroilqr-probe-", dir=out)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise ConfigError(f"--out {out}: not writable ({e.strerror})") from None


def read_lock(run_dir: Path) -> None:
    """A shared lock on a run directory this process reads (playback of its plan): a solve
    into it is refused meanwhile, so a playback never pairs an old plan with new results.
    Nothing to do where the directory is not writable (nothing can replace it either)."""

    key = str(Path(run_dir).resolve())
    if key in _LOCKS or key in _READ_LOCKS:
        return
    try:
        _READ_LOCKS[key] = _hold(_lock_file(run_dir), shared=True)
    except _Held:
        raise ConfigError(
            f"{run_dir} is being written by another hydroilqr run: wait for it"
        ) from None
    except _Foreign:
        raise _foreign_lock(_lock_file(run_dir)) from None
    except OSError:
        return


_READ_LOCKS: dict[str, int] = {}  # directories this process reads (shared locks)


def release_locks() -> None:
    """Releases every lock this process holds (the command is done with its directories).
    Each lock file is removed unless another process holds it too (a playback sharing a read
    lock), which then removes it when it is done."""

    if os.getpid() != _PID:  # a forked copy of this process: its parent holds them
        return
    for table in (_LOCKS, _READ_LOCKS):
        while table:
            key, fd = table.popitem()
            _release(_lock_file(key), fd)


_PID = os.getpid()  # the process whose tables these are (a forked child inherits them)


def _release(path: Path, fd: int) -> None:
    try:
        # Exclusive (a shared lock is upgraded): no other process holds this file then.
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        if _is_file_at(fd, path):
            path.unlink()
    except OSError:
        pass  # another holder (it removes the file), or the directory is gone or read-only
    finally:
        os.close(fd)


# What ``hydroilqr playback`` writes (into DIR/playback-POLICY, or where --out says).
PLAYBACK_FILES = ("playback.json", "playback.npz", "playback.png", "reference.csv", "playback.html")


def solve_outputs(out: Path) -> list[Path]:
    """What earlier solves wrote into ``out``: standard files, task plots and playbacks."""
    out = Path(out)
    if not out.is_dir():
        return []
    names = set(SOLVE_FILES) | metrics_mod.plot_files() | _previous_plot_files(out)
    if (out / "playback.json").exists():  # a playback of the earlier plan written into out
        names |= set(PLAYBACK_FILES)
    found = [out / n for n in sorted(names) if (out / n).exists()]
    found += sorted(p for p in out.glob("playback-*") if (p / "playback.json").exists())
    return found


def _previous_plot_files(out: Path) -> set[str]:
    """Plots named after the task's parameters (e.g. a body) that the solve recorded in
    ``out/summary.json`` wrote."""
    try:
        cfg = json.loads((Path(out) / "summary.json").read_text()).get("config") or {}
        return metrics_mod.plot_files(cfg.get("metrics") or [], cfg.get("metric_params") or {})
    except (OSError, ValueError, AttributeError, TypeError):
        return set()
