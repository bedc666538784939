"""A task's sampling search: its spline space, the rollout and cost of a sample, the search.

``SearchSpace(task)`` reads the task's ``search:`` section (``problem.search.SearchConfig``):
K knots per actuator of a spline of ``order`` over the horizon, in one of two spaces:

- ``torque``: the spline is the actuators' command at each step's time, U: [N, nu]
  (clipped to the effort limits, as the plant applies it);
- ``position``: the spline is the actuated joints' position targets at each state's time,
  Q_ref: [N+1, nu], tracked by playback's PD+ law (``model.pd.pd_rollout``: gains
  ``search.kp`` / ``kd``, gravity compensation as feed-forward); the torques are the
  rollout's. The first knot is the start posture (pinned), the others stay within the
  joint limits.

A sample's cost is the task's own cost (terms included) of the task's own plant's rollout
from its initial state; a rollout the plant cannot step costs inf. The nominal knots come
from the task's initial guess (its controls, or its rollout's joint positions); the noise
unit is each actuator's effort limit (1 without one) in torque space and 1 (rad or m) in
position space. ``run_search(task, evaluate)`` runs ``solver.sampling.search`` with them;
``evaluate`` defaults to this process's own rollouts (``studies/search.py`` sends batches to
Dask workers instead).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hydroilqr.model.pd import actuated_indices, pd_rollout
from hydroilqr.model.plant import SimulationError
from hydroilqr.problem.search import SearchConfig
from hydroilqr.solver import sampling, splines
from hydroilqr.solver.solution import Solution


@dataclass
class Rollout:
    """A sample's rollout: X: [N+1, nx], U: [N, nu] (the torques applied), its cost."""

    X: np.ndarray
    U: np.ndarray
    cost: float


class SearchSpace:
    """The spline, space and bounds of a task's search (``settings``: default the task's
    ``search:`` section, else the defaults)."""

    def __init__(self, task, settings: SearchConfig | None = None):
        self.settings = settings or task.config.search or SearchConfig()
        cfg = self.settings
        dyn = task.dynamics
        self.N = task.steps
        self.dt = dyn.dt
        self.T = self.N * self.dt
        steps = self.N if cfg.space == "torque" else self.N + 1
        self.W = splines.basis(cfg.knots, self.dt * np.arange(steps), self.T, cfg.order)
        self.knot_steps = np.minimum(
            np.round(splines.knot_times(cfg.knots, self.T, cfg.order) / self.dt).astype(int),
            self.N - 1 if cfg.space == "torque" else self.N,
        )
        if cfg.space == "torque":
            lim = np.asarray(dyn.effort_limits, float)
            finite = np.isfinite(lim) & (lim > 0)
            self.scale = np.where(finite, lim, 1.0)
            self.lower, self.upper = np.where(finite, -lim, -np.inf), np.where(finite, lim, np.inf)
        else:
            self.qi, _ = actuated_indices(dyn.plant)
            if len(self.qi) != dyn.nu:
                raise ValueError("search.space position needs one 1-DoF joint per actuator")
            self.scale = np.ones(dyn.nu)
            lo = np.asarray(dyn.plant.GetPositionLowerLimits()[self.qi], float)
            hi = np.asarray(dyn.plant.GetPositionUpperLimits()[self.qi], float)
            # [K, nu]: the first knot is pinned at the start posture (a target away from it
            # at t = 0 would be a step the PD+ law answers with a jolt); the others within
            # the joint limits
            q0 = np.asarray(task.x0[self.qi], float)
            self.lower, self.upper = np.tile(lo, (cfg.knots, 1)), np.tile(hi, (cfg.knots, 1))
            self.lower[0] = self.upper[0] = q0

    def nominal(self, task) -> np.ndarray:
        """θ0: [K, nu] from the task's initial guess: its controls at the knots' times
        (torque), or the joint positions its rollout reaches there (position)."""
        U0 = task.initial_guess(self.N)
        if self.settings.space == "torque":
            return U0[self.knot_steps].copy()
        try:
            X0 = task.dynamics.rollout(task.x0, U0)
        except SimulationError:  # the guess blows up: hold the start posture
            X0 = np.tile(task.x0, (self.N + 1, 1))
        return X0[self.knot_steps][:, self.qi].copy()

    def decode(self, knots: np.ndarray) -> np.ndarray:
        """The command of knots θ: [K, nu]: U [N, nu] (torque) or Q_ref [N+1, nu] (position)."""
        return self.W @ knots

    def rollout(self, task, command: np.ndarray) -> Rollout:
        """The command's rollout on the task's plant from its initial state, and its cost (a
        SimulationError propagates)."""
        dyn = task.dynamics
        if self.settings.space == "torque":
            U = dyn.clip_to_limits(np.asarray(command, float))
            X = dyn.rollout(task.x0, U)
        else:
            X, U = pd_rollout(dyn, task.x0, command, self.settings.kp, self.settings.kd)
        with np.errstate(all="ignore"):
            cost = float(task.cost.total(X, U))
        return Rollout(X, U, cost if math.isfinite(cost) else math.inf)

    def cost(self, task, command: np.ndarray) -> float:
        """The command's cost; inf if its rollout fails."""
        try:
            return self.rollout(task, command).cost
        except SimulationError:
            return math.inf


def local_evaluator(task, space: SearchSpace):
    """``evaluate(commands) -> costs`` in this process, on the task's own plant."""

    def evaluate(commands):
        return [space.cost(task, c) for c in commands]

    return evaluate


def run_search(task, evaluate=None, settings: SearchConfig | None = None, on_iteration=None):
    """(SearchSpace, SamplingResult): the task's search (``settings``: default its ``search:``
    section) with ``evaluate`` (default: ``local_evaluator``); the best ``search.polish``
    distinct samples (at least 1) are kept as candidates."""
    space = SearchSpace(task, settings)
    cfg = space.settings
    result = sampling.search(
        evaluate or local_evaluator(task, space),
        space.decode,
        space.nominal(task),
        space.scale,
        cfg,
        space.lower,
        space.upper,
        keep=max(1, cfg.polish),
        on_iteration=on_iteration,
    )
    return space, result


def as_solution(task, space: SearchSpace, result: sampling.SamplingResult) -> Solution:
    """The best sample as a Solution (its rollout; no gains): ``costs`` the best cost after
    each iteration, led by the nominal's (``record`` says what the search did)."""
    r = space.rollout(task, result.best.command)
    costs = np.concatenate([result.costs[:1, 0], result.best_costs]) if result.history else [r.cost]
    return Solution(
        X=r.X,
        U=r.U,
        K=np.zeros(0),
        kappa=np.zeros(0),
        t=space.dt * np.arange(space.N + 1),
        costs=np.asarray(costs, float),
        iteration_seconds=[h["seconds"] for h in result.history],
        phase_seconds={},
        converged=False,
        reason="interrupted" if result.interrupted else "search",
        derivatives="none (sampling)",
        status="interrupted" if result.interrupted else "max_iterations",
    )


def record(space: SearchSpace, result: sampling.SamplingResult) -> dict:
    """The search in plain data (summary.json): settings, history and the candidates."""
    cfg = space.settings
    return {
        "settings": {k: getattr(cfg, k) for k in cfg.__dataclass_fields__},
        "samples_evaluated": result.samples,
        "seconds": result.seconds,
        "samples_per_second": result.samples / result.seconds if result.seconds > 0 else None,
        "interrupted": result.interrupted,
        "best_cost": result.best.cost,
        "nominal_cost": float(result.costs[0, 0]) if result.costs.size else None,
        "history": result.history,
        "candidates": [
            {"cost": c.cost, "iteration": c.iteration, "index": c.index} for c in result.candidates
        ],
    }
