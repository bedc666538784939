"""When the iLQR loop stops, and what the stop means (``Solution.status``).

The loop's *reason* says which test ended it (``expected_decrease``, ``relative_cost_change``,
``stalled``, ``max_iterations``, ``line_search_failed``, ``regularization_max``,
``derivatives failed: ...``, ``deadline``, ``callback``, ``interrupted``). The *status* says
what the result is worth:

* ``converged``: a convergence test held (the predicted decrease of a full step fell below
  ``expected_decrease_tolerance``, or a full step changed the cost by less than
  ``relative_cost_tolerance``) after the plan improved on its initial guess (``improved``).
* ``stalled``: the last ``STALL_WINDOW`` iterations together, of shortened steps, made less
  progress than the cost tolerance allows, after the plan improved: a local minimum at the
  resolution the dynamics allow. Counts as converged.
* ``max_iterations``: the iteration budget ran out while the plan was still improving.
* ``line_search_failed``: no step size decreased the cost, after the plan had improved.
* ``no_progress``: the plan never improved on its initial guess (whichever test then stopped
  it): e.g. no contact along the guess, so no gradient reaches the object.
* ``interrupted``: Ctrl+C; the best plan so far.
* ``callback``: a callback asked to stop.
* ``deadline``: MPC: an update ran past its deadline.
* ``failed``: the derivatives failed along the plan, or Q_uu stayed indefinite up to
  ``regularization_max`` (no descent direction), after the plan had improved.

``converged`` (the Solution's flag) is true for ``converged`` and ``stalled`` only.
"""

from __future__ import annotations

import numpy as np

from hydroilqr.problem.solver import SolverConfig

STATUSES = (
    "converged",
    "stalled",
    "max_iterations",
    "line_search_failed",
    "no_progress",
    "interrupted",
    "callback",
    "deadline",
    "failed",
)

# Iterations over which small progress from shortened steps counts as convergence.
STALL_WINDOW = 5

# The relative cost decrease from the initial guess that counts as an improvement.
MIN_IMPROVEMENT = 1e-3

# Statuses from worst to best (``worst``): a receding run is as good as its worst window.
_ORDER = (
    "failed",
    "interrupted",
    "callback",
    "no_progress",
    "line_search_failed",
    "deadline",
    "max_iterations",
    "stalled",
    "converged",
)


def stationary(expected_full: float, J: float, s: SolverConfig) -> bool:
    """The predicted decrease of a full step is negligible at cost J."""
    return expected_full < s.expected_decrease_tolerance * max(1.0, abs(J))


def small_full_step(rel: float, eps: float, s: SolverConfig, costs: list[float] = ()) -> bool:
    """A full step changed the cost by less than ``relative_cost_tolerance`` (relative); with
    ``convergence_window`` N > 1, the last N iterations together (``costs``: every cost so
    far, the step's last) changed it by less than N times that, relative to the cost N
    iterations back."""
    w = s.convergence_window
    if eps < 1.0:
        return False
    if w == 1:
        return rel < s.relative_cost_tolerance
    if len(costs) <= w:
        return False
    before = costs[-w - 1]
    return (before - costs[-1]) / max(abs(before), 1e-12) < w * s.relative_cost_tolerance


def stalled(costs: list[float], J: float, s: SolverConfig) -> bool:
    """The last ``STALL_WINDOW`` iterations together made little progress. Small progress
    from one shortened step is not convergence (the local model may just be poor there), so
    a short step counts only when the last few iterations together made little progress."""
    w = STALL_WINDOW
    return (
        len(costs) > w and (costs[-w - 1] - J) / max(abs(J), 1e-12) < w * s.relative_cost_tolerance
    )


def no_step_reason(late: bool, stationary_pass: bool, pd: bool) -> tuple[str, bool]:
    """(reason, converged) of an iteration that took no step: the deadline passed, the
    backward pass found a stationary point (``stationary_pass``: its predicted decrease was
    negligible with Q_uu positive definite and μ not raised), Q_uu stayed indefinite (not
    ``pd``), or no step size decreased the cost."""
    if late:
        return "deadline", False
    if stationary_pass:
        return "expected_decrease", True
    if not pd:
        # Q_uu stayed indefinite up to solver.regularization_max: no descent step.
        return "regularization_max", False
    # A local minimum at the resolution the dynamics allow: reported honestly.
    return "line_search_failed", False


def improved(costs) -> bool:
    """The final cost is below the first by at least ``MIN_IMPROVEMENT`` (relative)."""
    if len(costs) < 2:
        return False
    J0, J = float(costs[0]), float(costs[-1])
    return bool(np.isfinite(J0) and (J0 - J) >= MIN_IMPROVEMENT * max(abs(J0), 1e-12))


def status(reason: str, costs, require_improvement: bool = True) -> str:
    """The status (see the module docstring) of a single solve that stopped for ``reason``
    with per-iteration ``costs`` (the initial guess's first). ``require_improvement=False``
    judges the stop test alone (a warm start that is already a local minimum, e.g. a
    receding-horizon window after the first)."""
    if reason in ("interrupted", "callback", "deadline"):
        return reason
    if require_improvement and not improved(costs):
        return "no_progress"
    if reason in ("expected_decrease", "relative_cost_change"):
        return "converged"
    if reason in ("stalled", "max_iterations", "line_search_failed"):
        return reason
    return "failed"  # regularization_max, derivatives failed: ...


def is_converged(status_: str) -> bool:
    """The ``converged`` flag a status stands for."""
    return status_ in ("converged", "stalled")


def worst(statuses: list[str]) -> str:
    """The worst of several statuses (unknown ones, e.g. from an older checkpoint, ignored;
    "failed" if none is known)."""
    known = [s for s in statuses if s in _ORDER]
    return min(known, key=_ORDER.index) if known else "failed"
