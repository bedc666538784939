"""One sentence on how a solve ended and its likely cause (``explain(solution, task)``)."""

from __future__ import annotations

import numpy as np

from hydroilqr.model.contacts import no_contact_remedy, touches_tracked, tracked_objects
from hydroilqr.model.plant import SimulationError
from hydroilqr.solver.solution import Solution


def explain(sol: Solution, task) -> str:
    """A one-sentence explanation of ``sol.status`` (see ``hydroilqr.solver.stopping``) for a
    solve of ``task``, with the likely cause; for a receding-horizon run, of its worst
    window."""
    costs = _costs(sol)
    status = sol.status
    if status == "no_progress":
        return _no_progress(sol, task, costs)
    sentences = {
        "converged": f"converged after improving on the initial guess ({costs})",
        "stalled": (
            "stalled in a local minimum: the last iterations' shortened steps together made "
            f"little progress ({costs})"
        ),
        "max_iterations": (
            f"stopped at solver.max_iterations while still improving ({costs}): allow more "
            "iterations to continue"
        ),
        "line_search_failed": (
            f"no step size decreased the cost any more ({costs}): a local minimum at the "
            "resolution the dynamics allow"
        ),
        "interrupted": f"interrupted: the best plan so far is kept ({costs})",
        "callback": f"a callback stopped the solve ({costs})",
        "deadline": f"the deadline passed before a step was found ({costs})",
        "failed": f"failed ({sol.reason}; {costs})",
    }
    text = sentences.get(status, f"stopped ({sol.reason}; {costs})")
    ens = sol.extra.get("ensemble")
    if isinstance(ens, dict) and ens.get("stopped_in") == "warm_start":
        text += "; this was the ensemble's warm start: the plan is the task's own, not robust"
    if "resolves" in sol.extra:
        text = f"{sol.reason}; the worst window: {text}"
    return text


def stop_line(sol: Solution, seconds: float) -> str:
    """The line that says how a solve ended: ``status STATUS after N iterations (stop test:
    REASON), cost C, T s``. The status is the verdict (``summary.json``'s ``status``); the stop
    test (``reason``) only says which test ended the loop, e.g. ``expected_decrease`` ends
    a solve that converged as well as one that made no progress."""
    n = sol.iterations
    test = "windows" if "resolves" in sol.extra else "stop test"  # (a receding-horizon run)
    return (
        f"status {sol.status} after {n} iteration{'' if n == 1 else 's'} ({test}: "
        f"{sol.reason}), cost {sol.final_cost:.6g}, {seconds:.2f} s"
    )


def _costs(sol: Solution) -> str:
    """'cost A -> B': from the initial guess's cost to the final one; for an ensemble solve,
    of the ensemble objective (what its status was judged on; after a warm start whose guess
    could not be rolled out on every member, from the warm plan's)."""
    ens = sol.extra.get("ensemble")
    robust = isinstance(ens, dict) and "members" in ens  # (a stop in the warm start: not)
    what = "ensemble objective" if robust else "cost"
    return f"{what} {sol.initial_cost:.6g} -> {sol.final_cost:.6g}"


def _guess_rollout(sol: Solution, task) -> np.ndarray:
    """The rollout of the task's initial guess when the solve started from the task's state
    over its steps; else the plan itself (for no progress, close to its guess)."""
    N = sol.U.shape[0]
    if N == task.steps and np.array_equal(sol.X[0], task.x0):
        try:
            return task.dynamics.rollout(task.x0, task.initial_guess(N))
        except SimulationError:
            pass
    return sol.X


def _no_progress(sol: Solution, task, costs: str) -> str:
    if sol.iterations == 0 and sol.reason == "max_iterations":
        return (
            f"no iterations were run (solver.max_iterations 0; {costs}): the plan is the "
            "initial guess itself (`hydroilqr check TASK --replay FILE.html` shows a guess "
            "without a solve)"
        )
    steps = sum(1 for e in sol.eps if e > 0)
    costs += "; no step was taken" if steps == 0 else f"; {steps} small step(s) were taken"
    tracked = tracked_objects(task)
    if tracked and not touches_tracked(task, _guess_rollout(sol, task)):
        names = ", ".join(sorted(tracked))
        return (
            f"no progress ({costs}): no contact along the initial guess between {names} and "
            f"a moving body, so no gradient reaches it: {no_contact_remedy(task, sol.X, names)}"
        )
    return (
        f"no progress ({costs}): the plan never improved on its initial guess, which may "
        "already be a local minimum of this cost"
    )
