"""Iterative LQR (paper §III-B, eqs. 4-8) as small array kernels plus a driver.

Backward pass (eqs. 5-6), with the second-order dynamics terms dropped (iLQR, not DDP) and a
Levenberg-Marquardt term μ I added to Q_uu:

    Q_x  = l_x  + A_kᵀ V'_x            Q_u  = l_u  + B_kᵀ V'_x
    Q_xx = l_xx + A_kᵀ V'_xx A_k       Q_uu = l_uu + B_kᵀ V'_xx B_k + μ I
    Q_ux = B_kᵀ V'_xx A_k
    κ_k = Q_uu⁻¹ Q_u,   K_k = Q_uu⁻¹ Q_ux
    V_x  = Q_x − K_kᵀ Q_u − Q_uxᵀ κ_k + K_kᵀ Q_uu κ_k
    V_xx = Q_xx − K_kᵀ Q_ux − Q_uxᵀ K_k + K_kᵀ Q_uu K_k

(the last two equal eq. 6 when μ = 0 and stay consistent when μ > 0).

Forward pass (eq. 7): u_k = ū_k − ε κ_k − K_k (x_k − x̄_k). The predicted cost change of a
step of size ε is ΔJ(ε) = −ε Σ κᵀQ_u + ½ ε² Σ κᵀ Q_uu κ; a step is accepted when the actual
decrease is at least ``armijo`` times the predicted one (ε = 1, f, f², ... for
``line_search_factor`` f; with ``line_search_workers`` > 1 a round of them is evaluated side by
side in worker processes and the first acceptable one in that order is taken, so the iterates
do not depend on the number of workers). A rollout that fails (contact solver
not converging, non-finite state) is a rejected step. When no ε works, μ grows and the
backward pass is repeated; μ shrinks after a successful step, unless the step was shorter than
``short_step`` (the quadratic model held only for a short step: μ grows, a shrinking trust
region).

After convergence, u_k = ū_k − K_k (x_k − x̄_k) (eq. 8) is the local feedback policy.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from hydroilqr.model import workers
from hydroilqr.model.cost import QuadraticCost, Quadratization
from hydroilqr.model.derivatives import DerivativeMethod, Linearizer
from hydroilqr.model.plant import Dynamics, SimulationError
from hydroilqr.problem.config import ConfigError, SolverConfig, validate_solver
from hydroilqr.solver.solution import PHASES, Solution

# Iterations over which small progress from shortened steps counts as convergence.
STALL_WINDOW = 5
# Line-search trials (ε = 1, f, f², ...) along secant partials before exact ones are taken.
SECANT_TRIALS = 4


@dataclass
class BackwardPassResult:
    """K: [N, nu, nx], kappa: [N, nu], dV: (Σ κᵀQ_u, Σ κᵀQ_uu κ); ok=False if Q_uu not PD."""

    K: np.ndarray
    kappa: np.ndarray
    dV: tuple[float, float]
    ok: bool = True


def backward_pass(
    A: np.ndarray, B: np.ndarray, quad: Quadratization, mu: float
) -> BackwardPassResult:
    """A: [N, nx, nx], B: [N, nx, nu], quad: cost derivatives, mu: regularization ≥ 0."""
    with np.errstate(over="ignore", invalid="ignore"):
        return _backward_pass(A, B, quad, mu)


def _backward_pass(A, B, quad, mu) -> BackwardPassResult:
    N, nx, nu = B.shape
    K = np.zeros((N, nu, nx))
    kappa = np.zeros((N, nu))
    Vx = quad.lx[N].copy()
    Vxx = quad.lxx[N].copy()
    d1 = d2 = 0.0
    eye = mu * np.eye(nu)
    lx, lu, lxx, luu = quad.lx, quad.lu, quad.lxx, quad.luu
    cholesky, solve = np.linalg.cholesky, np.linalg.solve
    for k in range(N - 1, -1, -1):
        Ak, Bk = A[k], B[k]
        AtV = Ak.T @ Vxx
        BtV = Bk.T @ Vxx
        Qx = lx[k] + Ak.T @ Vx
        Qu = lu[k] + Bk.T @ Vx
        Qxx = lxx[k] + AtV @ Ak
        Quu = luu[k] + BtV @ Bk + eye
        Qux = BtV @ Ak
        Quu = 0.5 * (Quu + Quu.T)
        if not (np.isfinite(Quu).all() and np.isfinite(Qux).all() and np.isfinite(Qu).all()):
            # Overflowed cost-to-go (very stiff partials): treat like an indefinite Q_uu so
            # the caller raises the regularization instead of propagating NaN.
            return BackwardPassResult(K, kappa, (d1, d2), ok=False)
        try:
            cholesky(Quu)  # positive-definiteness test
        except np.linalg.LinAlgError:
            return BackwardPassResult(K, kappa, (d1, d2), ok=False)
        # A plain LAPACK solve: scipy's solve_triangular goes through OpenBLAS trsm, which
        # spawns threads even for 1x1 systems and took ~13 ms per call on a loaded 2-core
        # machine (the whole backward pass then dominated an iteration).
        rhs = np.empty((nu, nx + 1))
        rhs[:, 0] = Qu
        rhs[:, 1:] = Qux
        sol = solve(Quu, rhs)
        kap, Kk = sol[:, 0], sol[:, 1:]
        kappa[k], K[k] = kap, Kk
        QuuK = Quu @ Kk
        Vx = Qx - Kk.T @ Qu - Qux.T @ kap + QuuK.T @ kap
        KtQux = Kk.T @ Qux
        Vxx = Qxx - KtQux - KtQux.T + Kk.T @ QuuK
        Vxx = 0.5 * (Vxx + Vxx.T)
        d1 += kap @ Qu
        d2 += kap @ (Quu @ kap)
    return BackwardPassResult(K, kappa, (float(d1), float(d2)))


def expected_decrease(dV: tuple[float, float], eps: float) -> float:
    """Predicted cost *decrease* (positive) for step size eps."""
    return eps * dV[0] - 0.5 * eps**2 * dV[1]


@dataclass
class LineSearchResult:
    """One line search: ``accepted``; the last step size tried ``eps`` (the accepted one) and
    its predicted decrease ``expected``; the accepted trajectory X: [N+1, nx], U: [N, nu] and
    its cost J (None / inf without one); ``tried``: trials evaluated; ``late``: stopped by the
    deadline before a step was accepted."""

    accepted: bool
    eps: float
    expected: float
    X: np.ndarray | None
    U: np.ndarray | None
    J: float
    tried: int
    late: bool


def line_search(
    problem: Problem,
    X: np.ndarray,
    U: np.ndarray,
    J: float,
    K: np.ndarray,
    kappa: np.ndarray,
    dV: tuple[float, float],
    s: SolverConfig,
    deadline: float | None = None,
) -> LineSearchResult:
    """Forward passes (eq. 7) around X: [N+1, nx], U: [N, nu] of cost J, along the backward
    pass's K: [N, nu, nx], kappa: [N, nu] (predicted change ``dV``): ε = 1, f, f², ... (f =
    ``line_search_factor``, at most ``line_search_max_steps`` trials); the first trial whose
    actual decrease is at least ``armijo`` times the predicted one is accepted. Trials run a
    round at a time in the dynamics' line-search worker processes (1: serially); a rollout that
    fails is a rejected trial. No round starts after ``deadline`` (a perf_counter value)."""
    dyn, cost, t0 = problem.dynamics, problem.cost, problem.t0
    x0 = np.asarray(problem.x0, dtype=float)
    eps = expected = 0.0
    next_eps, tried = 1.0, 0
    while tried < s.line_search_max_steps:
        if deadline is not None and time.perf_counter() > deadline:
            return LineSearchResult(False, eps, expected, None, None, np.inf, tried, True)
        # trials side by side in worker processes (1: serial)
        width = workers.line_search_width(dyn, s.line_search_workers)
        n = min(width, s.line_search_max_steps - tried)
        trial_eps = []
        for _ in range(n):  # ε, ε·f, ε·f², ... by repeated products, as serially
            trial_eps.append(next_eps)
            next_eps *= s.line_search_factor
        for e, trial in zip(trial_eps, _trials(dyn, x0, U, X, K, kappa, trial_eps)):
            eps = e
            expected = expected_decrease(dV, eps)
            tried += 1
            if isinstance(trial, SimulationError):
                continue  # a failed rollout is a rejected step
            Xn, Un = trial
            with np.errstate(over="ignore", invalid="ignore"):
                Jn = cost.total(Xn, Un, t0)  # a blown-up trial is just rejected
            if np.isfinite(Jn) and J - Jn >= s.armijo * expected and Jn < J:
                return LineSearchResult(True, eps, expected, Xn, Un, Jn, tried, False)
    return LineSearchResult(False, eps, expected, None, None, np.inf, tried, False)


@dataclass
class IterationInfo:
    """What a callback sees after each iteration: its number (from 1), the cost after it, the
    accepted step ε (0: none), μ, its wall time and phase split (seconds), the predicted
    decrease, whether a step was accepted, and the current iterate X: [N+1, nx], U: [N, nu]
    (the solver's arrays: copy them to keep them). A callback that returns True stops the
    solve after this iteration (``reason == "callback"``)."""

    iteration: int
    cost: float
    eps: float
    mu: float
    seconds: float
    phases: dict[str, float]
    expected: float
    accepted: bool
    X: np.ndarray | None = None
    U: np.ndarray | None = None


@dataclass
class Problem:
    """An optimal control problem (4): dynamics, cost, x0, horizon start time t0."""

    dynamics: Dynamics
    cost: QuadraticCost
    x0: np.ndarray
    t0: float = 0.0


def check_finite(name: str, a: np.ndarray) -> None:
    """ValueError naming the first NaN or infinite entry of the array ``name``, if any."""
    if not np.isfinite(a).all():
        where = np.argwhere(~np.isfinite(a))[0].tolist()
        raise ValueError(
            f"{name} must be finite (no NaN or infinite entries): "
            f"{name}{where} is {a[tuple(where)]}"
        )


def callback_list(callbacks) -> list:
    """``callbacks`` as a list: None, one callable, or a list/tuple of callables. TypeError
    naming what was given otherwise."""
    if callbacks is None:
        return []
    if callable(callbacks):
        return [callbacks]
    items = None
    if not isinstance(callbacks, (str, bytes, dict)):
        try:
            items = list(callbacks)  # a list, tuple, or any other iterable of functions
        except TypeError:
            pass
    if items is None or not all(callable(c) for c in items):
        raise TypeError(
            "callbacks: expected a function f(info) -> bool or a list of them, got "
            f"{type(callbacks).__name__}"
            + (f" of {', '.join(sorted({type(c).__name__ for c in items}))}" if items else "")
        )
    return items


def solve(
    problem: Problem,
    U0: np.ndarray,
    settings: SolverConfig | None = None,
    callbacks: list[Callable[[IterationInfo], bool | None]] | None = None,
    max_iterations: int | None = None,
    final_gains: bool = True,
    linearizer: Linearizer | None = None,
    X0: np.ndarray | None = None,
    stop_on_interrupt: bool = False,
    deadline: float | None = None,
) -> Solution:
    """Runs iLQR from the initial control guess U0: [N, nu]. Returns a Solution.

    ``settings``: the solver settings (default ``SolverConfig()``, *not* a task's: to solve a
    task with its own settings use ``hydroilqr.solve(task, U0=..., x0=...)``).
    ``callbacks``: a function or a list of them, called with an ``IterationInfo`` after every
    iteration; one returning True stops the solve (``reason == "callback"``).
    Worker processes follow ``settings.autodiff_workers`` (through the default linearizer)
    and ``settings.line_search_workers``.

    ``linearizer`` computes the partials (default: one built from ``settings``); MPC passes
    its own to keep partials across updates. ``X0``: [N+1, nx], a rollout of U0 already
    computed (MPC: the previous plan's prediction); used instead of the initial rollout only
    when ``X0[0]`` equals x0 exactly, since then it *is* that rollout.
    ``stop_on_interrupt``: Ctrl+C ends the solve with the best trajectory so far (reason
    "interrupted") instead of raising KeyboardInterrupt.
    ``deadline``: a ``time.perf_counter()`` value; no line-search trial starts after it (the
    iteration then keeps its trajectory, with the gains of its backward pass). For real-time
    MPC: an update that runs late returns in time.
    """
    s = settings or SolverConfig()
    validate_solver(s)
    dyn, cost, x0, t0 = problem.dynamics, problem.cost, problem.x0, problem.t0
    x0 = np.asarray(x0, dtype=float)
    U0 = np.asarray(U0, dtype=float)
    if x0.shape != (dyn.nx,):
        raise ValueError(f"x0 must have shape [{dyn.nx}] (nx), got {x0.shape}")
    if U0.ndim != 2 or U0.shape[1] != dyn.nu or U0.shape[0] < 1:
        raise ValueError(f"U0 must have shape [N, {dyn.nu}] (nu = {dyn.nu}), got {U0.shape}")
    check_finite("x0", x0)
    check_finite("U0", U0)
    method = DerivativeMethod(s.derivatives)
    max_it = s.max_iterations if max_iterations is None else max_iterations
    callbacks = callback_list(callbacks)
    N = U0.shape[0]

    phases = {p: [] for p in PHASES}
    iter_seconds: list[float] = []
    t_start = time.perf_counter()
    U = np.array(U0, dtype=float)
    if X0 is not None and X0.shape == (N + 1, dyn.nx) and np.array_equal(X0[0], x0):
        X = np.array(X0, dtype=float)
    else:
        try:
            X = dyn.rollout(x0, U)
        except SimulationError as e:
            raise SimulationError(
                f"initial rollout failed: {e} (`hydroilqr check` reports initial overlaps)"
            ) from None
    J = cost.total(X, U, t0)
    if not np.isfinite(J):
        raise ConfigError(
            f"the cost of the initial guess is {J} on a finite trajectory: the cost weights "
            "(or R) are too large to evaluate in floating point"
        )
    rollout_time = time.perf_counter() - t_start
    costs = [J]
    mu = s.regularization_init
    K = np.zeros((N, dyn.nu, dyn.nx))
    kappa = np.zeros((N, dyn.nu))
    reason = "max_iterations"
    converged = False
    eps_hist, mu_hist = [], []
    accepted = False

    lin = linearizer or Linearizer.from_settings(dyn, s)
    # One pool serves both kinds of work: sized for the larger (made here, on first use).
    ad = getattr(lin, "autodiff_workers", 1)  # (a Linearizer stand-in: none)
    ad = ad if getattr(lin, "method", None) is DerivativeMethod.AUTODIFF else 1
    size = max(workers.resolve(ad), workers.resolve(s.line_search_workers))
    if size > 1 and hasattr(dyn, "task"):  # (duck-typed test dynamics: serial)
        workers.pool(dyn, size)
    derivative_steps: list[int] = []

    def partials(X, U):
        out = lin(X, U, rollout=True)
        derivative_steps.append(lin.last_computed)
        return out

    # Along secant partials a search tries only the longer steps: if none is accepted, exact
    # partials are cheaper than the rest of the search.
    s_secant = replace(s, line_search_max_steps=min(SECANT_TRIALS, s.line_search_max_steps))

    def exact_partials(X, U, A, B, ph):
        """Exact partials in place of secant ones (which found no step); the secant ones if
        differentiation fails (the search then goes on with them, μ growing)."""
        t = time.perf_counter()
        try:
            A, B = lin.exact(X, U, rollout=True)
            derivative_steps[-1] += lin.last_computed
        except SimulationError:
            lin.last_secant = False
        ph["derivatives"] += time.perf_counter() - t
        return A, B

    interrupted = False
    partials_current = False
    try:
        for it in range(max_it):
            # the first iteration's time includes the initial rollout (its "rollout" phase)
            t_it = time.perf_counter() if it else t_start
            ph = dict.fromkeys(PHASES, 0.0)
            if it == 0:
                ph["rollout"] = rollout_time
            t = time.perf_counter()
            partials_current = False
            try:
                A, B = partials(X, U)
            except SimulationError as e:
                reason = f"derivatives failed: {e}"
                break
            quad = cost.quadratize(X, U, t0)
            partials_current = True  # A, B, quad are around the current (X, U)
            ph["derivatives"] = time.perf_counter() - t

            accepted = False
            eps = 0.0
            expected = 0.0
            expected_full = np.inf  # stays so if no backward pass succeeds (Q_uu never PD)
            searches = 0
            late = False  # the deadline passed before a step was found
            raised = False  # μ was raised in this iteration (Q_uu indefinite or a failed search)
            first_gains = None  # (K, kappa) of the least-regularized pass around this X
            while True:
                t = time.perf_counter()
                bp = backward_pass(A, B, quad, mu)
                ph["backward_pass"] += time.perf_counter() - t
                if not bp.ok and getattr(lin, "last_secant", False):
                    A, B = exact_partials(X, U, A, B, ph)  # secant partials failed: exact ones
                    continue
                if not bp.ok:
                    mu, raised = _increase(mu, s), True
                    if mu > s.regularization_max:
                        break
                    continue
                K, kappa = bp.K, bp.kappa
                if first_gains is None:
                    first_gains = (K, kappa)
                expected_full = expected_decrease(bp.dV, 1.0)
                if expected_full < s.expected_decrease_tolerance * max(1.0, abs(J)) and getattr(
                    lin, "last_secant", False
                ):
                    A, B = exact_partials(X, U, A, B, ph)  # stationary by exact partials?
                    first_gains = None
                    continue
                if expected_full < s.expected_decrease_tolerance * max(1.0, abs(J)):
                    # Stationary only if μ was not raised to get here: a large μ makes any
                    # predicted decrease small.
                    expected = expected_full
                    break
                t = time.perf_counter()
                secant = getattr(lin, "last_secant", False)
                s_ls = s_secant if secant else s
                ls = line_search(problem, X, U, J, K, kappa, bp.dV, s_ls, deadline)
                ph["line_search"] += time.perf_counter() - t
                if ls.tried:
                    eps, expected = ls.eps, ls.expected
                accepted, late = ls.accepted, ls.late
                if accepted:
                    Xn, Un, Jn = ls.X, ls.U, ls.J
                if accepted or late:
                    break
                if getattr(lin, "last_secant", False):
                    # no step along secant partials: the same μ again with exact ones
                    A, B = exact_partials(X, U, A, B, ph)
                    first_gains = None
                    continue
                searches += 1
                mu, raised = _increase(mu, s), True
                if mu > s.regularization_max or searches > s.line_search_retries:
                    break
            if not accepted and first_gains is not None:
                # No step: the gains kept are those around this X at the iteration's own μ, not
                # those of the most-regularized retry (which have almost no feedback). With
                # final_gains they are recomputed at the end at the smallest workable μ.
                K, kappa = first_gains

            seconds = time.perf_counter() - t_it
            iter_seconds.append(seconds)
            for p in PHASES:
                phases[p].append(ph[p])
            if accepted:
                rel = (J - Jn) / max(abs(J), 1e-12)
                X, U, J = Xn, Un, Jn
                partials_current = False
                if eps < s.short_step:
                    # The quadratic model only held for a short step: regularize more (a trust
                    # region that shrinks while the model is poor) instead of less.
                    mu = min(
                        s.regularization_max,
                        max(mu, s.regularization_min) * s.regularization_factor,
                    )
                else:
                    mu = max(s.regularization_min, mu / s.regularization_factor)
            costs.append(J)
            eps_hist.append(eps if accepted else 0.0)
            mu_hist.append(mu)
            info = IterationInfo(
                it + 1, J, eps if accepted else 0.0, mu, seconds, ph, expected, accepted, X, U
            )
            # every callback sees every iteration; only True (Python's or numpy's) stops, not any
            # truthy return value (e.g. a progress bar's update() returns True-ish counts)
            stop = [_is_true(cb(info)) for cb in callbacks]
            if not accepted:
                if late:
                    reason = "deadline"
                elif (
                    expected_full < s.expected_decrease_tolerance * max(1.0, abs(J))
                    and bp.ok
                    and not raised
                ):
                    reason, converged = "expected_decrease", True
                elif not bp.ok:
                    # Q_uu stayed indefinite up to solver.regularization_max: no descent step.
                    reason = "regularization_max"
                else:
                    reason = "line_search_failed"
                    # A local minimum at the resolution the dynamics allow: report honestly.
                break
            if any(stop):
                reason = "callback"
                break
            # Small progress from one shortened step is not convergence (the local model may just
            # be poor there), so a short step counts only when the last few iterations together
            # made little progress: the solver has stalled in a local minimum.
            if rel < s.relative_cost_tolerance and eps >= 1.0:
                reason, converged = "relative_cost_change", True
                break
            w = STALL_WINDOW
            if (
                len(costs) > w
                and (costs[-w - 1] - J) / max(abs(J), 1e-12) < w * s.relative_cost_tolerance
            ):
                reason, converged = "stalled", True
                break
    except KeyboardInterrupt:
        if not stop_on_interrupt:
            raise
        # Ctrl+C: keep the best trajectory so far, with its statistics made consistent (an
        # iteration cut off before its bookkeeping is recorded only if its step was taken).
        interrupted, converged, reason = True, False, "interrupted"
        n = min(len(iter_seconds), len(costs) - 1, len(eps_hist), len(mu_hist))
        n = min([n] + [len(v) for v in phases.values()])
        for lst in (iter_seconds, eps_hist, mu_hist, *phases.values()):
            del lst[n:]
        del costs[n + 1 :]
        if J != costs[-1]:
            costs.append(J)
            iter_seconds.append(0.0)
            eps_hist.append(0.0)
            mu_hist.append(mu)
            for v in phases.values():
                v.append(0.0)

    gains_mu = None
    if final_gains and not interrupted:
        # Gains of eq. (8) around the *final* trajectory, regularized only as much as Q_uu
        # needs: the solver's μ at the end can be large (a run of short steps raises it), and
        # gains at μ = 1e3 are ~0, no feedback at all. After an accepted step the last
        # partials were around the previous trajectory (with no iterations, there were none).
        t = time.perf_counter()
        try:
            if not partials_current:
                A, B = partials(X, U)
                quad = cost.quadratize(X, U, t0)
            gains = feedback_gains(A, B, quad, s)
            if gains is not None:
                K, kappa, gains_mu = gains
        except SimulationError:
            pass
        except KeyboardInterrupt:
            if not stop_on_interrupt:
                raise
            # the trajectory is complete; its gains are the last pass's
            reason, converged = "interrupted", False
        elapsed = time.perf_counter() - t
        if iter_seconds:
            phases["derivatives"][-1] += elapsed
            iter_seconds[-1] += elapsed
    return Solution(
        X=X,
        U=U,
        K=K,
        kappa=kappa,
        t=cost.times(N, t0),
        costs=np.array(costs),
        iteration_seconds=iter_seconds,
        phase_seconds=phases,
        converged=converged,
        reason=reason,
        derivatives=method.value,
        eps=eps_hist,
        mu=mu_hist,
        extra={"derivative_steps": derivative_steps, "gains_mu": gains_mu},
    )


class FeedbackGains(NamedTuple):
    """K: [N, nu, nx], kappa: [N, nu] and the regularization μ they were computed at."""

    K: np.ndarray
    kappa: np.ndarray
    mu: float


def feedback_gains(
    A: np.ndarray, B: np.ndarray, quad: Quadratization, s: SolverConfig
) -> FeedbackGains | None:
    """The gains of eq. (8) around a trajectory: the backward pass at the smallest μ (from
    ``regularization_min``, raised as ``_increase`` does) for which Q_uu is positive definite.
    A: [N, nx, nx], B: [N, nx, nu]. Returns FeedbackGains (unpacks as (K, kappa, μ)), or None
    if Q_uu is indefinite up to ``regularization_max``."""
    mu = s.regularization_min
    while mu <= s.regularization_max:
        bp = backward_pass(A, B, quad, mu)
        if bp.ok:
            return FeedbackGains(bp.K, bp.kappa, mu)
        mu = _increase(mu, s)
    return None


def _is_true(value) -> bool:
    return value is True or (isinstance(value, np.bool_) and bool(value))


def _trials(dyn, x0, U, X, K, kappa, eps_list):
    """Closed-loop rollouts (eq. 7) for each ε: (X, U) or the SimulationError of a failed one."""
    if len(eps_list) > 1:
        try:
            return workers.closed_loop_rollouts(dyn, x0, U, X, K, kappa, eps_list)
        except workers.Unavailable:
            pass
    out = []
    for e in eps_list:  # serial: one ε, or the pool stopped taking work
        try:
            out.append(dyn.closed_loop_rollout(x0, U, X, K, kappa, e))
        except SimulationError as err:
            out.append(err)
    return out


# After a failure μ grows to at least this, whatever regularization_min is: from a tiny μ
# (1e-9) the factor alone would take many rejected backward passes and line searches.
MU_RESTART = 1e-6


def _increase(mu: float, s: SolverConfig) -> float:
    return max(mu * s.regularization_factor, MU_RESTART)
