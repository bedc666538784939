"""Dynamics partials f_x, f_u (paper eq. 2) along a whole trajectory, as their own layer.

``linearize(dyn, X, U, method)`` returns ``A: [N, nx, nx]`` and ``B: [N, nx, nu]`` with
``A_k = ∂f/∂x (x_k, u_k)`` and ``B_k = ∂f/∂u (x_k, u_k)`` in Drake's coordinates (quaternions
as four numbers).

Methods (``DerivativeMethod``):

* ``AUTODIFF``: Drake AutoDiffXd through the discrete update, one time step at a time with all
  nx+nu directions seeded at once (the paper's method). Through SAP, Drake differentiates the
  converged solve with the implicit function theorem.
* ``FORWARD``: one-sided differences, ``(f(z + h e_i) − f(z)) / h``.
* ``CENTRAL``: ``(f(z + h e_i) − f(z − h e_i)) / 2h``, second-order accurate.

The finite-difference methods evaluate every perturbed (x, u) of every time step in a single
call to Drake's ``BatchEvalUniquePeriodicDiscreteUpdate``, which runs them on C++ threads:
there is no Python loop over columns or time steps.

``interval > 1`` computes exact partials at every ``interval``-th step (and the last) and
linearly interpolates between them: a speed/accuracy trade-off reported by ``bench``.
"""

from __future__ import annotations

import enum
import os

import numpy as np
from pydrake.autodiffutils import ExtractGradient, InitializeAutoDiff
from pydrake.common import Parallelism
from pydrake.systems.analysis import BatchEvalUniquePeriodicDiscreteUpdate

from .plant import Dynamics, SimulationError


class DerivativeMethod(enum.Enum):
    AUTODIFF = "autodiff"
    FORWARD = "forward"
    CENTRAL = "central"


def num_threads(requested: int = 0) -> int:
    return requested if requested and requested > 0 else (os.cpu_count() or 1)


def linearize(
    dyn: Dynamics,
    X: np.ndarray,
    U: np.ndarray,
    method: DerivativeMethod | str = DerivativeMethod.CENTRAL,
    eps: float = 1e-6,
    threads: int = 0,
    interval: int = 1,
    rollout: bool = False,
    adaptive: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Partials along a trajectory. X: [N+1, nx] (only X[:N] used), U: [N, nu].

    ``rollout=True`` promises that X is a rollout of U through ``dyn`` (X[k+1] = f(X[k], U[k])
    exactly, as in the solver): forward differences then reuse X[k+1] instead of evaluating
    f(X[k], U[k]) again (one evaluation per step fewer).

    ``adaptive=True`` (with ``interval > 1``) adds keypoints on both sides of every step where
    the set of touching geometry pairs changes, so interpolation never spans a contact event.

    Returns A: [N, nx, nx], B: [N, nx, nu]. Raises SimulationError if a step fails.
    """
    method = DerivativeMethod(method)
    N = U.shape[0]
    rollout = rollout and X.shape[0] == N + 1
    if interval > 1 and N > 2:
        keys = set(range(0, N, interval)) | {N - 1}
        if adaptive:
            keys |= contact_events(dyn, X[:N])
        keys = sorted(keys)
        nxt = X[np.asarray(keys) + 1] if rollout else None
        Ak, Bk = _fd_or_ad(dyn, X[keys], U[keys], method, eps, threads, nxt)
        return _interpolate(keys, Ak, Bk, N)
    return _fd_or_ad(dyn, X[:N], U, method, eps, threads, X[1 : N + 1] if rollout else None)


def _fd_or_ad(dyn, X, U, method, eps, threads, next_states):
    N = U.shape[0]
    if method is DerivativeMethod.AUTODIFF:
        workers = dyn.task.solver.autodiff_workers or (os.cpu_count() or 1)
        if workers > 1 and N >= 2 * workers and getattr(dyn, "_ad_pool", None) is not False:
            try:
                return _autodiff_parallel(dyn, X[:N], U, workers)
            except _PoolUnavailable:
                dyn._ad_pool = False  # e.g. inside a daemonic worker: stay serial from now on
        return _autodiff(dyn, X[:N], U)
    return _finite_differences(
        dyn,
        X[:N],
        U,
        central=method is DerivativeMethod.CENTRAL,
        eps=eps,
        threads=threads,
        next_states=next_states,
    )


def contact_signature(dyn: Dynamics, x: np.ndarray) -> frozenset:
    """The set of touching geometry pairs at x (a geometry query, no contact solve)."""
    surfaces, points = dyn.contact_query(x)
    pairs = {frozenset((s.id_M(), s.id_N())) for s in surfaces}
    pairs |= {frozenset((p.id_A, p.id_B)) for p in points}
    return frozenset(pairs)


def contact_events(dyn: Dynamics, X: np.ndarray) -> set[int]:
    """Steps k and k+1 wherever the touching pairs differ between X[k] and X[k+1]."""
    sig = [contact_signature(dyn, x) for x in X]
    out: set[int] = set()
    for k in range(len(sig) - 1):
        if sig[k] != sig[k + 1]:
            out |= {k, k + 1}
    return out


def _interpolate(keys, Ak, Bk, N):
    A = np.empty((N,) + Ak.shape[1:])
    B = np.empty((N,) + Bk.shape[1:])
    for j in range(len(keys) - 1):
        k0, k1 = keys[j], keys[j + 1]
        for k in range(k0, k1):
            s = (k - k0) / (k1 - k0)
            A[k] = (1 - s) * Ak[j] + s * Ak[j + 1]
            B[k] = (1 - s) * Bk[j] + s * Bk[j + 1]
    A[keys[-1]] = Ak[-1]
    B[keys[-1]] = Bk[-1]
    return A, B


def _autodiff(dyn: Dynamics, X: np.ndarray, U: np.ndarray):
    _, ad_context, ad_plant, ad_plant_context, ad_input = dyn.autodiff()
    N, nx, nu = U.shape[0], dyn.nx, dyn.nu
    A = np.empty((N, nx, nx))
    B = np.empty((N, nx, nu))
    for k in range(N):
        z = InitializeAutoDiff(np.concatenate([X[k], U[k]]))
        ad_plant.SetPositionsAndVelocities(ad_plant_context, z[:nx])
        ad_input.FixValue(ad_context, z[nx:])
        try:
            xn = ad_plant.EvalUniquePeriodicDiscreteUpdate(ad_plant_context).value(0)
        except RuntimeError as e:
            raise SimulationError(f"autodiff step {k}: {str(e).strip().splitlines()[0]}") from None
        G = ExtractGradient(xn)
        if G.shape[1] != nx + nu:  # no dependence at all (cannot happen for a real plant)
            G = np.zeros((nx, nx + nu))
        A[k], B[k] = G[:, :nx], G[:, nx:]
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(B))):
        raise SimulationError("non-finite autodiff derivatives")
    return A, B


def _finite_differences(
    dyn: Dynamics,
    X,
    U,
    central: bool,
    eps: float,
    threads: int,
    next_states: np.ndarray | None = None,
):
    N, nx, nu = U.shape[0], dyn.nx, dyn.nu
    nz = nx + nu
    Z = np.concatenate([X, U], axis=1)  # [N, nz]
    # Relative step: h_i = eps * max(1, |z_i|).
    H = eps * np.maximum(1.0, np.abs(Z))  # [N, nz]
    eye = np.eye(nz)
    plus = Z[:, None, :] + H[:, :, None] * eye[None]  # [N, nz, nz]: row i perturbs coord i
    if central:
        minus = Z[:, None, :] - H[:, :, None] * eye[None]
        pts = np.concatenate([plus, minus], axis=1)  # [N, 2nz, nz]
    elif next_states is None:
        pts = np.concatenate([plus, Z[:, None, :]], axis=1)  # [N, nz+1, nz]
    else:
        pts = plus
    flat = pts.reshape(-1, nz)
    out = _batch_step(dyn, flat, threads).reshape(N, -1, nx)
    if not central and next_states is not None:
        out = np.concatenate([out, np.asarray(next_states)[:, None, :]], axis=1)
    if central:
        D = (out[:, :nz] - out[:, nz:]) / (2.0 * H[:, :, None])
    else:
        D = (out[:, :nz] - out[:, nz : nz + 1]) / H[:, :, None]
    # D: [N, nz, nx] with D[k, i] = ∂f/∂z_i -> transpose to [N, nx, nz]
    J = np.transpose(D, (0, 2, 1))
    return np.ascontiguousarray(J[:, :, :nx]), np.ascontiguousarray(J[:, :, nx:])


def _batch_step(dyn: Dynamics, Z: np.ndarray, threads: int) -> np.ndarray:
    """Next states for many (x, u) pairs on C++ threads. Z: [M, nx+nu] -> [M, nx]."""
    nx = dyn.nx
    M = Z.shape[0]
    states = np.asfortranarray(Z[:, :nx].T)
    inputs = np.asfortranarray(Z[:, nx:].T)
    times = np.zeros((1, M))
    try:
        out = BatchEvalUniquePeriodicDiscreteUpdate(
            dyn.diagram,
            dyn.context,
            times,
            states,
            inputs,
            num_time_steps=1,
            input_port_index=dyn.diagram.get_input_port(dyn.scene.actuation_port).get_index(),
            parallelize=Parallelism(num_threads(threads)),
        )
    except RuntimeError as e:
        raise SimulationError(f"batched step: {str(e).strip().splitlines()[0]}") from None
    out = np.asarray(out).T
    if not np.all(np.isfinite(out)):
        raise SimulationError("non-finite state in a finite-difference evaluation")
    return out


def batch_step(dyn: Dynamics, X: np.ndarray, U: np.ndarray, threads: int = 0) -> np.ndarray:
    """One step from many states at once. X: [M, nx], U: [M, nu] -> [M, nx]."""
    return _batch_step(dyn, np.concatenate([X, U], axis=1), threads)


# ------------------------------------------------------------------------------------------
# AutoDiff split over worker processes (pydrake holds the GIL, so threads do not help)
# ------------------------------------------------------------------------------------------

_WORKER_DYN = None


def _worker_init(config: dict, base_dir: str) -> None:
    global _WORKER_DYN
    from .config import task_from_dict

    _WORKER_DYN = Dynamics(task_from_dict(config, base_dir))


def _worker_autodiff(X: np.ndarray, U: np.ndarray):
    return _autodiff(_WORKER_DYN, X, U)


def _autodiff_pool(dyn: Dynamics, workers: int):
    """A process pool of ``workers - 1`` processes (this process takes a share too), built
    once per Dynamics and shut down at exit."""
    pool = getattr(dyn, "_ad_pool", None)
    if pool is None:
        import atexit
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        pool = ProcessPoolExecutor(
            max_workers=workers - 1,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_worker_init,
            initargs=(dyn.task.to_dict(), dyn.task.base_dir),
        )
        atexit.register(pool.shutdown, wait=False, cancel_futures=True)
        dyn._ad_pool = pool
    return pool


class _PoolUnavailable(RuntimeError):
    pass


def _autodiff_parallel(dyn: Dynamics, X: np.ndarray, U: np.ndarray, workers: int):
    """Same result as ``_autodiff``: the steps are split into ``workers`` contiguous chunks."""
    chunks = np.array_split(np.arange(U.shape[0]), workers)
    try:
        pool = _autodiff_pool(dyn, workers)
        futures = [pool.submit(_worker_autodiff, X[c], U[c]) for c in chunks[1:]]
    except Exception as e:  # no child processes allowed here (daemonic process, limits)
        raise _PoolUnavailable(str(e)) from None
    A0, B0 = _autodiff(dyn, X[chunks[0]], U[chunks[0]])
    parts = [(A0, B0)]
    for f in futures:
        try:
            parts.append(f.result())
        except SimulationError:
            raise
        except Exception as e:  # a worker died: report as a failed derivative step
            raise SimulationError(f"autodiff worker failed: {e}") from None
    return np.concatenate([a for a, _ in parts]), np.concatenate([b for _, b in parts])
