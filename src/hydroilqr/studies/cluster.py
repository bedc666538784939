"""The Dask client for independent jobs (sweep points, multi-start solves).

``open_client(None)`` starts an embedded ``LocalCluster``: one single-threaded worker process
per core (``workers`` to choose), its dashboard on a free loopback port. ``open_client(ADDRESS)``
connects to an existing scheduler within ``CONNECT_SECONDS`` (``open_client(Scheduler(ADDRESS,
SECONDS))`` for another deadline: the commands' ``--connect-timeout``) or fails with one line
naming the address (a silent listener, one that closes, or one speaking another protocol
included).
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import socket
import threading
import time
from multiprocessing import resource_tracker
from typing import NamedTuple

import psutil
from distributed import Client, LocalCluster

from hydroilqr.io.environment import cores
from hydroilqr.problem.errors import ConfigError

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


class Scheduler(NamedTuple):
    """An existing Dask scheduler: its address and how long it has to answer (a plain address
    string is one with the default ``CONNECT_SECONDS``)."""

    address: str
    connect_seconds: float = CONNECT_SECONDS

    def __str__(self) -> str:
        return self.address


def open_client(scheduler: str | Scheduler | None, workers: int | None = None):
    """(client, cluster): cluster is None when connected to an existing scheduler."""

    if scheduler:
        address, seconds = Scheduler(scheduler) if isinstance(scheduler, str) else scheduler
        # a lost scheduler is reported in one line at the end, not as Dask's tracebacks
        logging.getLogger("distributed.client").setLevel(logging.CRITICAL)
        _probe_scheduler(address, seconds)
        return _client_within(Client, address, seconds), None

    n = workers or cores()
    # Ctrl+C in a terminal reaches the whole process group. The workers never act on it, so
    # only this process does: it stops the work and the cluster, without every worker
    # printing its own KeyboardInterrupt traceback. The cluster's threads (its event loop,
    # which starts the worker processes, also those Dask restarts later) are created with
    # SIGINT blocked, and a process inherits its starter's blocked signals: the workers start
    # with it blocked (worker_setup also ignores it). This process keeps receiving it
    # throughout: ignoring it while the workers were spawned lost a Ctrl+C pressed in those
    # seconds (on a busy machine the sweep then ran to its end).
    cluster = None
    others = {c.pid for c in psutil.Process().children()}
    try:
        with _sigint_blocked_in_new_threads():
            cluster = LocalCluster(
                n_workers=0,  # (started by scale below)
                threads_per_worker=1,
                processes=True,
                dashboard_address=None,
                silence_logs=logging.ERROR,
                # The scheduler's HTTP routes still bind a port: any free one, so
                # parallel sweeps do not warn about 8787 being taken.
                scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                preload=["hydroilqr.studies.worker_setup"],
            )
        _OTHER_CHILDREN[id(cluster)] = others
        cluster.scale(n)
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


# id(cluster) -> the child processes this process had before it started that cluster
_OTHER_CHILDREN: dict[int, set[int]] = {}
START_SECONDS = 300.0  # a local cluster's workers start within this long, or it is an error


@contextlib.contextmanager
def _sigint_blocked_in_new_threads():
    """SIGINT blocked in this thread inside the block, so the threads started meanwhile
    (and the processes they start) block it; this thread's mask is restored after."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    # (multiprocessing's resource tracker, started with the first worker, unblocks SIGINT in
    # the thread that starts it: it is started here first, before anything is blocked)
    resource_tracker.ensure_running()
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def _spawned_pids(me, before: set[int]) -> list[int]:
    """The process ids of ``me``'s multiprocessing spawns (worker processes) not in
    ``before``."""
    pids = []
    for child in me.children():
        if child.pid in before:
            continue
        try:
            if any("spawn_main" in part for part in child.cmdline()):
                pids.append(child.pid)
        except psutil.Error:
            pass
    return pids


def kill_workers(cluster) -> None:
    """Ends an embedded cluster's worker processes at once (after Ctrl+C: their unfinished
    jobs are abandoned anyway; closing them politely waits for a busy worker and lets it
    log the scheduler's going away)."""

    for name in ("distributed", "tornado.application"):  # (a nanny whose worker it kills)
        logging.getLogger(name).setLevel(logging.CRITICAL)
    pids = {getattr(nanny, "pid", None) for nanny in list(getattr(cluster, "workers", {}).values())}
    # A worker still starting (on a busy machine, seconds) is not listed yet: left alive, it
    # printed a heartbeat traceback when the scheduler went away. Every worker process is a
    # multiprocessing spawn of this process.
    # (children this process had before the cluster started are not its workers)
    if id(cluster) in _OTHER_CHILDREN:
        pids |= set(_spawned_pids(psutil.Process(), _OTHER_CHILDREN[id(cluster)]))
    for pid in pids - {None}:
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
