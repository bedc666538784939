"""The iLQR iteration (paper §III-B), built from the kernels of ``ilqr``:

    roll out U0 -> X, J
    repeat:
        linearize: A, B (dynamics), quadratize the cost around (X, U)
        backward pass at μ (raising μ while Q_uu is indefinite)       (eqs. 5-6)
        line search along K, κ (raising μ and retrying if it fails)    (eq. 7)
        accept the step, update μ                                      (regularization)
        stop if a test holds                                           (stopping)
    feedback gains around the final trajectory                         (eq. 8)

Ctrl+C ends the loop with the best trajectory so far (``interrupt``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from hydroilqr.model import workers
from hydroilqr.model.derivatives import DerivativeMethod, Linearizer
from hydroilqr.model.plant import SimulationError
from hydroilqr.model.task import Problem, check_finite
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.solver import SolverConfig
from hydroilqr.solver import regularization, stopping
from hydroilqr.solver.ilqr import (
    IterationInfo,
    backward_pass,
    expected_decrease,
    feedback_gains,
    line_search,
)
from hydroilqr.solver.solution import PHASES, Solution

# Line-search trials (ε = 1, f, f², ...) along secant partials before exact ones are taken:
# if none of the longer steps is accepted, exact partials are cheaper than the rest.
SECANT_TRIALS = 4


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


@dataclass
class State:
    """The solve so far: the current trajectory X: [N+1, nx], U: [N, nu] of cost J, the gains
    K: [N, nu, nx], kappa: [N, nu], μ, the partials around (X, U) if ``partials_current``,
    and the per-iteration history (costs, seconds, phases, ε, μ, steps differentiated)."""

    problem: Problem
    s: SolverConfig
    lin: Linearizer
    X: np.ndarray
    U: np.ndarray
    J: float
    K: np.ndarray
    kappa: np.ndarray
    mu: float
    rollout_time: float
    t_start: float
    reason: str = "max_iterations"
    converged: bool = False
    interrupted: bool = False
    partials_current: bool = False
    A: np.ndarray | None = None
    B: np.ndarray | None = None
    quad: object = None
    costs: list = field(default_factory=list)
    iter_seconds: list = field(default_factory=list)
    phases: dict = field(default_factory=lambda: {p: [] for p in PHASES})
    eps_hist: list = field(default_factory=list)
    mu_hist: list = field(default_factory=list)
    derivative_steps: list = field(default_factory=list)


@dataclass
class Step:
    """One iteration's descent: whether a step was accepted (its Xn, Un, Jn, ε), the
    predicted decrease, whether the deadline cut the search, the last backward pass's
    success ``pd``, its full-step prediction, whether μ was raised, and whether a longer step
    than the accepted one was tried and rejected in the search that accepted it
    (``shortened``; earlier searches of the iteration, at a smaller μ, do not count)."""

    accepted: bool = False
    eps: float = 0.0
    shortened: bool = False
    expected: float = 0.0
    expected_full: float = np.inf  # stays so if no backward pass succeeds (Q_uu never PD)
    late: bool = False
    raised: bool = False
    pd: bool = True
    Xn: np.ndarray | None = None
    Un: np.ndarray | None = None
    Jn: float = np.inf


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
    s = settings or SolverConfig()  # (checked where it was taken in: a task, or solve())
    U0 = _checked_start(problem, U0)
    max_it = s.max_iterations if max_iterations is None else max_iterations
    callbacks = callback_list(callbacks)
    st = start(problem, U0, X0, s, linearizer)
    try:
        for it in range(max_it):
            if iterate(st, it, callbacks, deadline):
                break
    except KeyboardInterrupt:
        if not stop_on_interrupt:
            raise
        repair_after_interrupt(st)
    gains_mu = None
    if final_gains and not st.interrupted:
        gains_mu = final_feedback_gains(st, stop_on_interrupt)
    return solution(st, gains_mu)


def _checked_start(problem: Problem, U0: np.ndarray) -> np.ndarray:
    """U0 as a float array; ValueError for a wrong shape or a non-finite x0 or U0."""
    dyn = problem.dynamics
    x0 = np.asarray(problem.x0, dtype=float)
    U0 = np.asarray(U0, dtype=float)
    if x0.shape != (dyn.nx,):
        raise ValueError(f"x0 must have shape [{dyn.nx}] (nx), got {x0.shape}")
    if U0.ndim != 2 or U0.shape[1] != dyn.nu or U0.shape[0] < 1:
        raise ValueError(f"U0 must have shape [N, {dyn.nu}] (nu = {dyn.nu}), got {U0.shape}")
    check_finite("x0", x0)
    check_finite("U0", U0)
    return U0


def start(problem: Problem, U0, X0, s: SolverConfig, linearizer) -> State:
    """The initial rollout (or ``X0`` if it is one) and its cost; the linearizer and the
    worker processes."""
    dyn, cost, t0 = problem.dynamics, problem.cost, problem.t0
    x0 = np.asarray(problem.x0, dtype=float)
    N = U0.shape[0]
    t_start = time.perf_counter()
    U = np.array(U0, dtype=float)
    if X0 is not None and X0.shape == (N + 1, dyn.nx) and np.array_equal(X0[0], x0):
        X = np.array(X0, dtype=float)
    else:
        try:
            X = dyn.rollout(x0, U)
        except SimulationError as e:
            raise SimulationError(
                f"the rollout of the initial guess failed: {e} (a guess that drives the "
                "simulation to blow up, or an initial overlap: `hydroilqr check` reports both)"
            ) from None
    J = cost.total(X, U, t0)
    if not np.isfinite(J):
        raise ConfigError(
            f"the cost of the initial guess is {J} on a finite trajectory: the cost weights "
            "(or R) are too large to evaluate in floating point"
        )
    rollout_time = time.perf_counter() - t_start
    lin = linearizer or Linearizer.from_settings(dyn, s)
    _start_workers(dyn, lin, s)
    return State(
        problem,
        s,
        lin,
        X,
        U,
        J,
        np.zeros((N, dyn.nu, dyn.nx)),
        np.zeros((N, dyn.nu)),
        s.regularization_init,
        rollout_time,
        t_start,
        costs=[J],
    )


def _start_workers(dyn, lin, s: SolverConfig) -> None:
    """One pool serves both kinds of work: sized for the larger (made here, on first use)."""
    ad = getattr(lin, "autodiff_workers", 1)  # (a Linearizer stand-in: none)
    ad = ad if getattr(lin, "method", None) is DerivativeMethod.AUTODIFF else 1
    size = max(workers.resolve(ad), workers.resolve(s.line_search_workers))
    if size > 1 and hasattr(dyn, "spec"):  # (duck-typed test dynamics: serial)
        workers.pool(dyn, size)


def iterate(st: State, it: int, callbacks: list, deadline: float | None) -> bool:
    """One iLQR iteration: linearize, backward pass and line search, accept, record, test.
    Returns True when the solve stops (``st.reason`` says why)."""
    # the first iteration's time includes the initial rollout (its "rollout" phase)
    t_it = time.perf_counter() if it else st.t_start
    ph = dict.fromkeys(PHASES, 0.0)
    if it == 0:
        ph["rollout"] = st.rollout_time
    if not linearize(st, ph):
        return True
    step = descend(st, ph, deadline)
    seconds = time.perf_counter() - t_it
    st.iter_seconds.append(seconds)
    for p in PHASES:
        st.phases[p].append(ph[p])
    rel = accept(st, step) if step.accepted else None
    st.costs.append(st.J)
    st.eps_hist.append(step.eps if step.accepted else 0.0)
    st.mu_hist.append(st.mu)
    info = IterationInfo(
        it + 1,
        st.J,
        step.eps if step.accepted else 0.0,
        st.mu,
        seconds,
        ph,
        step.expected,
        step.accepted,
        st.X,
        st.U,
    )
    # every callback sees every iteration; only True (Python's or numpy's) stops, not any
    # truthy return value (e.g. a progress bar's update() returns True-ish counts)
    stop = [_is_true(cb(info)) for cb in callbacks]
    return stop_test(st, step, rel, any(stop))


def linearize(st: State, ph: dict) -> bool:
    """Partials A, B and the cost's quadratization around (X, U) into ``st``; False (and the
    reason set) if the derivatives fail."""
    t = time.perf_counter()
    st.partials_current = False
    try:
        st.A, st.B = _partials(st, st.X, st.U)
    except SimulationError as e:
        st.reason = f"derivatives failed: {e}"
        return False
    st.quad = st.problem.cost.quadratize(st.X, st.U, st.problem.t0)
    st.partials_current = True  # A, B, quad are around the current (X, U)
    ph["derivatives"] = time.perf_counter() - t
    return True


def _partials(st: State, X, U):
    out = st.lin(X, U, rollout=True)
    st.derivative_steps.append(st.lin.last_computed)
    return out


def _secant(st: State) -> bool:
    """The current partials are secant (Broyden) updates, not exact ones."""
    return bool(getattr(st.lin, "last_secant", False))


def _exact_partials(st: State, ph: dict) -> None:
    """Exact partials in place of secant ones (which failed or found no step); the secant
    ones stay if differentiation fails (the search then goes on with them, μ growing)."""
    t = time.perf_counter()
    try:
        st.A, st.B = st.lin.exact(st.X, st.U, rollout=True)
        st.derivative_steps[-1] += st.lin.last_computed
    except SimulationError:
        st.lin.last_secant = False
    ph["derivatives"] += time.perf_counter() - t


def first_step(st: State) -> float:
    """The line search's first ε: 1, or with ``line_search_warm_start`` one factor above the
    step the previous iteration accepted (1 after an iteration that accepted none)."""
    s = st.s
    if not s.line_search_warm_start or not st.eps_hist or st.eps_hist[-1] <= 0:
        return 1.0
    return min(1.0, st.eps_hist[-1] / s.line_search_factor)


def descend(st: State, ph: dict, deadline: float | None) -> Step:
    """Backward pass and line search, raising μ after an indefinite Q_uu or a failed search
    (at most ``line_search_retries`` times, μ up to ``regularization_max``). Along secant
    partials, a failed pass, an apparently stationary point or a failed (shortened) search
    is retried at the same μ with exact partials first. Leaves the gains of the
    least-regularized pass in ``st`` if no step was accepted."""
    s = st.s
    step = Step()
    searches = 0
    first_gains = None  # (K, kappa) of the least-regularized pass around this X
    while True:
        t = time.perf_counter()
        bp = backward_pass(st.A, st.B, st.quad, st.mu)
        ph["backward_pass"] += time.perf_counter() - t
        step.pd = bp.ok
        if not bp.ok and _secant(st):
            _exact_partials(st, ph)
            continue
        if not bp.ok:
            st.mu, step.raised = regularization.increase(st.mu, s), True
            if regularization.too_large(st.mu, s):
                break
            continue
        st.K, st.kappa = bp.K, bp.kappa
        if first_gains is None:
            first_gains = (st.K, st.kappa)
        step.expected_full = expected_decrease(bp.dV, 1.0)
        if stopping.stationary(step.expected_full, st.J, s) and _secant(st):
            _exact_partials(st, ph)  # stationary by exact partials too?
            first_gains = None
            continue
        if stopping.stationary(step.expected_full, st.J, s):
            # Stationary only if μ was not raised to get here: a large μ makes any
            # predicted decrease small.
            step.expected = step.expected_full
            break
        t = time.perf_counter()
        # along secant partials only the longer steps (if none is accepted, exact partials
        # are cheaper than the rest of the search)
        s_ls = replace(s, line_search_max_steps=min(SECANT_TRIALS, s.line_search_max_steps))
        s_ls = s_ls if _secant(st) else s
        ls = line_search(
            st.problem, st.X, st.U, st.J, st.K, st.kappa, bp.dV, s_ls, deadline, first_step(st)
        )
        ph["line_search"] += time.perf_counter() - t
        if ls.tried:
            step.eps, step.expected = ls.eps, ls.expected
        step.accepted, step.late = ls.accepted, ls.late
        if step.accepted:
            step.Xn, step.Un, step.Jn = ls.X, ls.U, ls.J
            step.shortened = ls.tried > 1
        if step.accepted or step.late:
            break
        if _secant(st):  # no step along secant partials: the same μ again with exact ones
            _exact_partials(st, ph)
            first_gains = None
            continue
        searches += 1
        st.mu, step.raised = regularization.increase(st.mu, s), True
        if regularization.too_large(st.mu, s) or searches > s.line_search_retries:
            break
    if not step.accepted and first_gains is not None:
        # No step: the gains kept are those around this X at the iteration's own μ, not
        # those of the most-regularized retry (which have almost no feedback). With
        # final_gains they are recomputed at the end at the smallest workable μ.
        st.K, st.kappa = first_gains
    return step


def accept(st: State, step: Step) -> float:
    """Takes the step and updates μ; returns the relative cost decrease."""
    rel = (st.J - step.Jn) / max(abs(st.J), 1e-12)
    st.X, st.U, st.J = step.Xn, step.Un, step.Jn
    st.partials_current = False
    st.mu = regularization.after_step(st.mu, step.eps, st.s, step.shortened)
    return rel


def stop_test(st: State, step: Step, rel: float | None, callback_stop: bool) -> bool:
    """Whether the solve stops after this iteration; sets ``st.reason`` and
    ``st.converged`` (a convergence test held) when it does."""
    s = st.s
    if not step.accepted:
        stationary = stopping.stationary(step.expected_full, st.J, s)
        st.reason, st.converged = stopping.no_step_reason(
            step.late, stationary and step.pd and not step.raised, step.pd
        )
        return True
    if callback_stop:
        st.reason = "callback"
        return True
    if stopping.small_full_step(rel, step.eps, s, st.costs):
        st.reason, st.converged = "relative_cost_change", True
        return True
    if stopping.stalled(st.costs, st.J, s):
        st.reason, st.converged = "stalled", True
        return True
    return False


def repair_after_interrupt(st: State) -> None:
    """Ctrl+C: keep the best trajectory so far, with its statistics made consistent (an
    iteration cut off before its bookkeeping is recorded only if its step was taken)."""
    st.interrupted, st.converged, st.reason = True, False, "interrupted"
    n = min(len(st.iter_seconds), len(st.costs) - 1, len(st.eps_hist), len(st.mu_hist))
    n = min([n] + [len(v) for v in st.phases.values()])
    for lst in (st.iter_seconds, st.eps_hist, st.mu_hist, *st.phases.values()):
        del lst[n:]
    del st.costs[n + 1 :]
    if st.J != st.costs[-1]:
        st.costs.append(st.J)
        st.iter_seconds.append(0.0)
        st.eps_hist.append(0.0)
        st.mu_hist.append(st.mu)
        for v in st.phases.values():
            v.append(0.0)


def final_feedback_gains(st: State, stop_on_interrupt: bool) -> float | None:
    """Gains of eq. (8) around the *final* trajectory, regularized only as much as Q_uu
    needs: the solver's μ at the end can be large (a run of short steps raises it), and gains
    at μ = 1e3 are ~0, no feedback at all. After an accepted step the last partials were
    around the previous trajectory (with no iterations, there were none). Returns the μ of
    the gains (None: the last pass's kept)."""
    gains_mu = None
    t = time.perf_counter()
    try:
        if not st.partials_current:
            st.A, st.B = _partials(st, st.X, st.U)
            st.quad = st.problem.cost.quadratize(st.X, st.U, st.problem.t0)
        gains = feedback_gains(st.A, st.B, st.quad, st.s)
        if gains is not None:
            st.K, st.kappa, gains_mu = gains
    except SimulationError:
        pass
    except KeyboardInterrupt:
        if not stop_on_interrupt:
            raise
        # the trajectory is complete; its gains are the last pass's
        st.reason, st.converged = "interrupted", False
    elapsed = time.perf_counter() - t
    if st.iter_seconds:
        st.phases["derivatives"][-1] += elapsed
        st.iter_seconds[-1] += elapsed
    return gains_mu


def solution(st: State, gains_mu: float | None) -> Solution:
    """The Solution of the solve so far, with its status (``stopping.status``)."""
    status = stopping.status(st.reason, st.costs)
    return Solution(
        X=st.X,
        U=st.U,
        K=st.K,
        kappa=st.kappa,
        t=st.problem.cost.times(st.U.shape[0], st.problem.t0),
        costs=np.array(st.costs),
        iteration_seconds=st.iter_seconds,
        phase_seconds=st.phases,
        converged=st.converged and stopping.is_converged(status),
        reason=st.reason,
        derivatives=DerivativeMethod(st.s.derivatives).value,
        status=status,
        eps=st.eps_hist,
        mu=st.mu_hist,
        extra={"derivative_steps": st.derivative_steps, "gains_mu": gains_mu},
    )


def _is_true(value) -> bool:
    return value is True or (isinstance(value, np.bool_) and bool(value))
