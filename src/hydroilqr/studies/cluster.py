"""The Dask client for independent jobs (sweep points, multi-start solves).

``open_client(None)`` starts an embedded ``LocalCluster``: one single-threaded worker process
per core (``workers`` to choose), its dashboard on a free loopback port. ``open_client(ADDRESS)``
connects to an existing scheduler within ``CONNECT_SECONDS`` or fails with one line naming the
address (a silent listener, one that closes, or one speaking another protocol included).
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import threading
import time

import psutil
from distributed import Client, LocalCluster

from hydroilqr.io.environment import cores
from hydroilqr.problem.config import ConfigError

CONNECT_SECONDS = 15.0  # connecting to a --scheduler: at most this long


def _probe_scheduler(address: str, seconds: float = CONNECT_SECONDS) -> None:
    """ConfigError naming ``address`` unless a TCP scheduler there greets within ``seconds``
    (a Dask scheduler sends its handshake first; a silent or HTTP listener is refused here,
    before Dask waits on it). Other schemes (tls://, ...) are left to ``_client_within``."""

    scheme, _, rest = address.rpartition("://")
    if scheme not in ("", "tcp"):
        return
    host, _, port = rest.rpartition(":")
    host = host.strip("[]") or "127.0.0.1"
    try:
        port_no = int(port)
    except ValueError:
        raise ConfigError(f"--scheduler {address}: expected tcp://HOST:PORT") from None
    deadline = time.monotonic() + seconds
    try:
        with socket.create_connection((host, port_no), timeout=seconds) as s:
            s.settimeout(max(0.1, deadline - time.monotonic()))
            first = s.recv(16)
    except TimeoutError:
        raise ConfigError(
            f"--scheduler {address}: no answer within {seconds:g} s (not a Dask scheduler?)"
        ) from None
    except OSError as e:
        raise ConfigError(f"--scheduler {address}: cannot connect ({e.strerror or e})") from None
    if not first:
        raise ConfigError(f"--scheduler {address}: closed the connection (not a Dask scheduler?)")
    if first[:5] in (b"HTTP/", b"<!DOC", b"<html") or first[:4] == b"SSH-":
        raise ConfigError(f"--scheduler {address}: answers, but not as a Dask scheduler")


def _client_within(Client, address: str, seconds: float = CONNECT_SECONDS):
    """``Client(address)``, or ConfigError naming the address when it is not connected
    within ``seconds`` (Dask's own timeout does not bound every way a connection can stall)."""
    box: dict = {}

    def connect() -> None:
        try:
            box["client"] = Client(address, timeout=f"{seconds:g}s")
        except BaseException as e:  # noqa: BLE001 - reported by the caller
            box["error"] = e

    t = threading.Thread(target=connect, name="hydroilqr-connect", daemon=True)
    t.start()
    t.join(seconds + 2)
    if t.is_alive():
        raise ConfigError(f"--scheduler {address}: not connected within {seconds:g} s")
    e = box.get("error")
    if e is not None:
        text = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise ConfigError(f"--scheduler {address}: cannot connect ({text})") from None
    return box["client"]


def open_client(scheduler: str | None, workers: int | None = None):
    """(client, cluster): cluster is None when connected to an existing scheduler."""

    if scheduler:
        # a lost scheduler is reported in one line at the end, not as Dask's tracebacks
        logging.getLogger("distributed.client").setLevel(logging.CRITICAL)
        _probe_scheduler(scheduler)
        return _client_within(Client, scheduler), None

    n = workers or cores()
    # Ctrl+C in a terminal reaches the whole process group. The workers ignore it, so only
    # this process acts on it: it stops the work and the cluster, without every worker
    # printing its own KeyboardInterrupt traceback. A worker inherits an ignored SIGINT from
    # this process, which ignores it only while the worker processes are being spawned
    # (_spawn_workers; ignoring it for the whole start-up lost a Ctrl+C pressed in those
    # seconds and let a sweep run to its end), and ignores it again itself as it starts
    # (worker_setup, preloaded: also a worker Dask restarts later).
    cluster = None
    try:
        cluster = LocalCluster(
            n_workers=0,  # (started by _spawn_workers)
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
            # The scheduler's HTTP routes still bind a port: any free one, so
            # parallel sweeps do not warn about 8787 being taken.
            scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
            preload=["hydroilqr.studies.worker_setup"],
        )
        _spawn_workers(cluster, n)
        try:
            cluster.wait_for_workers(n, timeout=START_SECONDS)
        except TimeoutError:
            raise ConfigError(
                f"the local Dask cluster's {n} worker(s) did not start within {START_SECONDS:g} s"
            ) from None
    except BaseException:
        if cluster is not None:
            _close_quietly(cluster)
        raise
    return Client(cluster), cluster


START_SECONDS = 300.0  # a local cluster's workers start within this long, or it is an error
SPAWN_SECONDS = 30.0  # at most this long with SIGINT ignored while workers are spawned


def _spawn_workers(cluster, n: int) -> None:
    """Asks ``cluster`` for ``n`` workers and returns once their processes exist, with SIGINT
    ignored meanwhile (from the main thread) so that they inherit an ignored one."""

    if threading.current_thread() is not threading.main_thread():
        cluster.scale(n)
        return
    me = psutil.Process()
    before = {c.pid for c in me.children()}
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        cluster.scale(n)
        deadline = time.monotonic() + SPAWN_SECONDS
        while time.monotonic() < deadline and _spawned(me, before) < n:
            time.sleep(0.02)
    finally:
        signal.signal(signal.SIGINT, previous)


def _spawned(me, before: set[int]) -> int:
    """Worker processes (multiprocessing spawns) started since ``before``."""

    n = 0
    for child in me.children():
        if child.pid in before:
            continue
        try:
            n += any("spawn_main" in part for part in child.cmdline())
        except psutil.Error:
            pass
    return n


def kill_workers(cluster) -> None:
    """Ends an embedded cluster's worker processes at once (after Ctrl+C: their unfinished
    jobs are abandoned anyway; closing them politely waits for a busy worker and lets it
    log the scheduler's going away)."""

    for nanny in list(getattr(cluster, "workers", {}).values()):
        pid = getattr(nanny, "pid", None)
        if pid:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass


def _close_quietly(cluster) -> None:
    """Closes a cluster after Ctrl+C without Dask's log lines."""
    logging.getLogger("distributed").setLevel(logging.CRITICAL)
    kill_workers(cluster)
    try:
        cluster.close(timeout=5)
    except BaseException:  # noqa: BLE001 - a half-started cluster: nothing more to do
        pass
