"""output.files: atomic writes, locks and Ctrl+C while results are written."""

from __future__ import annotations

import numpy as np
import pytest


def test_ctrl_c_while_results_are_written_waits_for_them():
    import os
    import signal

    from hydroilqr.output.report import deferred_interrupt

    done = []
    with pytest.raises(KeyboardInterrupt, match="written first"):
        with deferred_interrupt():
            os.kill(os.getpid(), signal.SIGINT)
            done.append("the rest of the block ran")
    assert done
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_an_ignored_sigint_stays_ignored_and_a_read_lock_upgrades(tmp_path):
    import os
    import signal

    from hydroilqr.output import report

    old = signal.signal(signal.SIGINT, signal.SIG_IGN)  # e.g. a background job
    try:
        with report.deferred_interrupt():
            os.kill(os.getpid(), signal.SIGINT)  # ignored: nothing raised afterwards
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, old)
    report.read_lock(tmp_path)  # playback RUN --out RUN: reads, then writes the same dir
    report._lock(tmp_path)
    key = str(tmp_path.resolve())
    assert key in report._LOCKS and key not in report._READ_LOCKS
    os.close(report._LOCKS.pop(key))


def test_atomic_writes_leave_the_old_file_when_a_write_fails(tmp_path, monkeypatch):
    import os

    from hydroilqr.io import files

    p = files.atomic_write(tmp_path / "a.json", '{"old": 1}')
    files.atomic_savez(tmp_path / "a.npz", X=np.arange(3.0))
    with np.load(tmp_path / "a.npz") as d:
        assert d["X"].tolist() == [0.0, 1.0, 2.0]

    def full_disk(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", full_disk)
    with pytest.raises(OSError):
        files.atomic_write(p, '{"new": 2}')
    assert p.read_text() == '{"old": 1}'  # untouched, and no temporary file left behind
    assert sorted(q.name for q in tmp_path.iterdir()) == ["a.json", "a.npz"]


def test_the_last_holder_removes_the_lock_file_and_a_stale_open_cannot_let_two_writers_in(
    tmp_path,
):
    import os

    from hydroilqr.output import report

    path = tmp_path / report.LOCK_NAME
    report._lock(tmp_path)  # a writer
    stale = os.open(path, os.O_RDWR)  # another one opened the file just before its release
    report.release_locks()
    assert not path.exists()
    report._lock(tmp_path)  # a third writer, on a new lock file
    with pytest.raises(report._Held):  # the old file's flock is free, but no longer the lock
        report._hold(path, shared=False, fd=stale)
    report.release_locks()
    assert not path.exists()
    # two readers share it: the first to leave keeps the file, the last removes it
    first, second = (report._hold(path, shared=True) for _ in range(2))
    report._release(path, first)
    assert path.exists()
    with pytest.raises(report._Held):  # and it is still a lock
        report._hold(path, shared=False)
    report._release(path, second)
    assert not path.exists()
