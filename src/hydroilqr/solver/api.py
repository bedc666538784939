"""The Python entry point: ``solve(task) -> Solution``.

from hydroilqr import Task, solve
task = Task.load("cartpole-wall")
sol = solve(task)
print(sol.converged, sol.final_cost, sol.X.shape)
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hydroilqr.model.plant import SimulationError
from hydroilqr.model.task import Task
from hydroilqr.problem.solver import SolverConfig, validate_solver
from hydroilqr.problem.task import validate_for_solve
from hydroilqr.problem.typed import build_dataclass
from hydroilqr.solver import stopping
from hydroilqr.solver.explain import explain  # noqa: F401 - the CLI reads it from here
from hydroilqr.solver.ilqr import IterationInfo
from hydroilqr.solver.loop import callback_list
from hydroilqr.solver.loop import solve as ilqr_solve
from hydroilqr.solver.realize import assert_physical, realize
from hydroilqr.solver.receding import solve_receding
from hydroilqr.solver.robust import solve_ensemble
from hydroilqr.solver.solution import PHASES, Solution


def solve(
    task: Task | str,
    U0: np.ndarray | None = None,
    x0: np.ndarray | None = None,
    settings: SolverConfig | dict | None = None,
    callbacks: list[Callable[[IterationInfo], bool | None]] | None = None,
    checkpoint_dir: str | Path | None = None,
    on_resolve=None,
    stop_on_interrupt: bool = False,
    on_checkpoint=None,
) -> Solution:
    """Solves a task (a Task, or a built-in task name / task file path): one iLQR solve over
    the horizon, or the receding-horizon schedule if the task has one (continuing the
    checkpoint in ``checkpoint_dir`` if there is one; ``on_checkpoint(state)`` after every
    resolve: ``output.results.checkpointer(directory)`` saves it there).

    ``U0``: [N, nu] initial guess (default: the task's ``initial_guess``); ``x0``: [nx] initial
    state (default: the task's; a quaternion in it that is not of unit norm is normalized, as
    in a task file). A receding-horizon task takes x0 from its task file; its U0 is the first
    window's guess, [W, nu]. ``settings``: solver settings for this solve, a SolverConfig or
    a dict of changes to the task's ``solver`` section (default: that section; the task
    itself is not changed). ``callbacks``: a function f(info) or a list of them, info an
    ``ilqr.IterationInfo``; one returning True stops the solve (single solves) or the current
    window (receding horizon).

    ``stop_on_interrupt``: Ctrl+C ends a single solve with the best trajectory so far
    (``reason == "interrupted"``); a receding run raises KeyboardInterrupt and keeps its
    checkpoint (continue with ``--resume``).

    The Solution's ``status`` says what the result is worth (``hydroilqr.solver.stopping``;
    for a continuation, judged from the guess's cost on the task's own model; for a receding
    horizon, its worst window's), ``explain(solution, task)`` why. A task whose cost has no
    terms is refused (ConfigError).

    A task with ``ensemble:`` members is solved robustly, against the task and every member
    at once (``solver.robust``): the Solution's X and gains are the nominal's, its costs the
    ensemble objective's, ``extra["ensemble"]`` how each member ended."""
    task = _as_task(task)
    validate_for_solve(task.config)
    task.check_memory()  # before any horizon is allocated
    callbacks = callback_list(callbacks)
    # A dict changes fields of each solve's own solver section (a stage may have its own);
    # a SolverConfig replaces them all. The task itself is not changed.
    solver = _settings_for(task.config.solver, settings)
    stages = [] if task.config.receding_horizon is not None else task.stages()
    stage_solvers = [_settings_for(st.config.solver, settings, False) for st in stages]
    if task.config.receding_horizon is not None:
        if x0 is not None:
            raise ValueError(
                f"{task.name} is a receding-horizon task: x0 comes from its task file "
                "(initial_state)"
            )
        W = task.config.receding_horizon.window_steps
        if U0 is not None and np.shape(U0)[:1] != (W,):
            raise ValueError(
                f"U0 of a receding-horizon task is its first window's guess: shape [{W}, "
                f"{task.dynamics.nu}], got {np.shape(U0)}"
            )
        return solve_receding(
            task, callbacks, checkpoint_dir, on_resolve, solver, U0, on_checkpoint
        )
    x0, U0 = _start(task, U0, x0)
    if task.config.ensemble:  # (not with continuation or receding_horizon: config.validate)
        return solve_ensemble(task, U0, x0, solver, callbacks, stop_on_interrupt)
    if _realizes(task):  # (single solves only: config.validate)
        return _realized(task, stages, stage_solvers, solver, U0, x0, callbacks, stop_on_interrupt)
    return _single(task, stages, stage_solvers, solver, U0, x0, callbacks, stop_on_interrupt)


def _single(task, stages, stage_solvers, solver, U0, x0, callbacks, stop_on_interrupt):
    """A single solve from U0: the continuation stages, if any, then the task."""
    if not stages:
        return ilqr_solve(
            task.problem(x0=x0), U0, solver, callbacks, stop_on_interrupt=stop_on_interrupt
        )
    return _continuation(
        task, list(zip(stages, stage_solvers)), solver, U0, x0, callbacks, stop_on_interrupt
    )


def _realizes(task: Task) -> bool:
    guess = task.config.initial_guess
    return not isinstance(guess, str) and guess.realize is not None


def _realized(task, stages, stage_solvers, solver, U0, x0, callbacks, stop_on_interrupt):
    """The position guess realized with virtual forces (solver/realize.py), then the single
    solve from its controls on the task's own plant; ``extra["realize"]`` keeps its stages.
    Stopped inside the realization: its hand-off, on the task's model, without iterations."""
    done = realize(task, U0, x0, solver, callbacks, stop_on_interrupt)
    if done.stopped:
        sol = ilqr_solve(task.problem(x0=x0), done.U, solver, max_iterations=0)
        sol.reason = done.stopped
    else:
        sol = _single(task, stages, stage_solvers, solver, done.U, x0, callbacks, stop_on_interrupt)
    assert_physical(task, sol)
    sol.extra["realize"] = done.record()
    return sol


def _as_task(task) -> Task:
    """A Task from a Task or a built-in task name / task file path."""
    if isinstance(task, (str, Path)):
        task = Task.load(str(task))
    if not isinstance(task, Task):
        raise TypeError(f"task: expected a Task or a task name/path, got {type(task).__name__}")
    return task


def _start(task: Task, U0, x0):
    """(x0, U0) of a single solve: x0 checked (quaternions normalized) or None for the task's;
    U0 checked against the task's N steps, or the task's initial guess (a computed guess
    holds the given state)."""
    N = task.config.steps
    if x0 is not None:
        x0 = task.checked_state(x0)  # quaternions normalized
    if U0 is None:
        U0 = task.initial_guess(N, x=x0)  # a computed guess holds the given state
    elif np.shape(U0)[:1] != (N,):
        raise ValueError(
            f"U0 must have shape [{N}, {task.dynamics.nu}] (the task's N steps, nu), "
            f"got {np.shape(U0)}"
        )
    return x0, U0


def _continuation(task: Task, stages, solver, U0, x0, callbacks, stop_on_interrupt) -> Solution:
    """Solves each (stage, its solver settings) in turn, each warm-starting the next, then
    the task itself; one joined Solution (``_join``)."""
    task_initial_cost = _initial_cost(task, U0, x0)
    parts = []
    for i, (stage, stage_solver) in enumerate(stages):
        try:
            sol = ilqr_solve(
                stage.problem(x0=x0), U0, stage_solver, callbacks, stop_on_interrupt=True
            )
        except SimulationError as e:
            raise SimulationError(f"continuation[{i}]: {e}") from None
        parts.append(sol)
        U0 = sol.U
        if sol.reason in ("interrupted", "callback"):
            if sol.reason == "interrupted" and not stop_on_interrupt:
                raise KeyboardInterrupt
            # Stopped inside a stage: the result is the stage's controls on the task's own
            # model (its trajectory and cost), not the stage model's trajectory.
            task_part = ilqr_solve(  # no iterations: the rollout and its gains
                task.problem(x0=x0), U0, solver, max_iterations=0
            )
            task_part.reason = sol.reason
            return _join(task, parts + [task_part], task_initial_cost)
    parts.append(
        ilqr_solve(task.problem(x0=x0), U0, solver, callbacks, stop_on_interrupt=stop_on_interrupt)
    )
    return _join(task, parts, task_initial_cost)


def _initial_cost(task: Task, U0, x0) -> float | None:
    """The guess's cost on the task's own model (the stages' costs are theirs); None if its
    rollout fails."""
    try:
        X0 = task.dynamics.rollout(np.asarray(task.x0 if x0 is None else x0, float), U0)
        return task.cost.total(X0, U0)
    except SimulationError:
        return None


def _settings_for(
    solver: SolverConfig, settings: SolverConfig | dict | None, check: bool = True
) -> SolverConfig:
    """The settings a solve uses: its own section ``solver`` (checked with its task) with
    ``settings`` applied; ``check``: the settings given here are checked (once per solve: a
    continuation stage's combination of them is not checked again)."""
    if settings is not None and not isinstance(settings, (dict, SolverConfig)):
        raise TypeError(
            f"settings: expected a SolverConfig or a dict of its fields, got "
            f"{type(settings).__name__}"
        )
    if settings is None:
        return solver
    if isinstance(settings, dict):
        settings = build_dataclass(
            SolverConfig, {**dataclasses.asdict(solver), **settings}, "settings"
        )
    if check:
        validate_solver(settings)
    return settings


def _join(task: Task, parts: list[Solution], task_initial_cost: float | None = None) -> Solution:
    """One Solution from continuation stages: the last stage's trajectory, gains and stop
    reason; the iteration histories of all stages in order (so times count every stage; each
    stage's costs are of its own model), and ``extra["continuation"]`` per stage.

    Its status is the last part's stop reason judged against the whole run: improvement is
    measured from the guess's cost on the task's own model (its first stage's if that
    rollout failed) to the final cost, so a last stage that starts from an already good
    plan still converges."""
    last = parts[-1]
    stages_cfg = task.config.continuation
    costs = [parts[0].costs[0]]
    for p in parts:
        costs.extend(p.costs[1:])
    if last.iterations == 0:  # stopped in a stage: its last iterate, costed on the task's model
        costs[-1] = last.costs[0]
    start = costs[0] if task_initial_cost is None else task_initial_cost
    status = stopping.status(last.reason, [start, costs[-1]])
    stages = [
        {
            "overrides": dict(stages_cfg[i]) if i < len(stages_cfg) else {},  # {}: the task
            "iterations": p.iterations,
            "start_cost": float(p.costs[0]),
            "final_cost": p.final_cost,
            "seconds": p.total_seconds,
            "reason": p.reason,
        }
        for i, p in enumerate(parts)
    ]
    return Solution(
        X=last.X,
        U=last.U,
        K=last.K,
        kappa=last.kappa,
        t=last.t,
        costs=np.array(costs),
        iteration_seconds=[s for p in parts for s in p.iteration_seconds],
        phase_seconds={k: [v for p in parts for v in p.phase_seconds[k]] for k in PHASES},
        converged=stopping.is_converged(status),
        reason=last.reason,
        status=status,
        derivatives=last.derivatives,
        eps=[e for p in parts for e in p.eps],
        mu=[m for p in parts for m in p.mu],
        extra={
            **last.extra,
            # steps differentiated per linearization, of every stage in order
            "derivative_steps": [n for p in parts for n in p.extra.get("derivative_steps", [])],
            "continuation": stages,
            **({"task_initial_cost": task_initial_cost} if task_initial_cost is not None else {}),
        },
    )
