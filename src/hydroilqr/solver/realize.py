"""A position guess realized with virtual forces (``initial_guess.realize``).

A guess that moves an unactuated coordinate (a base's x, an object's position) asks for a
motion the actuators alone may not make: its tracking rollout on the task's plant moves that
coordinate only as far as the actuators' torques do. As in contact-implicit and inverse-
dynamics trajectory optimization, where a "virtual" (or "helper") force on the unactuated
coordinates is penalized and driven to zero, the realization:

1. tracks the guess on the task's plant with one virtual actuator (no effort limit) on the
   joint of each unactuated coordinate the guess names (model/guess.py's ``virtual_config``):
   the path is followed, the virtual forces carrying what the actuators cannot;
2. solves the task on that plant once per ``realize.weights`` entry (``realize.iterations``
   iLQR iterations each), the virtual forces costed by that weight (their R) and every
   stage warm-starting the next, so the actuators take over the motion as the weights rise;
3. hands the last stage's plan to the task's own plant, which has no virtual actuators: the
   actuators' controls rolled out under that stage's feedback gains (so the state stays near
   the stage's trajectory as the virtual forces drop out), clipped to the effort limits.

The task itself (its own continuation stages, then the task) is then solved from those
controls, so the final plan is physical: it has no virtual force.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from hydroilqr.model.plant import SimulationError
from hydroilqr.model.task import Task
from hydroilqr.problem.solver import SolverConfig
from hydroilqr.solver.loop import solve as ilqr_solve
from hydroilqr.solver.solution import Solution


@dataclasses.dataclass
class Realized:
    """A realization's result: U: [N, nu] the task's controls it hands over (no virtual
    force), X: [N+1, nx] their rollout on the task's plant, per stage a record
    (``stages``), how it was handed over and its cost on the task (``handoff``,
    ``handoff_cost``); ``stopped``: a stage was interrupted or stopped by a callback
    (``interrupted`` or ``callback``), else None."""

    U: np.ndarray
    X: np.ndarray
    stages: list[dict]
    handoff: str
    handoff_cost: float
    stopped: str | None = None

    def record(self) -> dict:
        """What summary.json keeps of it."""
        return {"stages": self.stages, "handoff": self.handoff, "handoff_cost": self.handoff_cost}


def realize(
    task: Task,
    U0: np.ndarray,
    x0: np.ndarray | None,
    solver: SolverConfig,
    callbacks=None,
    stop_on_interrupt: bool = False,
) -> Realized:
    """The task's position guess realized from x0 (default: the task's), starting from its
    tracking with virtual forces; U0: [N, nu], the task's ``initial_guess`` (its tracking
    without them) or a perturbed copy, whose difference from it is added to the actuators'
    controls of that start. ``solver``: the task's settings (each stage
    runs ``realize.iterations`` of them, at most its ``max_iterations``). Raises
    SimulationError naming the stage."""
    r = task.config.initial_guess.realize
    nu = task.dynamics.nu
    x = task.x0 if x0 is None else np.asarray(x0, float)
    N = U0.shape[0]
    # the tracking with virtual forces, moved by U0's difference from the task's own guess
    # (none for the guess itself; a perturbed guess's perturbation otherwise)
    U = task.virtual_task().initial_guess(N, x)
    U[:, :nu] += np.asarray(U0, float) - task.initial_guess(N, x)
    its = min(int(r.iterations), solver.max_iterations)  # (a smoke run's few, too)
    settings = dataclasses.replace(solver, max_iterations=its)
    stages, sol = [], None
    for i, weight in enumerate(r.weights):
        stage = task.virtual_task(float(weight))
        t0 = time.perf_counter()
        try:
            sol = ilqr_solve(stage.problem(x0=x), U, settings, callbacks, stop_on_interrupt=True)
        except SimulationError as e:
            raise SimulationError(f"initial_guess.realize stage {i}: {e}") from None
        U = sol.U
        stages.append(_stage_record(weight, sol, nu, time.perf_counter() - t0))
        if sol.reason in ("interrupted", "callback"):
            if sol.reason == "interrupted" and not stop_on_interrupt:
                raise KeyboardInterrupt
            break
    X, Uphys, how, cost = handoff(task, x, sol)
    stopped = sol.reason if sol.reason in ("interrupted", "callback") else None
    return Realized(Uphys, X, stages, how, cost, stopped)


def _stage_record(weight: float, sol: Solution, nu: int, seconds: float) -> dict:
    """One stage of a realization in plain data: its weight, iterations, costs, and the
    largest virtual force (N or N·m) and its RMS over the plan."""
    V = sol.U[:, nu:]
    return {
        "weight": float(weight),
        "iterations": sol.iterations,
        "start_cost": float(sol.costs[0]),
        "final_cost": sol.final_cost,
        "max_virtual_force": float(np.max(np.abs(V))),
        "rms_virtual_force": float(np.sqrt(np.mean(V**2))),
        "reason": sol.reason,
        "seconds": seconds,
    }


def handoff(task: Task, x0: np.ndarray, sol: Solution):
    """(X, U, how, cost): the last stage's plan on the task's own plant (no virtual actuators):
    its actuators' controls open loop (``how``: "open_loop") or under its feedback gains
    ("feedback"), whichever costs less on the task (a failed rollout costs inf); U clipped
    to the effort limits (what the plant applies, so X is their rollout); cost: the task's
    cost of it."""
    dyn = task.dynamics
    nu = dyn.nu
    Ubar = sol.U[:, :nu]
    tries = {}
    try:
        U = dyn.clip_to_limits(Ubar)
        tries["open_loop"] = (dyn.rollout(x0, U), U)
    except SimulationError:
        pass
    K = np.asarray(sol.K)
    if K.ndim == 3:
        try:
            kappa = np.zeros_like(Ubar)
            X, U = dyn.closed_loop_rollout(x0, Ubar, sol.X, K[:, :nu, :], kappa, 0.0)
            tries["feedback"] = (X, dyn.clip_to_limits(U))
        except SimulationError:
            pass
    if not tries:
        raise SimulationError("initial_guess.realize: the last stage's plan fails on the plant")
    costs = {k: float(task.cost.total(*xu)) for k, xu in tries.items()}
    how = min(costs, key=costs.get)
    return *tries[how], how, costs[how]


def assert_physical(task: Task, sol: Solution) -> None:
    """The final plan of a realized solve is the task's own: one control per actuator of the
    task's plant, whose plant has no virtual actuator (AssertionError otherwise)."""
    assert not task.dynamics.spec.virtual_forces, "the task's own plant has virtual actuators"
    assert sol.U.shape[1] == task.dynamics.nu, "the final plan carries virtual forces"


def report(task: Task, unactuated: dict) -> dict:
    """What ``hydroilqr check`` shows of a realization from the task's guess over its
    horizon: per unactuated coordinate of ``unactuated`` (names, as ``model.guess.
    rollout_report`` gives them) where the tracking with virtual forces ends it
    (``virtual_tracking``) and where the realized guess, on the task's own plant, does
    (``realized``); each stage's record, and how the hand-off was made."""
    N = task.steps
    layout = task.dynamics.layout
    tracking = task.virtual_task().dynamics.rollout(task.x0, task.virtual_task().initial_guess(N))
    done = realize(task, task.initial_guess(N), None, task.config.solver)
    ends = {}
    for name in unactuated:
        q = layout.block(name, name).coords[0]
        ends[name] = {"virtual_tracking": float(tracking[-1, q]), "realized": float(done.X[-1, q])}
    return {"ends": ends, **done.record()}
