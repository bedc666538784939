"""The schedule of the Levenberg-Marquardt term μ I added to Q_uu in the backward pass.

μ grows (``increase``) when Q_uu is not positive definite or no step size decreases the cost;
after an accepted step it shrinks, unless the step was shorter than ``short_step`` and longer
ones were rejected: the quadratic model then held only for a short step, so μ grows instead (a
trust region that shrinks while the model is poor; ``after_step``). A short step accepted as
the first trial (a line search warm-started below 1) says nothing for or against the model: μ
stays.
"""

from __future__ import annotations

from hydroilqr.problem.solver import SolverConfig

# After a failure μ grows to at least this, whatever regularization_min is: from a tiny μ
# (1e-9) the factor alone would take many rejected backward passes and line searches.
MU_RESTART = 1e-6


def increase(mu: float, s: SolverConfig) -> float:
    """μ after a failed backward pass or line search."""
    return max(mu * s.regularization_factor, MU_RESTART)


def after_step(mu: float, eps: float, s: SolverConfig, shortened: bool = True) -> float:
    """μ after an accepted step of size ``eps``; ``shortened``: longer steps were tried and
    rejected in its line search."""
    if eps < s.short_step and not shortened:
        return mu  # accepted at the first trial: no evidence on the model either way
    if eps < s.short_step:
        # The quadratic model only held for a short step: regularize more (a trust region
        # that shrinks while the model is poor) instead of less.
        return min(s.regularization_max, max(mu, s.regularization_min) * s.regularization_factor)
    return max(s.regularization_min, mu / s.regularization_factor)


def too_large(mu: float, s: SolverConfig) -> bool:
    """μ is past ``regularization_max``: the backward pass gives no usable step."""
    return mu > s.regularization_max
