"""The Dask client for independent jobs (sweep points, multi-start solves).

``open_client(None)`` starts an embedded ``LocalCluster``: one single-threaded worker process
per core (``workers`` to choose), its dashboard on a free loopback port. ``open_client(ADDRESS)``
connects to an existing scheduler and fails with one line naming the address when it cannot.
"""

from __future__ import annotations

import logging
import signal
import threading

from hydroilqr.problem.config import ConfigError

CONNECT_TIMEOUT = "15s"


def connect(scheduler: str):
    """A client of the scheduler at ``scheduler``, or ConfigError naming it."""
    from distributed import Client

    # a lost scheduler is reported in one line, not as Dask's tracebacks
    logging.getLogger("distributed.client").setLevel(logging.CRITICAL)
    try:
        return Client(scheduler, timeout=CONNECT_TIMEOUT)
    except (OSError, TimeoutError, ValueError) as e:
        raise ConfigError(f"--scheduler {scheduler}: cannot connect ({e})") from None


def local_cluster(workers: int | None = None):
    """An embedded cluster of ``workers`` (default: one per core) single-threaded processes."""
    from distributed import LocalCluster

    from hydroilqr.model.workers import cores

    # The worker processes inherit an ignored SIGINT: Ctrl+C in a terminal (sent to the whole
    # process group) then reaches only this process, which stops the work and the cluster.
    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if main_thread else None
    try:
        return LocalCluster(
            n_workers=workers or cores(),
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
            scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
        )
    finally:
        if main_thread:
            signal.signal(signal.SIGINT, previous)


def open_client(scheduler: str | None, workers: int | None = None):
    """(client, cluster): cluster is None when connected to an existing scheduler."""
    from distributed import Client

    if scheduler:
        return connect(scheduler), None
    cluster = local_cluster(workers)
    return Client(cluster), cluster
