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
there is no Python loop over columns or time steps. With ``solver.fd_forces`` and a model
that allows it (``Dynamics.force_path``), they perturb q and an applied generalized force τ
instead of (q, v, u): a step depends on (v, u) only through the free-motion velocity
v* = v + dt M⁻¹ (B u − C v + τ_g), so f_v and f_u follow from f_τ with nq + nv evaluations per
step instead of nx + nu (``_force_differences``; 37 instead of 49 for the Mini Cheetah).

``interval > 1`` computes exact partials at every ``interval``-th step (and the last) and
linearly interpolates between them: a speed/accuracy trade-off reported by ``bench``.
"""

from __future__ import annotations

import numpy as np
from pydrake.common import Parallelism
from pydrake.systems.analysis import BatchEvalUniquePeriodicDiscreteUpdate

from hydroilqr.model.autodiff import autodiff_serial
from hydroilqr.model.plant import Dynamics, SimulationError
from hydroilqr.model.workers import Unavailable as WorkersUnavailable
from hydroilqr.model.workers import autodiff as parallel_autodiff
from hydroilqr.model.workers import resolve as resolve_workers
from hydroilqr.problem.solver import DerivativeMethod


def num_threads(requested: int = 0) -> int:
    """A ``solver.threads`` setting as a thread count: 0 (or less) = one per core. The same rule
    as worker counts (``workers.resolve``)."""
    return resolve_workers(requested or 0)


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
    autodiff_workers: int = 1,
    fd_forces: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Partials along a trajectory. X: [N+1, nx] (only X[:N] used), U: [N, nu].
    At one point: x: [nx] and u: [nu] (a number for one actuator) give A: [nx, nx] and
    B: [nx, nu].

    ``rollout=True`` promises that X is a rollout of U through ``dyn`` (X[k+1] = f(X[k], U[k])
    exactly, as in the solver): forward differences then reuse X[k+1] instead of evaluating
    f(X[k], U[k]) again (one evaluation per step fewer).

    ``adaptive=True`` (with ``interval > 1``) adds keypoints on both sides of every step where
    the set of touching geometry pairs changes, so interpolation never spans a contact event.

    ``autodiff_workers``: AutoDiff in that many processes (each with its own plant; 0 = one per
    core; the default 1 is serial, whatever the task's ``solver.autodiff_workers`` says).

    ``fd_forces``: finite differences over generalized forces where the model qualifies
    (``Dynamics.force_path``), as ``solver.fd_forces``; the default differences (x, u).

    Returns A: [N, nx, nx], B: [N, nx, nu]. Raises SimulationError if a step fails (or x or u
    holds NaN), ValueError for wrong shapes.
    """
    try:
        method = DerivativeMethod(method)
    except ValueError:
        valid = ", ".join(m.value for m in DerivativeMethod)
        raise ValueError(f"derivative method {method!r}: expected one of {valid}") from None
    if np.ndim(X) == 1 and np.ndim(U) <= 1:  # one state and input
        x, u = dyn.check_arguments(X, np.atleast_1d(U))
        A, B = _fd_or_ad(
            dyn, x[None], u[None], method, eps, threads, None, autodiff_workers, fd_forces
        )
        return A[0], B[0]
    X, U = dyn.check_arguments(X, U, x_rows=True, u_rows=True)  # NaN -> SimulationError
    N = U.shape[0]
    if X.shape[0] < N:
        raise ValueError(f"X must have N+1 (or N) rows for U: [N, nu], got {X.shape[0]} < {N}")
    rollout = rollout and X.shape[0] == N + 1
    if interval > 1 and N > 2:
        keys = keypoints(dyn, X, N, interval, adaptive)
        nxt = X[np.asarray(keys) + 1] if rollout else None
        Ak, Bk = _fd_or_ad(
            dyn, X[keys], U[keys], method, eps, threads, nxt, autodiff_workers, fd_forces
        )
        return _interpolate(keys, Ak, Bk, N)
    nxt = X[1 : N + 1] if rollout else None
    return _fd_or_ad(dyn, X[:N], U, method, eps, threads, nxt, autodiff_workers, fd_forces)


def keypoints(dyn: Dynamics, X: np.ndarray, N: int, interval: int, adaptive: bool) -> list[int]:
    """Steps with exact partials: every ``interval``-th, the last, and (adaptive) both sides
    of every contact event. X: [N+1, nx] (or [N, nx])."""
    if interval <= 1 or N <= 2:
        return list(range(N))
    keys = set(range(0, N, interval)) | {N - 1}
    if adaptive:
        keys |= contact_events(dyn, X[:N])
    return sorted(keys)


class Linearizer:
    """Partials along successive trajectories, reusing those taken at (nearly) the same point.

    For each time step k it keeps the point z_k = (x_k, u_k) where exact partials were last
    taken, and those partials. A call with a new trajectory recomputes, among the keypoints
    (see ``keypoints``), only the steps whose point moved by more than ``reuse_tolerance`` in
    the scaled max norm ``max_i |Δz_i| / max(1, |z_i|)``. With ``max_steps > 0`` at most that
    many are recomputed per call, those that moved most first (steps never computed come
    first); a step never computed and left out borrows the partials of the nearest step that
    has some. ``reuse_tolerance = 0`` and ``max_steps = 0`` give exactly ``linearize`` (only a
    step whose (x, u) is bitwise unchanged keeps its partials).

    MPC keeps one Linearizer across updates and calls ``shift(s)`` when the plan moves s steps
    forward in time, so partials of the previous plan serve the next one (the derivatives of a
    step are a function of its (x, u) only, not of time).

    ``secant_updates > 0``: after a call with exact partials, that many calls (each with a
    rollout: X[k+1] = f(X[k], U[k])) correct the previous call's partials of every step with
    Broyden's rank-one update ``J += (Δf − J Δz) Δzᵀ / (Δzᵀ Δz)`` (Δz: the step's change of
    (x, u), Δf: of its next state) instead of differentiating; then exact partials again. A
    call without a rollout, or with another N, is exact (and the next one after a call without
    a rollout too). ``last_secant``: the last call's partials were secant updates (``exact``
    recomputes them).

    ``last_computed``: how many steps the last call differentiated.
    """

    def __init__(
        self,
        dyn: Dynamics,
        method: DerivativeMethod | str,
        eps: float = 1e-6,
        threads: int = 0,
        interval: int = 1,
        adaptive: bool = False,
        reuse_tolerance: float = 0.0,
        max_steps: int = 0,
        autodiff_workers: int = 1,
        fd_forces: bool = False,
        secant_updates: int = 0,
    ):
        self.dyn = dyn
        self.autodiff_workers = autodiff_workers
        self.fd_forces = fd_forces
        self.secant_updates = secant_updates
        self._secant: tuple | None = None  # (J [N, nx, nz], Z [N, nz], F [N, nx], updates done)
        self.last_secant = False  # the last call's partials were secant updates
        self.method = DerivativeMethod(method)
        self.eps, self.threads = eps, threads
        self.interval, self.adaptive = interval, adaptive
        self.reuse_tolerance, self.max_steps = reuse_tolerance, max_steps
        self.Z: np.ndarray | None = None  # [N, nz] points of the cached partials (NaN: none)
        self.A: np.ndarray | None = None  # [N, nx, nx]
        self.B: np.ndarray | None = None  # [N, nx, nu]
        self.last_computed = 0

    @staticmethod
    def from_settings(dyn: Dynamics, s) -> Linearizer:
        return Linearizer(
            dyn,
            s.derivatives,
            s.fd_epsilon,
            s.threads,
            s.derivative_interval,
            s.derivative_adaptive,
            s.derivative_reuse_tolerance,
            autodiff_workers=s.autodiff_workers,
            fd_forces=s.fd_forces,
            secant_updates=s.derivative_secant_updates,
        )

    def shift(self, steps: int) -> None:
        """The plan moved ``steps`` forward: cached step k + steps becomes step k."""
        if self.Z is not None and steps > 0:
            self.Z, self.A, self.B = self.Z[steps:], self.A[steps:], self.B[steps:]

    def clear(self) -> None:
        """Forget every cached partial (the next call differentiates all keypoints)."""
        self.Z = self.A = self.B = None
        self._secant = None

    def _resize(self, N: int) -> None:
        dyn = self.dyn
        nz = dyn.nx + dyn.nu
        if self.Z is None:
            self.Z = np.full((0, nz), np.nan)
            self.A = np.zeros((0, dyn.nx, dyn.nx))
            self.B = np.zeros((0, dyn.nx, dyn.nu))
        n = self.Z.shape[0]
        if n > N:
            self.Z, self.A, self.B = self.Z[:N], self.A[:N], self.B[:N]
        elif n < N:
            m = N - n
            self.Z = np.vstack([self.Z, np.full((m, nz), np.nan)])
            self.A = np.concatenate([self.A, np.zeros((m, dyn.nx, dyn.nx))])
            self.B = np.concatenate([self.B, np.zeros((m, dyn.nx, dyn.nu))])

    def __call__(self, X: np.ndarray, U: np.ndarray, rollout: bool = False):
        """X: [N+1, nx] (a rollout of U if ``rollout``), U: [N, nu] -> A: [N, nx, nx],
        B: [N, nx, nu]. Raises SimulationError if a step fails."""
        N = U.shape[0]
        rollout = rollout and X.shape[0] == N + 1
        self.last_secant = False
        if self.secant_updates > 0 and rollout:
            out = self._secant_step(X, U)
            if out is not None:
                self.last_secant = True
                return out
        return self.exact(X, U, rollout)

    def exact(self, X: np.ndarray, U: np.ndarray, rollout: bool = False):
        """Like a call, but exact partials (of the keypoints) whatever ``secant_updates`` says;
        secant updates, if any, count again from here. The solver calls it when a secant
        iteration found no step."""
        N = U.shape[0]
        rollout = rollout and X.shape[0] == N + 1
        self.last_secant = False
        A, B = self._exact(X, U, rollout)
        self._secant = None  # without a rollout there is no next state to update from
        if self.secant_updates > 0 and rollout:
            J = np.concatenate([A, B], axis=2)
            self._secant = (J, np.concatenate([X[:N], U], axis=1), X[1 : N + 1].copy(), 0)
        return A, B

    def _secant_step(self, X: np.ndarray, U: np.ndarray):
        """Broyden-updated partials, or None when exact ones are due."""
        N, nx = U.shape[0], self.dyn.nx
        if self._secant is None:
            return None
        J, Z0, F0, done = self._secant
        if done >= self.secant_updates or J.shape[0] != N:
            return None
        Z = np.concatenate([X[:N], U], axis=1)
        F = X[1 : N + 1]
        dZ, dF = Z - Z0, F - F0
        den = np.einsum("ki,ki->k", dZ, dZ)
        moved = den > 0.0
        if moved.any():
            r = dF[moved] - np.einsum("kij,kj->ki", J[moved], dZ[moved])
            J = J.copy()
            J[moved] += r[:, :, None] * dZ[moved][:, None, :] / den[moved][:, None, None]
        if not np.all(np.isfinite(J)):
            return None
        self._secant = (J, Z, F.copy(), done + 1)
        self.last_computed = 0
        return np.ascontiguousarray(J[:, :, :nx]), np.ascontiguousarray(J[:, :, nx:])

    def _exact(self, X: np.ndarray, U: np.ndarray, rollout: bool):
        N = U.shape[0]
        self._resize(N)
        keys = np.array(keypoints(self.dyn, X, N, self.interval, self.adaptive))
        Z = np.concatenate([X[:N], U], axis=1)
        with np.errstate(invalid="ignore"):
            moved = np.max(
                np.abs(Z[keys] - self.Z[keys]) / np.maximum(1.0, np.abs(Z[keys])), axis=1
            )
        moved[~np.isfinite(moved)] = np.inf
        todo = keys[moved > self.reuse_tolerance]
        if self.max_steps > 0 and todo.size > self.max_steps:
            order = np.argsort(-moved[moved > self.reuse_tolerance], kind="stable")
            todo = np.sort(todo[order[: self.max_steps]])
        if todo.size:
            nxt = X[todo + 1] if rollout else None
            A, B = _fd_or_ad(
                self.dyn,
                X[todo],
                U[todo],
                self.method,
                self.eps,
                self.threads,
                nxt,
                self.autodiff_workers,
                self.fd_forces,
            )
            self.A[todo], self.B[todo], self.Z[todo] = A, B, Z[todo]
        self.last_computed = int(todo.size)
        have = keys[np.isfinite(self.Z[keys, 0])]
        if have.size < keys.size:  # never computed and over the budget: nearest neighbour
            for k in keys[~np.isfinite(self.Z[keys, 0])]:
                j = have[np.argmin(np.abs(have - k))]
                self.A[k], self.B[k] = self.A[j], self.B[j]
        if len(keys) == N:
            return self.A.copy(), self.B.copy()
        return _interpolate(list(keys), self.A[keys], self.B[keys], N)


def _fd_or_ad(dyn, X, U, method, eps, threads, next_states, autodiff_workers=1, fd_forces=False):
    N = U.shape[0]
    if method is DerivativeMethod.AUTODIFF:
        workers = resolve_workers(autodiff_workers)
        if workers > 1 and N >= 2 * workers:
            try:
                return parallel_autodiff(dyn, X[:N], U, workers)
            except WorkersUnavailable:
                pass  # e.g. inside a daemonic process: serial
        return autodiff_serial(dyn, X[:N], U)
    return _finite_differences(
        dyn,
        X[:N],
        U,
        central=method is DerivativeMethod.CENTRAL,
        eps=eps,
        threads=threads,
        next_states=next_states,
        forces=fd_forces,
    )


def contact_signature(dyn: Dynamics, x: np.ndarray) -> frozenset:
    """The set of touching geometry pairs at x: [nx] (a geometry query, no contact solve)."""
    surfaces, points = dyn.contact_query(x)
    pairs = {frozenset((s.id_M(), s.id_N())) for s in surfaces}
    pairs |= {frozenset((p.id_A, p.id_B)) for p in points}
    return frozenset(pairs)


def contact_events(dyn: Dynamics, X: np.ndarray) -> set[int]:
    """Steps k and k+1 wherever the touching pairs differ between X[k] and X[k+1]. X: [T, nx]."""
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


def _finite_differences(
    dyn: Dynamics,
    X,
    U,
    central: bool,
    eps: float,
    threads: int,
    next_states: np.ndarray | None = None,
    forces: bool = False,
):
    if forces and dyn.force_path() is not None:
        return _force_differences(dyn, X, U, central, eps, threads, next_states)
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


def _force_differences(dyn: Dynamics, X, U, central, eps, threads, next_states):
    """f_x, f_u from nq + nv perturbed steps per time step instead of nx + nu.

    A discrete step depends on (v, u) only through the free-motion velocity
    ``v* = v + dt M(q)⁻¹ (B u − C(q, v) v + τ_g(q))`` (``Dynamics.force_path``), so with
    ``G_τ = ∂f/∂τ`` (differences over an applied generalized force τ, nv columns):

        f_u = G_τ B S,    f_v = G_τ (M/dt − ∂(C v)/∂v),    f_q by differences as usual,

    S = diag(1 where the command is inside its effort limit, else 0) (Drake clips). C v is
    quadratic in v, so its Jacobian from central differences of unit steps is exact up to
    rounding. The τ steps are the velocity steps the (x, u) scheme takes, as forces
    (h_τ,i = eps max(1, |v_i|) M_ii / dt). X: [N, nx], U: [N, nu] -> A: [N, nx, nx],
    B: [N, nx, nu]."""
    context, plant_context, port, Bact = dyn.force_path()
    plant = dyn.plant
    N, nq, nv, nx = U.shape[0], dyn.nq, dyn.nv, dyn.nx
    T = dyn.clip_to_limits(U) @ Bact.T  # [N, nv]
    W = np.empty((N, nv, nv))  # M/dt - d(Cv)/dv
    Ht = np.empty((N, nv))
    eye = np.eye(nv)
    for k in range(N):
        plant.SetPositionsAndVelocities(plant_context, X[k])
        M = plant.CalcMassMatrix(plant_context)
        v = X[k, nq:]
        dCv = np.empty((nv, nv))
        for i in range(nv):
            plant.SetVelocities(plant_context, v + eye[i])
            plus = plant.CalcBiasTerm(plant_context)
            plant.SetVelocities(plant_context, v - eye[i])
            dCv[:, i] = 0.5 * (plus - plant.CalcBiasTerm(plant_context))
        W[k] = M / dyn.dt - dCv
        Ht[k] = eps * np.maximum(1.0, np.abs(v)) * np.diag(M) / dyn.dt
    Hq = eps * np.maximum(1.0, np.abs(X[:, :nq]))  # [N, nq]
    # Perturbed points, row i of [N, nq + nv, ...]: q_i (i < nq) or τ_{i - nq} moved.
    Xp = np.repeat(X[:, None, :], nq + nv, axis=1)
    Tp = np.repeat(T[:, None, :], nq + nv, axis=1)
    Xp[:, np.arange(nq), np.arange(nq)] += Hq
    Tp[:, nq + np.arange(nv), np.arange(nv)] += Ht
    if central:
        Xm = np.repeat(X[:, None, :], nq + nv, axis=1)
        Tm = np.repeat(T[:, None, :], nq + nv, axis=1)
        Xm[:, np.arange(nq), np.arange(nq)] -= Hq
        Tm[:, nq + np.arange(nv), np.arange(nv)] -= Ht
        Xp, Tp = np.concatenate([Xp, Xm], axis=1), np.concatenate([Tp, Tm], axis=1)
    elif next_states is None:  # the unperturbed step too (a rollout's next states are it)
        Xp = np.concatenate([Xp, X[:, None, :]], axis=1)
        Tp = np.concatenate([Tp, T[:, None, :]], axis=1)
    rows = Xp.shape[1]
    out = _batch_eval(dyn, Xp.reshape(-1, nx), Tp.reshape(-1, nv), context, port, threads)
    out = out.reshape(N, rows, nx)
    H = np.concatenate([Hq, Ht], axis=1)[:, :, None]  # [N, nq + nv, 1]
    if central:
        D = (out[:, : nq + nv] - out[:, nq + nv :]) / (2.0 * H)
    else:
        base = out[:, -1] if next_states is None else np.asarray(next_states)
        D = (out[:, : nq + nv] - base[:, None, :]) / H
    D = np.transpose(D, (0, 2, 1))  # [N, nx, nq + nv]
    Gt = D[:, :, nq:]  # [N, nx, nv]
    inside = np.abs(U) < dyn.effort_limits  # [N, nu]
    A = np.empty((N, nx, nx))
    A[:, :, :nq] = D[:, :, :nq]
    A[:, :, nq:] = Gt @ W
    B = (Gt @ Bact) * inside[:, None, :]
    return A, B


def _batch_step(dyn: Dynamics, Z: np.ndarray, threads: int) -> np.ndarray:
    """Next states for many (x, u) pairs on C++ threads. Z: [M, nx+nu] -> [M, nx]."""
    port = dyn.diagram.get_input_port(dyn.scene.actuation_port)
    return _batch_eval(dyn, Z[:, : dyn.nx], Z[:, dyn.nx :], dyn.context, port, threads)


def _batch_eval(dyn: Dynamics, X, inputs, context, port, threads: int) -> np.ndarray:
    """Next states from X: [M, nx] with ``inputs``: [M, m] on the diagram input ``port`` (the
    other inputs as fixed in ``context``), on C++ threads -> [M, nx]."""
    M = X.shape[0]
    try:
        out = BatchEvalUniquePeriodicDiscreteUpdate(
            dyn.diagram,
            context,
            np.zeros((1, M)),
            np.asfortranarray(X.T),
            np.asfortranarray(inputs.T),
            num_time_steps=1,
            input_port_index=port.get_index(),
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
