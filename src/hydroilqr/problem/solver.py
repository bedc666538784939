"""The ``solver:`` section: the settings of iLQR and of how the partials are taken."""

from __future__ import annotations

import enum
from dataclasses import dataclass

from hydroilqr.problem.errors import ConfigError


class DerivativeMethod(enum.Enum):
    """How the partials f_x, f_u are taken (``solver.derivatives``; see derivatives.py).

    AUTODIFF: Drake AutoDiffXd through the discrete update (the paper's method); FORWARD and
    CENTRAL: one-sided and central finite differences. Defined here (derivatives.py
    re-exports it) so that validating ``solver.derivatives`` needs nothing from the layers
    that use it."""

    AUTODIFF = "autodiff"
    FORWARD = "forward"
    CENTRAL = "central"


DERIVATIVES = tuple(m.value for m in DerivativeMethod)  # the YAML/CLI spellings


@dataclass
class SolverConfig:
    max_iterations: int = 100
    derivatives: str = "central"  # a DerivativeMethod value: autodiff | forward | central
    fd_epsilon: float = 1e-6
    # Finite differences over applied generalized forces where the model allows (SAP, or TAMSI
    # without joint damping; no PD actuators: Dynamics.force_path): nq + nv perturbed steps per
    # time step instead of nx + nu, f_v and f_u then follow from f_τ
    # (derivatives._force_differences). Same partials up to rounding; pays with many actuators,
    # not with one (``hydroilqr bench`` compares them). Off: perturb (x, u) one coordinate at a
    # time.
    fd_forces: bool = False
    threads: int = 0  # 0 = all cores
    relative_cost_tolerance: float = 1e-4
    # The relative-cost-change test over this many iterations: a full step ends the solve when
    # the last N iterations together changed the cost by less than N x relative_cost_tolerance
    # (relative to the cost N iterations back); 1: that full step alone. More than 1: one
    # nearly flat full step right after large decreases (a poor local model on a contact-rich
    # landscape) does not end the solve.
    convergence_window: int = 1
    expected_decrease_tolerance: float = 1e-7
    line_search_factor: float = 0.5
    line_search_max_steps: int = 12
    # Start each line search one factor above the step the previous iteration accepted
    # (ε = min(1, ε_prev / line_search_factor), then ε·f, ...) instead of at ε = 1; after an
    # iteration without an accepted step, and in the first one, at 1. Saves the rejected
    # long trials of a solve whose accepted steps stay short; the start grows back by one
    # factor per iteration while the first trial is accepted. Off by default: it moves every
    # contact-rich solve into other basins.
    line_search_warm_start: bool = False
    # After a failed line search μ grows and the backward pass + line search run again, at
    # most this many times (and while μ <= regularization_max).
    line_search_retries: int = 20
    armijo: float = 1e-4
    regularization_init: float = 1e-6
    regularization_min: float = 1e-9
    regularization_max: float = 1e10
    regularization_factor: float = 10.0
    # After an accepted step shorter than this (line-search ε < short_step) for which longer
    # steps were rejected, μ grows by regularization_factor instead of shrinking (a trust
    # region that shrinks while the quadratic model only holds for short steps); after one
    # accepted as the first trial (line_search_warm_start) μ stays; 0 = always shrink after a
    # success.
    short_step: float = 0.1
    derivative_interval: int = 1  # >1: exact derivatives every k steps, interpolated between
    # With derivative_interval > 1: also exact at both sides of every change of the set of
    # touching geometry pairs (contact made or broken), interpolated only within a contact mode.
    derivative_adaptive: bool = False
    # AutoDiff in this many processes (the time steps split between them; each worker process
    # holds its own plant). 1 = serial in this process, as in the paper; 0 = one per core.
    autodiff_workers: int = 1
    # Line-search trials in this many processes: each round evaluates ε, ε·factor, ... side by
    # side and takes the first acceptable one in that order (the iterates of the serial search).
    # 1 = one trial after another; 0 = one per core. Shares the worker pool with autodiff.
    line_search_workers: int = 1
    # > 0: reuse a step's partials while its (x, u) has moved less than this (scaled max norm,
    # |Δz_i| / max(1, |z_i|)) since they were taken; 0 = recompute every iteration.
    derivative_reuse_tolerance: float = 0.0
    # > 0: after an iteration with exact partials, this many iterations update each step's
    # partials with a secant (Broyden rank-one) correction from the step's own change of
    # (x, u) and of its next state, both known from the rollouts, instead of differentiating;
    # then exact partials again. 0 = exact partials every iteration.
    derivative_secant_updates: int = 0


def validate_solver(sv: SolverConfig) -> None:
    """ConfigError naming the first invalid solver setting (also for settings built in Python)."""
    if sv.derivatives not in DERIVATIVES:
        raise ConfigError(
            f"solver.derivatives: expected one of {', '.join(DERIVATIVES)}, got {sv.derivatives!r}"
        )
    if sv.max_iterations < 0:
        raise ConfigError("solver.max_iterations: must be >= 0")
    if sv.fd_epsilon <= 0:
        raise ConfigError("solver.fd_epsilon: must be positive")
    for key in ("autodiff_workers", "line_search_workers"):
        if getattr(sv, key) < 0:
            raise ConfigError(f"solver.{key}: must be >= 0 (0 = one per core)")
    if sv.derivative_secant_updates < 0:
        raise ConfigError("solver.derivative_secant_updates: must be >= 0")
    if not sv.derivative_reuse_tolerance >= 0:
        raise ConfigError("solver.derivative_reuse_tolerance: must be >= 0")
    if sv.derivative_interval < 1:
        raise ConfigError("solver.derivative_interval: must be >= 1")
    if sv.convergence_window < 1:
        raise ConfigError(f"solver.convergence_window: must be >= 1, got {sv.convergence_window}")
    for name, ok, rule in (
        ("line_search_factor", 0 < sv.line_search_factor < 1, "between 0 and 1"),
        ("armijo", 0 <= sv.armijo < 1, "in [0, 1)"),
        ("line_search_max_steps", sv.line_search_max_steps >= 1, ">= 1"),
        ("line_search_retries", sv.line_search_retries >= 0, ">= 0"),
        ("regularization_init", sv.regularization_init >= 0, ">= 0"),
        ("regularization_min", sv.regularization_min >= 0, ">= 0"),
        ("regularization_max", sv.regularization_max > sv.regularization_min, "> its min"),
        ("regularization_factor", sv.regularization_factor > 1, "> 1"),
        ("short_step", 0 <= sv.short_step <= 1, "in [0, 1]"),
        ("relative_cost_tolerance", sv.relative_cost_tolerance >= 0, ">= 0"),
        ("expected_decrease_tolerance", sv.expected_decrease_tolerance >= 0, ">= 0"),
        ("threads", sv.threads >= 0, ">= 0 (0 = all cores)"),
    ):
        if not ok:
            raise ConfigError(f"solver.{name}: must be {rule}, got {getattr(sv, name)}")
