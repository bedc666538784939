"""Worker processes that each hold their own copy of the plant.

pydrake holds the GIL while Drake computes, so Python threads do not run two discrete updates
at once; processes do. One pool per ``Dynamics``, created on first use and shut down at exit:
``size − 1`` spawned processes (nothing of Drake is forked), this process being the first
worker. Each worker builds its plant from the task's dictionary, so what it computes is bitwise
what this process would compute (tests check both uses).

Two kinds of work are sent to it:

* ``autodiff``: the AutoDiff partials of every workers-th time step (the solver
  setting ``autodiff_workers``, passed by derivatives.py);
* ``closed_loop_rollouts``: line-search trials, one step size per process (the solver setting
  ``line_search_workers``, passed by ilqr.py to ``line_search_width``). A round evaluates ε,
  ε·f, ε·f², ... side by side and the first acceptable one in that order is taken, so the
  iterates are those of the serial line search;
* ``sample_rollouts``: a sampling planner's samples (MPC's ``planner: sampling``), dealt out
  in turn to the processes: torques open loop, or joint position targets under the PD+ law.

The worker counts are arguments (0 = one per core). The pool is created by its first user with
that user's size (``pool(dyn, size)``: size − 1 processes); a later, larger request shares it.
The processes start when the pool is created; until they have built their plants
(``started``), the work is computed in this process, so a solve does not wait for them.
Where child processes are not allowed (inside a daemonic process, e.g. a sweep worker) the
pool is marked unavailable and everything runs serially here.
"""

from __future__ import annotations

import multiprocessing
import os
import sys
import threading
import time
import weakref
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from hydroilqr.io.environment import cores
from hydroilqr.model.autodiff import autodiff_serial
from hydroilqr.model.pd import pd_rollout
from hydroilqr.model.plant import Dynamics, SimulationError

_DYN: Dynamics | None = None  # the plant of this worker process


def resolve(count: int) -> int:
    """A worker-count setting: 0 = one per core."""
    return count if count > 0 else cores()


def pool_size(dyn: Dynamics) -> int:
    """Processes of the Dynamics' pool, this one included (1: no pool)."""
    return getattr(dyn, "_worker_pool_size", 1) if getattr(dyn, "_worker_pool", None) else 1


def pool(dyn: Dynamics, size: int) -> ProcessPoolExecutor | None:
    """The Dynamics' pool, created on first use with ``size`` processes in all (this one
    included; 0 = one per core); None if it has none (size 1 at creation) or child processes
    cannot be started here."""
    p = getattr(dyn, "_worker_pool", None)
    if p is False:
        return None
    if p is None:
        size = resolve(size)
        if size < 2:
            return None
        try:
            p = ProcessPoolExecutor(
                max_workers=size - 1,
                mp_context=_SpawnContext(),
                initializer=_init,
                initargs=(dyn.spec,),
            )
        except Exception:  # no child processes allowed here
            dyn._worker_pool = False
            return None
        # Shut down with its Dynamics (or at exit): many Tasks must not pile up processes.
        weakref.finalize(dyn, p.shutdown, wait=False, cancel_futures=True)
        dyn._worker_pool, dyn._worker_pool_size = p, size
        # Start the processes now: each imports Drake and builds its plant (about a second),
        # meanwhile the work is computed here (``started``).
        try:
            dyn._worker_starts = [p.submit(_ready) for _ in range(size - 1)]
        except Exception:  # noqa: BLE001 - no child processes allowed here
            mark_unavailable(dyn)
            return None
    return p


def started(dyn: Dynamics) -> bool:
    """The pool's processes have built their plants (or one failed trying: then the work
    sent finds out). Until then work is computed in this process: the same numbers, without
    waiting a second for the processes to start."""
    return all(f.done() for f in getattr(dyn, "_worker_starts", ()))


class _SpawnProcess(multiprocessing.context.SpawnProcess):
    """A spawned process that does not run the parent's ``__main__`` again.

    Plain spawn re-imports the user's script in every child, so a script without an
    ``if __name__ == "__main__":`` guard would run its solves once more per worker. The
    workers need nothing from ``__main__`` (their functions live in this module), so the
    script is hidden from multiprocessing while the child is launched."""

    @staticmethod
    def _Popen(process_obj):
        # Serialized, so concurrent launches never save an already hidden state; the window
        # in which other spawns in this process would not see __main__ is one launch long.
        with _HIDE_MAIN:
            main = sys.modules.get("__main__")
            keys = ("__file__", "__spec__")
            saved = {k: main.__dict__[k] for k in keys if main is not None and k in main.__dict__}
            try:
                if main is not None:
                    main.__dict__.pop("__file__", None)
                    main.__spec__ = None
                return multiprocessing.context.SpawnProcess._Popen(process_obj)
            finally:
                if main is not None:
                    main.__dict__.update(saved)


_HIDE_MAIN = threading.Lock()


class _SpawnContext(multiprocessing.context.SpawnContext):
    Process = _SpawnProcess


def mark_unavailable(dyn: Dynamics) -> None:
    """Stay serial from now on (submitting failed, e.g. inside a daemonic process)."""
    p = getattr(dyn, "_worker_pool", None)
    if p:
        p.shutdown(wait=False, cancel_futures=True)
    dyn._worker_pool = False


def warm_up(dyn: Dynamics, size: int) -> None:
    """Start a pool of ``size`` processes (0 = one per core; 1: none) and build their plants
    now (e.g. before timing), not on first use."""
    if resolve(size) < 2:
        return
    p = pool(dyn, size)
    if p is not None:
        for f in [p.submit(_ready) for _ in range(pool_size(dyn) - 1)]:
            f.result()
        for f in getattr(dyn, "_worker_starts", ()):
            f.result()


class Unavailable(RuntimeError):
    """The pool could not take work; the caller computes serially."""


def _submit(dyn: Dynamics, fn, *args):
    p = getattr(dyn, "_worker_pool", None)  # (created by the caller)
    if not p:
        raise Unavailable("no worker processes")
    try:
        return p.submit(fn, *args)
    except Exception as e:  # e.g. a broken pool
        mark_unavailable(dyn)
        raise Unavailable(str(e)) from None


# ------------------------------------------------------------------------------ in workers
def _init(spec) -> None:
    global _DYN
    _exit_with_parent(os.getppid())
    _DYN = Dynamics(spec)


def _exit_with_parent(parent: int, period: float = 1.0) -> None:
    """A worker whose parent was killed (SIGKILL, or SIGTERM without cleanup) would otherwise
    wait forever on the pool's queue, holding its plant: it exits once it is orphaned."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(period)
        os._exit(0)

    threading.Thread(target=watch, daemon=True, name="hydroilqr-parent-watch").start()


def _ready() -> bool:
    return _DYN is not None


def _autodiff(X: np.ndarray, U: np.ndarray):
    return autodiff_serial(_DYN, X, U)


def _rollout(x0, Ubar, Xbar, K, kappa, eps):
    try:
        return _DYN.closed_loop_rollout(x0, Ubar, Xbar, K, kappa, eps)
    except SimulationError as e:
        return e  # a rejected trial, not a failure of the worker


def sample_rollout(dyn: Dynamics, x0, command, space: str, kp: float, kd: float):
    """(X, U) of one sample on ``dyn`` from x0: ``space`` torque (U = the command clipped)
    or position (the PD+ law towards the command's targets); a SimulationError returned."""
    try:
        if space == "torque":
            U = dyn.clip_to_limits(np.asarray(command, float))
            return dyn.rollout(x0, U), U
        return pd_rollout(dyn, x0, command, kp, kd)
    except SimulationError as e:
        return e


def _samples(x0, commands, space, kp, kd):
    return [sample_rollout(_DYN, x0, c, space, kp, kd) for c in commands]


# ------------------------------------------------------------------------------ in this process
def autodiff(dyn: Dynamics, X: np.ndarray, U: np.ndarray, workers: int):
    """Same result as ``autodiff.autodiff_serial`` on X: [N, nx], U: [N, nu]: the steps are
    dealt out to ``workers`` chunks in turn (steps i, i + workers, ...; the first chunk computed
    here), so that steps in contact, which cost several times more, spread evenly (contiguous
    chunks left one process idle while the other finished a stance phase). Raises
    Unavailable."""

    pool(dyn, workers)
    if not started(dyn):
        return autodiff_serial(dyn, X, U)
    N = U.shape[0]
    chunks = [np.arange(i, N, workers) for i in range(workers)]
    futures = [_submit(dyn, _autodiff, X[c], U[c]) for c in chunks[1:]]
    parts = [autodiff_serial(dyn, X[chunks[0]], U[chunks[0]])]
    for c, f in zip(chunks[1:], futures):
        try:
            parts.append(f.result())
        except SimulationError:
            raise
        except Exception:  # noqa: BLE001 - a worker died: its chunk is computed here
            mark_unavailable(dyn)
            parts.append(autodiff_serial(dyn, X[c], U[c]))
    A = np.empty((N, dyn.nx, dyn.nx))
    B = np.empty((N, dyn.nx, dyn.nu))
    for c, (a, b) in zip(chunks, parts):
        A[c], B[c] = a, b
    return A, B


def line_search_width(dyn: Dynamics, requested: int) -> int:
    """How many line-search trials one round evaluates side by side (1 = serial), for the
    solver setting ``line_search_workers`` = requested (0 = one per core)."""
    w = resolve(requested)
    if w < 2 or not hasattr(dyn, "spec") or pool(dyn, w) is None:  # (test dynamics: serial)
        return 1
    return min(w, pool_size(dyn))


def closed_loop_rollouts(dyn: Dynamics, x0, Ubar, Xbar, K, kappa, eps_list):
    """Forward passes of eq. (7) for each ε in eps_list, the first here and the others in
    worker processes. Returns a list of (X: [N+1, nx], U: [N, nu]) or SimulationError (a
    rejected trial) per ε. Raises Unavailable only before anything was computed."""
    pool(dyn, len(eps_list))
    if not started(dyn):
        raise Unavailable("the worker processes are still starting")
    futures = [_submit(dyn, _rollout, x0, Ubar, Xbar, K, kappa, e) for e in eps_list[1:]]
    try:
        out = [dyn.closed_loop_rollout(x0, Ubar, Xbar, K, kappa, eps_list[0])]
    except SimulationError as e:
        out = [e]
    for f, eps in zip(futures, eps_list[1:]):
        try:
            out.append(f.result())  # (X, U) or the SimulationError of a rejected trial
        except Exception:  # the worker died: redo the trial here, stay serial from now on
            mark_unavailable(dyn)
            try:
                out.append(dyn.closed_loop_rollout(x0, Ubar, Xbar, K, kappa, eps))
            except SimulationError as e:
                out.append(e)
    return out


def sample_rollouts(dyn: Dynamics, x0, commands: list, space: str, kp: float, kd: float,
                    workers: int) -> list:  # fmt: skip
    """``sample_rollout`` of each command, dealt out in turn to ``workers`` processes (this
    one included; 0: one per core) while the pool has started, else all here: a list of
    (X, U) or SimulationError, in the order of ``commands`` (the same numbers either way)."""
    w = resolve(workers)
    if w > 1:
        pool(dyn, w)
    w = min(w, pool_size(dyn)) if w > 1 and started(dyn) else 1
    idx = [list(range(i, len(commands), w)) for i in range(w)]
    futures = []
    for chunk in idx[1:]:
        try:
            futures.append(_submit(dyn, _samples, x0, [commands[i] for i in chunk], space, kp, kd))
        except Unavailable:
            futures.append(None)
    out: list = [None] * len(commands)
    for i in idx[0]:
        out[i] = sample_rollout(dyn, x0, commands[i], space, kp, kd)
    for chunk, f in zip(idx[1:], futures):
        try:
            parts = f.result() if f is not None else None
        except Exception:  # noqa: BLE001 - the worker died: its samples are rolled out here
            mark_unavailable(dyn)
            parts = None
        if parts is None:
            parts = [sample_rollout(dyn, x0, commands[i], space, kp, kd) for i in chunk]
        for i, r in zip(chunk, parts):
            out[i] = r
    return out
