"""The sampling planners of closed-loop MPC (``mpc.planner: sampling | hybrid``).

Each update searches a spline of ``K`` knots over the horizon from the measured state
(``solver.sampling.search``, the task's ``search:`` settings: method, noise, space, order, PD+
gains), warm-started by the previous best spline shifted by the time that has passed
(``solver.search.shifted_knots``; iCEM, mujoco_mpc), ``mpc.sampling_iterations`` iterations
of ``mpc.samples`` rollouts (the first plan: ``search.iterations``). The samples roll out on
the worker processes that hold the plant (``model.workers.sample_rollouts``) and are priced
here by the task's cost from the update's time. In ``position`` space the first knot is the
target the plan in force holds at that time (the joint controller's set point moves on
continuously) and the plan is the best sample's PD+ law written as a policy: the loop applies
u = ū − K (x − x̄) with ū, x̄ the sample's torques and states and K the PD gains on the actuated
joints, which is the PD+ law towards the sample's targets (its gravity feed-forward taken at
x̄). In ``torque`` space the plan is open loop (K = 0).

``hybrid`` then runs at most ``mpc.iterations_per_update`` iLQR iterations from the best
sample's torques (the first plan: ``solver.max_iterations``), cut short by ``mpc.deadline``
with ``--realtime``, and keeps the iLQR plan (its gains) when it lowered the cost: the
sampler finds the motion, iLQR refines it (mujoco_mpc's sample-gradient planner).
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from hydroilqr.control.ilqr_planner import UpdateResult
from hydroilqr.model.derivatives import Linearizer
from hydroilqr.model.pd import actuated_indices
from hydroilqr.model.plant import SimulationError
from hydroilqr.model.task import Problem
from hydroilqr.model.workers import sample_rollouts
from hydroilqr.problem.mpc import PlannerSettings
from hydroilqr.problem.search import SearchConfig
from hydroilqr.problem.solver import SolverConfig
from hydroilqr.solver import sampling
from hydroilqr.solver.loop import solve as ilqr_solve
from hydroilqr.solver.search import SearchSpace, priced, shifted_knots
from hydroilqr.solver.solution import PHASES, Solution


def sampler_settings(task, settings: PlannerSettings, horizon_steps: int) -> SearchConfig:
    """The sampler's settings: the task's ``search:`` section (or the defaults) with the
    ``mpc:`` section's samples and knots (at most one knot per step of the horizon)."""
    base = task.config.search or SearchConfig()
    return dataclasses.replace(
        base,
        samples=settings.samples or base.samples,
        knots=max(1, min(settings.knots or base.knots, horizon_steps)),
        window_steps=0,
    )


class SamplingPlanner:
    """``update(x, t, iterations)`` returns a plan (an ``UpdateResult``) as the iLQR
    ``Controller`` does; ``iterations``: iLQR iterations of a ``hybrid`` update."""

    uses_stages = False  # (a continuation's stages seed iLQR, not a sampler)

    def __init__(self, task, horizon_steps: int, settings: PlannerSettings, solver: SolverConfig):
        self.task, self.dyn, self.cost = task, task.dynamics, task.cost
        self.N = horizon_steps
        self.search = sampler_settings(task, settings, horizon_steps)
        self.hybrid = settings.planner == "hybrid"
        self.iterations = settings.sampling_iterations
        self.workers = settings.sampling_workers
        self.U_ref = None  # (no warm-start plan: the sampler starts from the task's guess)
        self.solver = solver
        self.solver_update = dataclasses.replace(
            solver,
            line_search_max_steps=max(1, settings.line_search_steps),
            line_search_retries=max(0, settings.line_search_retries),
        )
        self.linearizer = Linearizer(
            self.dyn, solver.derivatives, solver.fd_epsilon, solver.threads,
            solver.derivative_interval, solver.derivative_adaptive,
            autodiff_workers=solver.autodiff_workers, fd_forces=solver.fd_forces,
        )  # fmt: skip
        self.plan: Solution | None = None
        self.t_plan = 0.0
        self.space: SearchSpace | None = None
        self.knots: np.ndarray | None = None  # the best sample's knots of the plan in force
        self.command: np.ndarray | None = None  # its command (targets or torques)
        self.derivative_steps: list[float] = []
        self.reused_prediction: list[bool] = []
        self.phases: list[dict[str, float]] = []
        self.sampling: list[dict] = []  # per update: samples, seconds, costs, iLQR
        self.past_deadline = 0
        self.restarts = 0
        self.updates = 0
        self._ilqr: Solution | None = None  # the last hybrid polish (``_record``)
        if self.search.space == "position":
            qi, vi = actuated_indices(self.dyn.plant)
            G = np.zeros((self.dyn.nu, self.dyn.nx))
            G[np.arange(len(qi)), qi] = self.search.kp
            G[np.arange(len(vi)), vi] = self.search.kd
            self.gains = G
        else:
            self.gains = np.zeros((self.dyn.nu, self.dyn.nx))

    def seed(self, U: np.ndarray) -> None:  # (``ClosedLoop.first_plan``'s interface)
        pass

    def update(self, x, t: float, iterations: int, full: bool = False, deadline=None):
        """A new plan from the measured state x at time t; ``full``: the first plan (the
        search's own iterations; hybrid: iLQR to ``solver.max_iterations``)."""
        t0 = time.perf_counter()
        space, nominal = self._window(x, t)
        cfg = dataclasses.replace(
            self.search,
            iterations=self.search.iterations if full else self.iterations,
            seed=self.search.seed + self.updates,
        )
        space.settings = cfg
        self.updates += 1
        cache: list = []
        try:
            res = sampling.search(
                self._evaluator(x, t, cache), space.decode, nominal, space.scale, cfg,
                space.lower, space.upper,
            )  # fmt: skip
        except KeyboardInterrupt:
            raise
        rolled = cache[res.best.iteration * cfg.samples + res.best.index]
        seconds = time.perf_counter() - t0  # (the sampling: hybrid's iLQR is timed apart)
        self.reused_prediction.append(False)
        if rolled is None:  # every sample failed: the plan in force stays
            self._record(res, seconds, None, 0)
            return UpdateResult(self.plan, False)
        X, U = rolled
        plan = self._as_plan(X, U, t, res)
        ilqr_its = 0
        if self.hybrid:
            plan, ilqr_its = self._polish(plan, x, t, iterations, full, deadline)
        self._record(res, seconds, plan, ilqr_its)
        self.space, self.knots, self.command = space, res.best.knots, res.best.command
        self.plan, self.t_plan = plan, t
        return UpdateResult(plan, True)

    def _window(self, x, t: float):
        """The horizon's search space from x at t (position space: the first knot pinned at
        the plan in force's target then) and the warm start: the previous best spline
        shifted, or the task's guess for the first plan."""
        dt = self.dyn.dt
        pin = None
        if self.command is not None and self.search.space == "position":
            i = min(max(int(round((t - self.t_plan) / dt)), 0), self.command.shape[0] - 1)
            pin = self.command[i]
        start = int(round(t / dt))
        space = SearchSpace(self.task, self.search, start, self.N, x, pin)
        space.t0 = t
        if self.knots is None:
            return space, space.nominal(self.task)
        return space, shifted_knots(self.space, self.knots, space, t - self.t_plan)

    def _evaluator(self, x, t: float, cache: list):
        """``evaluate(commands) -> costs`` on the worker processes; each sample's (X, U)
        appended to ``cache`` (None: its rollout failed)."""
        cfg = self.search

        def evaluate(commands):
            outs = sample_rollouts(self.dyn, x, commands, cfg.space, cfg.kp, cfg.kd, self.workers)
            costs = []
            for o in outs:
                if isinstance(o, SimulationError):
                    cache.append(None)
                    costs.append(math.inf)
                    continue
                cache.append(o)
                costs.append(priced(self.task, o[0], o[1], t).cost)
            return costs

        return evaluate

    def _as_plan(self, X, U, t: float, res) -> Solution:
        N = U.shape[0]
        costs = [float(res.costs[0, 0]), *[h["best_cost"] for h in res.history]]
        return Solution(
            X=X,
            U=U,
            K=np.repeat(self.gains[None], N, axis=0),
            kappa=np.zeros_like(U),
            t=t + self.dyn.dt * np.arange(N + 1),
            costs=np.asarray(costs, float),
            iteration_seconds=[h["seconds"] for h in res.history],
            phase_seconds={},
            converged=False,
            reason="sampling",
            derivatives="none (sampling)",
            status="max_iterations",
        )

    def _polish(self, plan: Solution, x, t: float, iterations: int, full: bool, deadline):
        """hybrid: iLQR from the best sample; (the plan kept, its iLQR iterations)."""
        self.linearizer.clear()
        try:
            sol = ilqr_solve(
                Problem(self.dyn, self.cost, x, t),
                plan.U,
                self.solver if full else self.solver_update,
                max_iterations=iterations,
                final_gains=False,
                linearizer=self.linearizer,
                X0=plan.X,
                deadline=deadline,
            )
        except SimulationError:
            return plan, 0
        self.past_deadline += sol.reason == "deadline"
        self._ilqr = sol
        if not all(np.isfinite(a).all() for a in (sol.X, sol.U, sol.K)):
            return plan, 0
        if not sol.final_cost < plan.final_cost:
            return plan, sol.iterations
        sol.t = plan.t
        return sol, sol.iterations

    def _record(self, res, seconds: float, plan, ilqr_its: int) -> None:
        """Per update: the phases (the sampling counted as rollouts; hybrid: with iLQR's),
        derivative steps and the sampler's numbers (``sampling``)."""
        n = int(res.costs.size)
        sol, self._ilqr = self._ilqr, None
        phases = dict.fromkeys(PHASES, 0.0)
        steps = 0
        if sol is not None:
            phases.update({p: float(sum(v)) for p, v in sol.phase_seconds.items()})
            steps = int(sum(sol.extra.get("derivative_steps", [])))
        phases["rollout"] += seconds
        self.derivative_steps.append(steps)
        self.phases.append(phases)
        self.sampling.append(
            {
                "samples": n,
                "sampling_seconds": seconds,
                "samples_per_second": n / seconds if seconds > 0 else None,
                "best_cost": res.best.cost,
                "warm_start_cost": float(res.costs[0, 0]),
                "ilqr_iterations": ilqr_its,
                "plan_cost": plan.final_cost if plan is not None else None,
            }
        )
