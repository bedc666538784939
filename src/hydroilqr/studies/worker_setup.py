"""Preloaded in every worker process of the embedded Dask cluster (``studies/cluster.py``).

The worker ignores SIGINT: a terminal's Ctrl+C reaches the whole process group, and the
command's own process stops the work and the cluster; a worker acting on it too would only
print its own KeyboardInterrupt traceback."""

from __future__ import annotations

import signal
import threading


def dask_setup(worker) -> None:
    """Dask's preload hook, run in the worker process as it starts."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
