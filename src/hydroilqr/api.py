"""The Python entry point: ``solve(task) -> Solution``.

from hydroilqr import Task, solve
task = Task.load("cartpole-wall")
sol = solve(task)
print(sol.converged, sol.final_cost, sol.X.shape)
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from .config import SolverConfig
from .ilqr import IterationInfo
from .ilqr import solve as ilqr_solve
from .receding import solve_receding
from .solution import Solution
from .task import Task


def solve(
    task: Task,
    settings: SolverConfig | None = None,
    callbacks: list[Callable[[IterationInfo], None]] | None = None,
    checkpoint_dir: str | Path | None = None,
    on_resolve=None,
    stop_on_interrupt: bool = False,
) -> Solution:
    """Solves a task: one iLQR solve over the horizon, or the receding-horizon schedule if the
    task has one (checkpointed to ``checkpoint_dir`` after every resolve).

    ``stop_on_interrupt``: Ctrl+C ends a single solve with the best trajectory so far
    (``reason == "interrupted"``); a receding run raises KeyboardInterrupt and keeps its
    checkpoint (continue with ``--resume``)."""
    if settings is not None:
        task.config.solver = settings
    if task.config.receding_horizon is not None:
        return solve_receding(task, callbacks, checkpoint_dir, on_resolve)
    N = task.config.steps
    return ilqr_solve(
        task.problem(),
        task.initial_guess(N),
        task.config.solver,
        callbacks,
        stop_on_interrupt=stop_on_interrupt,
    )
