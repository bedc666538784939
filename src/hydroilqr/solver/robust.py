"""Robust (ensemble) solves of a task with ``ensemble:`` members (see model/ensemble.py).

The stacked problem (the task itself, the nominal, first; then each member of
``Task.members()``) is solved from the task's initial state x0 given to every member (the
real start does not depend on which model is right), by the ordinary iLQR loop. With
``ensemble_warm_start`` (the default) the task alone is solved first from the initial guess
and the ensemble solve starts from that plan; otherwise from the initial guess itself.
The Solution is then put in the nominal's terms:

* X: [N+1, n], the nominal member's states; U, kappa, costs, status, reason as solved (the
  costs are those of the ensemble objective Σ_m w_m J_m, which the stopping tests judged);
* K: [N, nu, n] = Σ_m K_m, the gains of every member's block summed. The stacked policy is
  u = ū − Σ_m K_m (x_m − x̄_m); with one measured state x standing in for every member it is
  u = ū − Σ_m K_m (x − x̄_m), which equals ū − K_eff (x − x̄_nominal) only up to the offsets
  K_m (x̄_m − x̄_nominal) of the perturbed members' trajectories. The stored K_eff is about
  the nominal trajectory (the offsets are dropped, so u = ū at x = x̄_nominal);
* ``extra["ensemble"]``: the weight, and per member (nominal first, overrides {}) its
  overrides, weight, final cost J_m, terminal cost and terminal error; after a warm start,
  ``warm_start`` (the task-alone solve: iterations, costs, seconds, reason) and
  ``ensemble_start_cost`` (the ensemble objective of the warm plan).

After a warm start the iteration histories (times, step sizes) are the warm start's followed
by the ensemble solve's; the costs are the task's own over the warm start's iterations, then
the ensemble objective from the warm plan on (the warm start's last entry is the ensemble
objective of its plan, so the final cost is always the ensemble's). The status is judged
from the ensemble objective of the initial guess (``initial_cost``) to its final value, so a
robust stage that only keeps the warm plan still counts the warm start's progress; a guess
whose ensemble rollout fails is judged from the warm plan's ensemble cost.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from hydroilqr.model.ensemble import EnsembleCost, EnsembleDynamics, EnsembleLinearizer
from hydroilqr.model.plant import SimulationError
from hydroilqr.model.task import Problem, Task
from hydroilqr.solver import stopping
from hydroilqr.solver.loop import solve as ilqr_solve
from hydroilqr.solver.solution import PHASES, Solution


def ensemble_problem(task: Task, x0: np.ndarray | None = None) -> Problem:
    """The stacked problem of ``task`` and its ensemble members, from x0: [n] (default: the
    task's initial state) given to every member: x0 stacked [M·n]."""
    members = [task, *task.members()]
    dyn = EnsembleDynamics([m.dynamics for m in members])
    weights = [1.0] + [task.config.ensemble_weight] * (len(members) - 1)
    cost = EnsembleCost([m.cost for m in members], weights)
    return Problem(dyn, cost, dyn.stack(task.x0 if x0 is None else x0), 0.0)


def solve_ensemble(
    task: Task, U0: np.ndarray, x0, settings, callbacks, stop_on_interrupt: bool
) -> Solution:
    """Solves ``task``'s ensemble problem from U0: [N, nu] (x0: [n] or None for the task's);
    the Solution in the nominal's terms (module docstring). Callbacks see the stacked
    iterates (IterationInfo.X: [N+1, M·n]), after those of the warm start (the task's own,
    [N+1, n]). Interrupted or stopped by a callback during the warm start: that plan, the
    task's own (no ensemble stage ran), with ``extra["ensemble"]["stopped_in"] ==
    "warm_start"``."""
    problem = ensemble_problem(task, x0)
    warm = None
    if task.config.ensemble_warm_start:
        guess_cost = _objective(problem, U0)
        warm = ilqr_solve(task.problem(x0=x0), U0, settings, callbacks, stop_on_interrupt=True)
        if warm.reason in ("interrupted", "callback"):
            if warm.reason == "interrupted" and not stop_on_interrupt:
                raise KeyboardInterrupt
            stopped = {"weight": task.config.ensemble_weight, "stopped_in": "warm_start"}
            return dataclasses.replace(warm, extra={**warm.extra, "ensemble": stopped})
        U0 = warm.U
    lin = EnsembleLinearizer.from_settings(problem.dynamics, settings)
    sol = ilqr_solve(
        problem, U0, settings, callbacks, stop_on_interrupt=stop_on_interrupt, linearizer=lin
    )
    sol = nominal_solution(task, problem, sol)
    return sol if warm is None else _after_warm_start(warm, sol, guess_cost)


def _objective(problem: Problem, U: np.ndarray) -> float | None:
    """The ensemble objective of U: [N, nu] (None if a member's rollout fails)."""
    try:
        X = problem.dynamics.rollout(problem.x0, U)
    except SimulationError:
        return None
    return float(problem.cost.total(X, U, problem.t0))


def _after_warm_start(warm: Solution, sol: Solution, guess_cost: float | None) -> Solution:
    """The ensemble Solution ``sol`` with the warm start's history put before its own and its
    status judged from the guess's ensemble objective (module docstring)."""
    start = sol.costs[0] if guess_cost is None else guess_cost
    status = stopping.status(sol.reason, [start, sol.costs[-1]])
    ensemble = {
        **sol.extra["ensemble"],
        "costs": "the task's own cost over the warm start's iterations, then the ensemble "
        "objective (the weighted sum over the members) from the warm plan on; initial_cost "
        "and final_cost are the ensemble objective's",
        "warm_start": {
            "iterations": warm.iterations,
            "start_cost": float(warm.costs[0]),
            "final_cost": warm.final_cost,
            "seconds": warm.total_seconds,
            "reason": warm.reason,
        },
        "ensemble_start_cost": float(sol.costs[0]),
        **({"guess_ensemble_cost": guess_cost} if guess_cost is not None else {}),
    }
    steps = [*warm.extra.get("derivative_steps", []), *sol.extra.get("derivative_steps", [])]
    return dataclasses.replace(
        sol,
        costs=np.concatenate([warm.costs[:-1], sol.costs]),
        iteration_seconds=[*warm.iteration_seconds, *sol.iteration_seconds],
        phase_seconds={k: [*warm.phase_seconds[k], *sol.phase_seconds[k]] for k in PHASES},
        eps=[*warm.eps, *sol.eps],
        mu=[*warm.mu, *sol.mu],
        status=status,
        converged=stopping.is_converged(status),
        # the cost the status was judged from, on the objective of the final cost
        extra={
            **sol.extra,
            "derivative_steps": steps,
            "ensemble": ensemble,
            "task_initial_cost": float(start),
        },
    )


def nominal_solution(task: Task, problem: Problem, sol: Solution) -> Solution:
    """``sol`` of the stacked ``problem`` in the nominal's terms: X of the nominal member,
    K_eff = Σ_m K_m, and ``extra["ensemble"]`` per member."""
    dyn, cost = problem.dynamics, problem.cost
    K = np.zeros((sol.K.shape[0], dyn.nu, dyn.n))
    for b in dyn.blocks:
        K += sol.K[:, :, b]
    overrides = [{}, *(dict(m) for m in task.config.ensemble)]
    members = []
    for m, (c, w) in enumerate(zip(cost.members, cost.weights)):
        Xm = dyn.member_states(sol.X, m)
        members.append(
            {
                "overrides": overrides[m],
                "weight": float(w),
                "final_cost": c.total(Xm, sol.U, problem.t0),
                **_terminal(c, Xm, sol.U.shape[0], problem.t0),
            }
        )
    ensemble = {
        "weight": task.config.ensemble_weight,
        # what the run's numbers are: the costs of the solve, the rest of the nominal's
        "costs": "initial_cost, final_cost and costs are the weighted sum over the members",
        "metrics": "the nominal model's (its trajectory X), as is the goal",
        "members": members,
    }
    return dataclasses.replace(
        sol, X=sol.X[:, : dyn.n].copy(), K=K, extra={**sol.extra, "ensemble": ensemble}
    )


def _terminal(cost, XN: np.ndarray, N: int, t0: float) -> dict:
    """Member's terminal cost x̃_Nᵀ Q_f x̃_N and terminal error |x̃_N| over the coordinates
    Q_f weights (over all of them if it weights none): x̃_N = x_N ⊖ x_nom(t_N)."""
    r = cost.layout.diff(XN[-1:], cost.targets(N, t0)[-1:])[0]
    mask = cost.qf > 0 if np.any(cost.qf > 0) else np.ones(r.shape, bool)
    return {
        "terminal_cost": float(r @ (cost.qf * r)),
        "terminal_error": float(np.linalg.norm(r[mask])),
    }
