"""The iLQR planner of closed-loop MPC (``mpc.planner: ilqr``): receding- (or shrinking-)
horizon iLQR warm-started by the previous plan shifted by the time that has passed, at most K
iterations per update; ``control/mpc.py`` runs the loop around it.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import NamedTuple

import numpy as np

from hydroilqr.model.derivatives import Linearizer
from hydroilqr.model.plant import SimulationError
from hydroilqr.model.task import Problem
from hydroilqr.problem.mpc import PlannerSettings
from hydroilqr.problem.solver import SolverConfig
from hydroilqr.solver.loop import solve as ilqr_solve
from hydroilqr.solver.solution import PHASES, Solution


class UpdateResult(NamedTuple):
    """What a control update leaves in force: the plan (a Solution over the horizon; None
    before the first) and whether this update made it (False: it failed, the old plan stays)."""

    plan: Solution | None
    ok: bool


class Controller:
    """Receding- (or shrinking-) horizon iLQR with warm starts. ``update(x, t)`` returns a plan.

    The partials live in one ``Linearizer`` for the whole run: when the plan shifts, so do
    they, and a step is differentiated again only when its (x, u) moved by more than
    ``derivative_reuse_tolerance`` (at most ``derivative_steps_per_update`` per iteration, the
    steps that moved most first).
    """

    def __init__(
        self,
        task,
        horizon_steps: int,
        settings: PlannerSettings | None = None,
        solver: SolverConfig | None = None,
        U_ref: np.ndarray | None = None,
    ):
        """``solver``: the solver settings of the first, full plan (default: the task's);
        later updates search fewer step sizes (``settings.line_search_steps``). ``U_ref``:
        the controls of a warm-start plan by time step, [M, nu] (``check_settings``)."""
        settings = settings or PlannerSettings()  # (the planner's part of an MPCConfig)
        self.task = task
        self.dyn = task.dynamics
        self.cost = task.cost
        self.N = horizon_steps
        self.shrinking = settings.shrinking_horizon  # the plan ends at the task's end
        self.tail = settings.warm_start_tail
        self.warm_feedback = settings.warm_start_feedback
        self.feedback_scale = settings.feedback_scale
        self.U_ref = U_ref  # controls by time step, or None
        self.candidates = list(settings.candidates)
        self.candidate_period = settings.candidate_period
        self.updates_since_first = 0  # (candidate_period counts the updates after the first)
        self.first: Solution | None = None  # the first (full) plan
        self.restarts = 0  # updates that started from a candidate instead of the warm start
        self.U = self._new_controls(0, horizon_steps, task.x0)
        self.t_plan = 0.0
        self.plan: Solution | None = None
        s = self.solver = solver or task.config.solver
        self.linearizer = Linearizer(
            self.dyn,
            s.derivatives,
            s.fd_epsilon,
            s.threads,
            s.derivative_interval,
            s.derivative_adaptive,
            settings.derivative_reuse_tolerance,
            settings.derivative_steps_per_update,
            autodiff_workers=s.autodiff_workers,
            fd_forces=s.fd_forces,
        )
        self.derivative_steps: list[float] = []  # steps differentiated, per update
        self.reused_prediction: list[bool] = []  # the measured state was the predicted one
        self.phases: list[dict[str, float]] = []  # seconds per solver phase, per update
        self.past_deadline = 0  # updates whose line search the deadline cut short
        # Updates search a few step sizes only; the first plan uses the task's settings.
        self.solver_update = dataclasses.replace(
            s,
            line_search_max_steps=max(1, settings.line_search_steps),
            line_search_retries=max(0, settings.line_search_retries),
        )

    def seed(self, U: np.ndarray) -> None:
        """Controls U: [N, nu] the next update starts from (a continuation's first plan)."""
        self.U = np.array(U, float)

    def update(
        self,
        x: np.ndarray,
        t: float,
        iterations: int,
        full: bool = False,
        deadline: float | None = None,
    ) -> UpdateResult:
        """A new plan from the measured state x: [nx] at time t (s), after at most
        ``iterations`` iLQR iterations. ``full``: no reuse and no cap on the partials (the
        first, converged plan). ``deadline``: a ``time.perf_counter()``
        value after which no line-search trial starts."""
        U_before = self.U  # restored if this update fails (the plan in force stays the old one)
        t_pre = time.perf_counter()  # the initial rollout below belongs to the rollout phase
        X0, on_prediction = self._warm_start(x, t) if self.plan is not None else (None, False)
        if self.plan is not None:
            self.updates_since_first += 1
        if (
            self.candidates
            and self.plan is not None
            and self.updates_since_first % self.candidate_period == 0
        ):
            X0, restarted = self._cheapest_start(x, t, X0)
            self.restarts += restarted
            on_prediction = on_prediction and not restarted
        self.reused_prediction.append(on_prediction)
        pre_rollout = time.perf_counter() - t_pre
        sol = self._solve(x, t, X0, iterations, full, deadline)
        if sol is None:
            return self._failed(U_before)
        self.derivative_steps.append(int(sum(sol.extra.get("derivative_steps", []))))
        self.phases.append({p: float(sum(v)) for p, v in sol.phase_seconds.items()})
        self.phases[-1]["rollout"] = self.phases[-1].get("rollout", 0.0) + pre_rollout
        self.past_deadline += sol.reason == "deadline"
        if not all(np.isfinite(a).all() for a in (sol.X, sol.U, sol.K)):
            return self._failed(U_before)
        self.U = sol.U.copy()
        self.t_plan = t
        self.plan = sol
        if full and self.first is None:
            self.first = sol
        return UpdateResult(sol, True)

    def _cheapest_start(self, x: np.ndarray, t: float, X0):
        """The warm start (self.U, its rollout X0 or None) against each of ``candidates``
        rolled out from x: sets self.U to the cheapest by the task's cost from t and returns
        (its states, whether a candidate won). ``first_plan`` gives two: the first plan's
        controls open loop (``first_plan_controls`` alone), and its policy (u = ū − K(x − x̄),
        which steers back towards its motion; ``first_plan_policy`` alone). A candidate that
        fails to roll out is skipped."""
        options = []
        try:
            X = X0 if X0 is not None else self.dyn.rollout(x, self.U)
            options.append((self.cost.total(X, self.U, t), X, self.U, False))
        except SimulationError:
            pass
        for U, Xbar, K in self._candidate_plans(x, t):
            try:
                if K is None:
                    X = self.dyn.rollout(x, U)
                else:
                    X, U = self.dyn.closed_loop_rollout(x, U, Xbar, K, np.zeros_like(U), 0.0)
            except SimulationError:
                continue
            options.append((self.cost.total(X, U, t), X, U, True))
        options = [o for o in options if np.isfinite(o[0])]
        if not options:
            return X0, False
        _, X, U, restarted = min(options, key=lambda o: o[0])
        self.U = np.array(U, float)
        if restarted:
            self.linearizer.clear()  # the partials were taken along another trajectory
        return X, restarted

    def _candidate_plans(self, x: np.ndarray, t: float):
        """(U [N, nu], X̄ [N+1, nx] or None, K [N, nu, nx] or None) of each candidate."""
        N = self.U.shape[0]
        for name in self.candidates:
            if name == "guess":
                yield self.task.initial_guess(N, x, start=int(round(t / self.dyn.dt))), None, None
                continue
            if self.first is None:
                continue
            U, X, K = self.first.U[:N], self.first.X[: N + 1], self.first.K[:N]
            if U.shape[0] < N:  # a first plan shorter than the horizon: the guess after it
                m = N - U.shape[0]
                U = np.vstack([U, self.task.initial_guess(m, x, start=U.shape[0])])
                X = np.vstack([X, np.repeat(X[-1:], m, axis=0)])
                K = np.concatenate([K, np.zeros((m,) + K.shape[1:])])
            if name in ("first_plan", "first_plan_controls"):
                yield U, None, None
            if name in ("first_plan", "first_plan_policy"):
                yield U, X, K

    def _warm_start(self, x: np.ndarray, t: float):
        """Shifts the controls (and the partials) by the time since the last plan and returns
        the initial rollout: the previous plan's prediction if the plant went exactly there,
        else its policy from x (``warm_start_feedback``), else None; and whether it was the
        prediction. A time between plan steps (a control rate above the plan's) resamples
        the plan instead (``_resample``)."""
        dt = self.dyn.dt
        s = (t - self.t_plan) / dt
        if not self.shrinking and abs(s - round(s)) > 1e-6 and s > 0:
            return self._resample(x, t, s), False
        X0 = None  # initial rollout: the previous plan's prediction, or its policy from x
        shift = int(round(s))
        shift = min(max(shift, 0), self.U.shape[0])
        pad = None
        if self.shrinking:  # drop what has passed, append nothing
            shift = min(shift, self.U.shape[0] - 1)
            if shift:
                self.U = self.U[shift:]
        elif shift:
            k_new = int(round(t / dt)) + self.U.shape[0] - shift  # first appended step
            pad = self._new_controls(k_new, shift, x)
            self.U = np.vstack([self.U[shift:], pad])
        self.linearizer.shift(shift)
        Xp = self.plan.X[shift:]
        on_prediction = bool(np.array_equal(Xp[0], x))
        if on_prediction:  # the plant went exactly where the plan said
            try:
                tail = self.dyn.rollout(Xp[-1], pad)[1:] if pad is not None else Xp[:0]
                X0 = np.vstack([Xp, tail])
            except SimulationError:
                X0, on_prediction = None, False
        elif self.warm_feedback:
            X0 = self._policy_rollout(x, Xp, self.plan.K[shift:])
        return X0, on_prediction

    def _resample(self, x: np.ndarray, t: float, s: float):
        """The previous plan moved to a grid that starts ``s`` (not whole) plan steps after
        it: new step k spans the old plan's time [k + s, k + 1 + s), so its control is the
        time average of the old controls there, its reference state the model's motion under
        those controls from the old plan's state at the new start (interpolated, quaternions
        renormalized) and its gains the old step's that holds most of it. The partials shift
        by whole steps (``derivative_reuse_tolerance`` decides whether the moved ones still
        fit). Returns the policy rollout from x (or None)."""
        dt = self.dyn.dt
        N, M = self.U.shape[0], self.plan.U.shape[0]
        i0 = int(math.floor(s))
        f = s - i0
        need = N + i0 + 2  # old-plan steps the new grid touches
        U = self.U
        if need > U.shape[0]:
            k_new = int(round(self.t_plan / dt)) + U.shape[0]
            U = np.vstack([U, self._new_controls(k_new, need - U.shape[0], x)])
        k = np.arange(N) + i0
        self.U = (1.0 - f) * U[k] + f * U[k + 1]
        # The reference of the feedback: the model's own motion under the resampled controls
        # from the old plan's state at the new start (interpolated). The old states
        # interpolated are not a motion of the model on the new grid, and feedback against
        # them fights that offset at every step.
        lo = min(i0, M - 1)
        a = min(s, M) - lo
        self.linearizer.shift(min(int(round(s)), N))
        if not self.warm_feedback:
            return None
        x_start = self.dyn.layout.normalize((1.0 - a) * self.plan.X[lo] + a * self.plan.X[lo + 1])
        try:
            X = self.dyn.rollout(x_start, self.U)
        except SimulationError:
            return None
        held = np.arange(N) + i0 + (1 if f >= 0.5 else 0)  # the old step holding most of it
        K = np.where((held < M)[:, None, None], self.plan.K[np.minimum(held, M - 1)], 0.0)
        return self._policy_rollout(x, X, K)

    def _solve(
        self, x, t, X0, iterations: int, full: bool, deadline: float | None
    ) -> Solution | None:
        """At most ``iterations`` iLQR iterations from x at time t; None if the solve failed
        (its per-update statistics then NaN)."""
        lin = self.linearizer
        keep = lin.reuse_tolerance, lin.max_steps
        if full:
            lin.reuse_tolerance, lin.max_steps = 0.0, 0
        try:
            sol = ilqr_solve(
                Problem(self.dyn, self.cost, x, t),
                self.U,
                self.solver if full else self.solver_update,
                max_iterations=iterations,
                final_gains=False,
                linearizer=lin,
                X0=X0,
                deadline=deadline,
            )
        except SimulationError:
            # Per-update lists stay aligned: a failed update's breakdown is unknown (NaN).
            self.derivative_steps.append(math.nan)
            self.phases.append(dict.fromkeys(PHASES, math.nan))
            return None
        finally:
            lin.reuse_tolerance, lin.max_steps = keep
        return sol

    def _new_controls(self, k0: int, n: int, x: np.ndarray) -> np.ndarray:
        """Controls for time steps k0 .. k0+n-1 that no plan has yet: the warm-start plan's
        where it has them, then the tail rule (task guess or the last control). -> [n, nu]"""
        out = []
        if self.U_ref is not None and k0 < self.U_ref.shape[0]:
            out.append(self.U_ref[k0 : k0 + n])
        m = n - sum(len(a) for a in out)
        if m > 0:
            if self.tail == "last" and (out or hasattr(self, "U")):
                out.append(np.tile(out[-1][-1] if out else self.U[-1], (m, 1)))
            else:  # "guess", or the very first plan: the guess's rows for these time steps
                out.append(self.task.initial_guess(m, x, start=k0 + n - m))
        return np.vstack(out)

    def _failed(self, U_before: np.ndarray) -> UpdateResult:
        """Undo this update's shift: the old plan (and its time) stays in force. The partials
        were shifted with it, so they are dropped and taken afresh next time."""
        self.U = U_before
        self.linearizer.clear()
        return UpdateResult(self.plan, False)

    def _policy_rollout(self, x, Xp, Kp):
        """The previous plan's policy from the measured state x: u_k = ū_k − K_k (x_k − x̄_k).

        Xp: [N_old + 1 − shift, nx] and Kp: [N_old − shift, nu, nx], the shifted plan; self.U:
        [N, nu], the shifted controls (with any tail appended, where K = 0). On success sets
        self.U to the controls applied and returns the states, X: [N + 1, nx]; else None.
        """
        N = self.U.shape[0]
        extra = N - Kp.shape[0]
        if extra > 0:
            Kp = np.concatenate([Kp, np.zeros((extra,) + Kp.shape[1:])])
            Xp = np.concatenate([Xp, np.repeat(Xp[-1:], extra, axis=0)])
        try:
            X, U = self.dyn.closed_loop_rollout(
                x, self.U, Xp[: N + 1], self.feedback_scale * Kp[:N], np.zeros_like(self.U), 0.0
            )
        except SimulationError:
            return None
        self.U = U
        return X
