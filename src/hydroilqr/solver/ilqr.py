"""Iterative LQR (paper §III-B, eqs. 4-8) as small array kernels; the iteration that uses
them is ``loop.solve`` (also importable from here as ``solve``).

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
``line_search_factor`` f, or from one factor above the last accepted step with
``line_search_warm_start``; with ``line_search_workers`` > 1 a round of them is evaluated side by
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
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.linalg import lapack

from hydroilqr.model import workers
from hydroilqr.model.cost import Quadratization
from hydroilqr.model.plant import SimulationError
from hydroilqr.model.task import Problem
from hydroilqr.problem.solver import SolverConfig
from hydroilqr.solver import regularization


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
    potrf, solve, isfinite = lapack.dpotrf, np.linalg.solve, np.isfinite
    G = np.empty((nu, nu + 1 + nx))  # [Q_uu | Q_u | Q_ux]: one finiteness test, and the rhs
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
        G[:, :nu] = Quu
        G[:, nu] = Qu
        G[:, nu + 1 :] = Qux
        if not isfinite(G).all():
            # Overflowed cost-to-go (very stiff partials): treat like an indefinite Q_uu so
            # the caller raises the regularization instead of propagating NaN.
            return BackwardPassResult(K, kappa, (d1, d2), ok=False)
        # Positive-definiteness test: LAPACK's Cholesky called directly (info > 0: not PD);
        # numpy's cholesky wrapper costs several times the factorization of a small Q_uu.
        if potrf(Quu, lower=1, clean=0)[1] != 0:
            return BackwardPassResult(K, kappa, (d1, d2), ok=False)
        # numpy's LAPACK solve, not scipy's: scipy's solve_triangular goes through OpenBLAS
        # trsm, which spawns threads even for 1x1 systems (slow on a loaded machine), and
        # scipy's own gesv (another OpenBLAS build) differs in the last bits.
        sol = solve(Quu, G[:, nu:])
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
    first: float = 1.0,
) -> LineSearchResult:
    """Forward passes (eq. 7) around X: [N+1, nx], U: [N, nu] of cost J, along the backward
    pass's K: [N, nu, nx], kappa: [N, nu] (predicted change ``dV``): ε = first, first·f,
    first·f², ... (f = ``line_search_factor``, ``first`` in (0, 1], at most
    ``line_search_max_steps`` trials); the first trial whose
    actual decrease is at least ``armijo`` times the predicted one is accepted. Trials run a
    round at a time in the dynamics' line-search worker processes (1: serially); a rollout that
    fails is a rejected trial. No round starts after ``deadline`` (a perf_counter value)."""
    dyn, cost, t0 = problem.dynamics, problem.cost, problem.t0
    x0 = np.asarray(problem.x0, dtype=float)
    eps = expected = 0.0
    next_eps, tried = first, 0
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


class FeedbackGains(NamedTuple):
    """K: [N, nu, nx], kappa: [N, nu] and the regularization μ they were computed at."""

    K: np.ndarray
    kappa: np.ndarray
    mu: float


def feedback_gains(
    A: np.ndarray, B: np.ndarray, quad: Quadratization, s: SolverConfig
) -> FeedbackGains | None:
    """The gains of eq. (8) around a trajectory: the backward pass at the smallest μ (from
    ``regularization_min``, raised as ``regularization.increase`` does) for which Q_uu is
    positive definite.
    A: [N, nx, nx], B: [N, nx, nu]. Returns FeedbackGains (unpacks as (K, kappa, μ)), or None
    if Q_uu is indefinite up to ``regularization_max``."""
    mu = s.regularization_min
    while mu <= s.regularization_max:
        bp = backward_pass(A, B, quad, mu)
        if bp.ok:
            return FeedbackGains(bp.K, bp.kappa, mu)
        mu = regularization.increase(mu, s)
    return None


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
