"""Closing an embedded Dask cluster on a loaded machine: a close that times out after the
work is done stops the workers outright instead of failing the command (it did: `hydroilqr
solve` of a task with a search: section ended in "error:" after its search and polish)."""

from __future__ import annotations

from hydroilqr.studies import multistart


class _Slow:
    def __init__(self):
        self.closed = 0

    def close(self, timeout=None):
        self.closed += 1
        raise TimeoutError(f"timed out after {timeout} s.")


def test_a_close_that_times_out_kills_the_workers(monkeypatch):
    killed = []
    monkeypatch.setattr(multistart, "kill_workers", killed.append)
    client, cluster = _Slow(), _Slow()
    multistart._close(client, cluster)
    assert client.closed == 1 and cluster.closed == 1 and killed == [cluster]
    multistart._close(_Slow(), None)  # no embedded cluster: nothing to kill
    assert killed == [cluster]
