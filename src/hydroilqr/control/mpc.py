"""Closed-loop model predictive control over hydroelastic contact.

A plant simulation (the task's own model, a separate Drake context) runs forward. At every
control update the controller reads the current state x, warm-starts from its previous plan
shifted by the time that has passed, runs at most K iLQR iterations over a short horizon, and
the plant then receives the local policy of eq. (8) between updates:

    u(t) = ū_i − K_i (x(t) − x̄_i),   i = (t − t_plan) / dt

clipped to the actuators' effort limits.

Two clocks:

* lock-step (default): the simulation waits for the controller; the report says how far from
  real time the controller is (``controller_realtime_factor`` = control period / solve time);
* ``realtime``: while the controller computes, the simulation keeps running with the old policy
  for the wall time the solve took, so its latency is felt; the new plan, computed from the
  state measured at the start of the solve, is applied from then on (indexed by time since that
  measurement).

``--push TIME:BODY:FX,FY,FZ`` applies an external force (N, world frame, at the body origin)
for ``push_duration`` seconds to show recovery.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from pydrake.multibody.math import SpatialForce
from pydrake.multibody.plant import ExternallyAppliedSpatialForce

from hydroilqr import metrics as metrics_mod
from hydroilqr.io.rundir import previous_task
from hydroilqr.metrics.common import beyond_limits
from hydroilqr.model.derivatives import Linearizer
from hydroilqr.model.guess import describe as describe_guess
from hydroilqr.model.names import body_labels, find_body
from hydroilqr.model.plant import Dynamics, SimulationError
from hydroilqr.model.task import Problem
from hydroilqr.problem.checks import MAX_STEPS, unknown_key
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.load import with_overrides
from hydroilqr.problem.mpc import MPCConfig, PlannerSettings, validate_mpc
from hydroilqr.problem.solver import SolverConfig
from hydroilqr.problem.task import validate_for_solve
from hydroilqr.problem.variants import check_truth_overrides
from hydroilqr.solver.loop import solve as ilqr_solve
from hydroilqr.solver.solution import PHASES, Solution, load_run_solution


@dataclass
class Push:
    time: float
    body: str
    force: np.ndarray  # [3] N, world frame
    duration: float = 0.1

    @staticmethod
    def parse(text: str, duration: float) -> Push:
        if not (math.isfinite(duration) and duration > 0):
            raise ConfigError(f"--push-duration {duration:g}: must be a positive number")
        try:
            t, body, f = text.split(":")
            force = np.array([float(v) for v in f.split(",")])
            t = float(t)
            if force.size != 3 or not np.all(np.isfinite(force)) or not math.isfinite(t):
                raise ValueError
            return Push(t, body, force, duration)
        except ValueError:
            raise ConfigError(f"--push {text!r}: expected TIME:BODY:FX,FY,FZ") from None


def check_settings(settings: MPCConfig, task, section_checked: bool = False) -> np.ndarray | None:
    """Raises ConfigError for settings that cannot run on ``task``; returns the warm-start
    plan's controls, U: [M, nu] (None without one). A task's ``ensemble:`` is not used: MPC
    re-plans on the task's own model. ``section_checked``: the settings are the task's own
    ``mpc:`` section (``mpc_config(task)``), whose own checks ran when the task was built;
    only those against the task run here."""
    dt = task.config.plant.time_step
    _check_timing(settings, dt)
    _check_iteration(settings)
    if not section_checked:
        validate_mpc(settings)  # the checks of a task file's mpc: section
    U_ref = plan_controls(settings, task) if settings.warm_start_plan else None
    _check_truth(settings, task, dt)
    _check_pushes(settings, task.dynamics.plant, simulation_step(settings, dt)[0])
    return U_ref


def _check_timing(settings: MPCConfig, dt: float) -> None:
    """Rate, horizon and duration: positive, within MAX_STEPS; the update period whole steps
    of the simulated robot (``simulation_step``; of the plan, ``dt``, with a shrinking
    horizon, whose plan ends on the task's grid)."""
    if not all(
        math.isfinite(v) and v > 0 for v in (settings.rate, settings.horizon, settings.duration)
    ):
        raise ConfigError("mpc: rate, horizon and duration must be positive finite numbers")
    if settings.threads < 0:
        raise ConfigError("mpc threads: must be >= 0 (0 = all cores)")
    for what, seconds in (("horizon", settings.horizon), ("duration", settings.duration)):
        if seconds / dt > MAX_STEPS:
            raise ConfigError(
                f"mpc {what} {seconds:g} s: more than {MAX_STEPS} time steps of {dt:g} s"
            )
    h = dt if settings.shrinking_horizon else simulation_step(settings, dt)[0]
    which = "plan (shrinking horizon)" if settings.shrinking_horizon else "simulated robot"
    if settings.rate > 1.0 / h * (1 + 1e-9):
        more = "" if h < dt or settings.shrinking_horizon else "; --plant-time-step for more"
        raise ConfigError(
            f"mpc rate {settings.rate:g} Hz: at most one update per time step of the {which} "
            f"({1.0 / h:g} Hz with its step {h:g} s{more})"
        )
    steps = 1.0 / (settings.rate * h)
    if abs(steps - round(steps)) > 1e-4 * steps:
        n = math.floor(steps)
        near = " or ".join(f"{1.0 / (m * h):g} Hz" for m in (n, n + 1) if m >= 1)
        raise ConfigError(
            f"mpc rate {settings.rate:g} Hz: an update period of {steps:g} time steps of the "
            f"{which} ({h:g} s); the period must be whole steps, e.g. {near}"
        )
    if settings.delay_compensation:
        m = 1.0 / (settings.rate * dt)
        if settings.shrinking_horizon or m < 1 - 1e-9 or abs(m - round(m)) > 1e-4 * m:
            raise ConfigError(
                f"mpc.delay_compensation: the update period ({1.0 / settings.rate:g} s) must "
                f"be whole plan steps ({dt:g} s) on a receding horizon"
            )
    if not settings.shrinking_horizon and settings.horizon < 2 * dt * (1 - 1e-9):
        raise ConfigError(
            f"mpc horizon {settings.horizon:g} s: at least two time steps ({2 * dt:g} s)"
        )
    if int(round(settings.duration / dt)) < 1:
        raise ConfigError(
            f"mpc duration {settings.duration:g} s: shorter than one time step ({dt:g} s)"
        )
    if 1.0 / settings.rate > settings.duration * (1 - 1e-9):  # (the first update: at one period)
        raise ConfigError(
            f"mpc rate {settings.rate:g} Hz: its update period ({1.0 / settings.rate:g} s) is "
            f"not shorter than the duration ({settings.duration:g} s): no update would run"
        )


def _check_iteration(settings: MPCConfig) -> None:
    """Iterations per update, feedback scale and line search of each update."""
    if settings.iterations_per_update < 1:
        raise ConfigError("mpc iterations per update: at least 1")
    if not (math.isfinite(settings.feedback_scale) and settings.feedback_scale >= 0):
        raise ConfigError(f"--feedback-scale {settings.feedback_scale:g}: must be finite and >= 0")
    if settings.line_search_steps < 1 or settings.line_search_retries < 0:
        raise ConfigError("mpc line_search_steps >= 1 and line_search_retries >= 0 required")


def _check_pushes(settings: MPCConfig, plant, h: float) -> None:
    """Each push: on a movable body of ``plant``, of positive duration, within the run, its
    start and length whole steps of the simulated robot (``h`` s), as it is applied."""
    labels = body_labels(plant)
    welded = {labels[int(b.index())] for b in plant.GetBodiesWeldedTo(plant.world_body())}
    for p in settings.pushes:
        try:
            find_body(plant, p.body, "--push", exclude=welded)
        except ConfigError as e:
            raise ConfigError(str(e).replace("no body named", "no movable body named")) from None
        if not p.duration > 0:
            raise ConfigError(f"--push-duration: must be positive, got {p.duration:g}")
        if not 0 <= p.time < settings.duration:
            raise ConfigError(
                f"--push at {p.time:g} s: outside the run (0 to {settings.duration:g} s)"
            )
        for what, value in (("--push at", p.time), ("--push-duration", p.duration)):
            n = value / h
            if what == "--push-duration" and round(n) < 1:
                raise ConfigError(
                    f"--push-duration {value:g} s: shorter than one step of the simulated "
                    f"robot ({h:g} s), the shortest push it applies"
                )
            if abs(n - round(n)) > 1e-6 * max(1.0, n):
                lo, hi = math.floor(n) * h, math.ceil(n) * h
                near = f"{lo:.10g} or {hi:.10g}" if lo > 0 or what == "--push at" else f"{hi:.10g}"
                raise ConfigError(
                    f"{what} {value:g} s: not whole steps of the simulated robot ({h:g} s), "
                    f"as a push is applied; e.g. {near} s"
                )
        if round(p.time / h) >= round(settings.duration / h):
            raise ConfigError(
                f"--push at {p.time:g} s: starts after the run's last step "
                f"({settings.duration:g} s)"
            )


def simulation_step(settings: MPCConfig, dt: float) -> tuple[float, int]:
    """The simulated robot's time step and how many of them make one plan step of ``dt``;
    ConfigError unless it divides ``dt``."""
    h = settings.plant_time_step
    if h == 0:
        return dt, 1
    if not (math.isfinite(h) and 0 < h <= dt):
        raise ConfigError(
            f"mpc.plant_time_step: a positive step no longer than the plan's {dt:g} s, got {h:g}"
        )
    r = dt / h
    if abs(r - round(r)) > 1e-6 * r:
        raise ConfigError(
            f"mpc.plant_time_step {h:g} s: must divide the plan's time step {dt:g} s "
            f"(e.g. {dt / math.ceil(r):g} s)"
        )
    return dt / round(r), int(round(r))


def _check_truth(settings: MPCConfig, task, dt: float) -> None:
    """The simulated plant's overrides and time step, and a shrinking horizon that ends with
    the task."""
    h, substeps = simulation_step(settings, dt)
    if task.steps * substeps > MAX_STEPS:  # (the simulated plant spans the task's horizon)
        raise ConfigError(
            f"--plant-time-step (mpc.plant_time_step) {h:g} s: the task's horizon "
            f"({task.steps * dt:g} s) is {task.steps * substeps} steps of it; at most {MAX_STEPS}"
        )
    # (the simulated plant's task is built, and checked, once: Truth)
    check_truth_overrides(settings.truth_overrides, mpc=True)
    if settings.shrinking_horizon and int(round(settings.duration / dt)) > task.steps:
        raise ConfigError(
            f"mpc: a shrinking horizon ends with the task ({task.steps * dt:g} s); the "
            f"duration {settings.duration:g} s is longer"
        )


def plan_controls(settings: MPCConfig, task) -> np.ndarray | None:
    """The warm-start plan's controls, U: [M, nu] (None without one); ConfigError if it
    cannot be read or does not fit the task ."""
    if not settings.warm_start_plan:
        return None
    plan, path = load_run_solution(settings.warm_start_plan, "mpc.warm_start_plan")
    U, t = np.asarray(plan.U, float), np.asarray(plan.t, float)
    nu = task.dynamics.nu
    if U.ndim != 2 or U.shape[1] != nu:
        raise ConfigError(
            f"mpc.warm_start_plan: {path} holds controls of shape {U.shape}, not [M, {nu}]"
        )
    if not np.all(np.isfinite(U)):
        raise ConfigError(f"mpc.warm_start_plan: {path} holds NaN or infinite controls")
    other = previous_task(path.parent)  # another task with as many actuators is wrong too
    if other is not None and other != task.name:
        raise ConfigError(
            f"mpc.warm_start_plan: {path.parent} is a run of task {other!r}, not {task.name!r}"
        )
    dt = task.config.plant.time_step
    if t.size > 1 and abs((t[1] - t[0]) - dt) > 1e-9:
        raise ConfigError(
            f"mpc.warm_start_plan: {path} has time step {t[1] - t[0]:g} s, the task {dt:g} s"
        )
    return U


def mpc_config(task, **overrides) -> MPCConfig:
    """The task's ``mpc:`` section, with keyword overrides (None = keep the task's): a copy.
    TypeError naming an unknown setting."""
    m = task.config.mpc
    s = dataclasses.replace(
        m,
        truth_overrides=list(m.truth_overrides),
        plan_overrides=list(m.plan_overrides),
        pushes=list(m.pushes),
    )
    if m.warm_start_plan:
        # a task file's path is relative to that file (a --warm-start-plan: to the cwd)
        s.warm_start_plan = str(task.config.resolve_path(m.warm_start_plan))
    if s.shrinking_horizon:
        # The task's default duration cannot outlast the task itself (e.g. under --smoke,
        # which shortens the task); an explicit duration that does is refused in check().
        s.duration = min(s.duration, task.steps * task.config.plant.time_step)
    fields = [f.name for f in dataclasses.fields(MPCConfig)]
    for k, v in overrides.items():
        if k not in fields:  # setattr would add an attribute nothing reads
            msg = unknown_key(k, fields, f"setting {k!r}")
            raise TypeError(f"mpc_config: {msg}")
        if v is not None:
            setattr(s, k, v)
    return s


SMOKE_UPDATES = 10  # --smoke without --duration: the loop runs at most this many updates


@dataclass
class MPCResult:
    """Closed-loop trajectory and controller statistics.

    X: [T+1, nx], U: [T, nu], t: [T+1]; solve_seconds / update_times: one per update.
    """

    X: np.ndarray
    U: np.ndarray
    t: np.ndarray
    update_times: list[float]
    solve_seconds: list[float]
    iterations: list[int]
    failures: int
    wall_seconds: float
    settings: MPCConfig
    failure: str = ""  # set when the simulated plant failed (the run stops there)
    derivative_steps: list[float] = field(default_factory=list)  # per update (NaN: failed)
    reused_prediction: list[bool] = field(default_factory=list)  # no initial rollout needed
    phases: list[dict] = field(default_factory=list)  # solver phase seconds, per update
    interrupted: bool = False  # stopped by Ctrl+C before the end
    past_deadline: int = 0  # updates whose line search mpc.deadline cut short
    saturated_fraction: float = 0.0  # commands clipped at an effort limit (of all commands)
    restarts: int = 0  # updates that started from an mpc.candidates entry
    # [T, nu] the inputs the controller asked for, before the effort limits clipped them (U)
    U_commanded: np.ndarray | None = None
    # how the first plan (before the clock starts) was made: its start, stages, outcome
    first_plan: dict = field(default_factory=dict)

    def stats(self) -> dict:
        s = np.array(self.solve_seconds) if self.solve_seconds else np.zeros(1)
        sim = float(self.t[-1] - self.t[0])
        period = 1.0 / self.settings.rate
        solved = [ph for ph in self.phases if np.all(np.isfinite(list(ph.values())))]
        steps = [n for n in self.derivative_steps if np.isfinite(n)]
        return {
            "duration_s": sim,
            "updates": len(self.solve_seconds),
            "requested_rate_hz": self.settings.rate,
            # Updates (the plan at t = 0 included) per second: 1 / mean interval between them.
            "achieved_rate_hz": (
                len(self.solve_seconds) / self.update_times[-1]
                if self.update_times and self.update_times[-1] > 0
                else 0.0
            ),
            "horizon_s": self.settings.horizon,
            "iterations_per_update": self.settings.iterations_per_update,
            "mean_iterations": float(np.mean(self.iterations)) if self.iterations else 0.0,
            "realtime_mode": self.settings.realtime,
            "delay_compensation": self.settings.delay_compensation,
            "threads": self.settings.threads,
            "derivatives": self.settings.derivatives,
            "solve_seconds": {
                "p50": float(np.percentile(s, 50)),
                "p95": float(np.percentile(s, 95)),
                "max": float(np.max(s)),
                "mean": float(np.mean(s)),
            },
            "controller_realtime_factor": period / float(np.mean(s)) if np.mean(s) > 0 else None,
            "realtime_factor": sim / self.wall_seconds if self.wall_seconds > 0 else None,
            "wall_seconds": self.wall_seconds,
            "simulation_failure": self.failure or None,
            "interrupted": self.interrupted,
            "deadline_fraction": self.settings.deadline,
            "updates_past_deadline": self.past_deadline,
            "feedback_scale": self.settings.feedback_scale,
            "saturated_fraction": self.saturated_fraction,
            "solver_failures": self.failures,
            "shrinking_horizon": self.settings.shrinking_horizon,
            "updates_on_prediction": int(sum(self.reused_prediction)),
            "candidates": list(self.settings.candidates),
            "candidate_period": self.settings.candidate_period,
            "updates_from_a_candidate": self.restarts,
            # Mean seconds per update in each solver phase (rollout, derivatives, ...).
            "phase_seconds_mean": {  # over the updates whose solve did not fail
                p: float(np.mean([ph.get(p, 0.0) for ph in solved])) for p in PHASES
            }
            if solved
            else {},
            "derivative_steps_per_update_mean": float(np.mean(steps)) if steps else 0.0,
            "truth_overrides": list(self.settings.truth_overrides),
            "plan_overrides": list(self.settings.plan_overrides),
            "plant_time_step_s": float(self.t[1] - self.t[0]) if len(self.t) > 1 else None,
            "warm_start_plan": self.settings.warm_start_plan,
            "first_plan": self.first_plan,
            "pushes": [
                {"time": p.time, "body": p.body, "force": p.force.tolist(), "duration": p.duration}
                for p in self.settings.pushes
            ],
        }

    def as_solution(self) -> Solution:
        """The closed-loop run in Solution form (for metrics, plots and replays)."""
        T, nu = self.U.shape
        nx = self.X.shape[1]
        return Solution(
            self.X,
            self.U,
            np.zeros((T, nu, nx)),
            np.zeros((T, nu)),
            self.t,
            np.zeros(1),
            [],
            {},
            True,
            "mpc",
            "",
        )


def loop_metrics(task, res: MPCResult) -> dict:
    """The task's metrics of a closed-loop run, on the plant that was simulated (truth
    overrides cannot touch the cost), the effort limits judged on the commanded inputs (the
    applied ones are clipped); {"error": ...} for a state the plant cannot evaluate."""
    try:
        sim_task = task
        if res.settings.truth_overrides:
            sim_task = task.with_overrides(res.settings.truth_overrides)
        task_metrics = metrics_mod.compute(sim_task, res.as_solution())
        if "commands_beyond_limits" in task_metrics and res.U_commanded is not None:
            for key in ("max_command_to_limit_ratio", "max_command_to_limit_actuator"):
                task_metrics.pop(key, None)  # (of the clipped inputs: not there)
            task_metrics.update(beyond_limits(sim_task.dynamics, res.U_commanded))
    except (RuntimeError, SimulationError) as e:  # e.g. a state the plant cannot evaluate
        task_metrics = {"error": str(e).strip().splitlines()[0]}
    return task_metrics


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


class Truth:
    """The simulated plant being controlled (its own Drake context), with external pushes."""

    def __init__(self, task, overrides: list[str] | None = None, time_step: float = 0.0):
        """``time_step``: the simulated robot's step (0: the task's)."""
        overrides = list(overrides or [])
        if time_step and time_step != task.config.plant.time_step:
            overrides.append(f"plant.time_step={time_step!r}")
        cfg = with_overrides(task.config, overrides) if overrides else task.config
        self.dyn = Dynamics(cfg)
        ref = task.dynamics
        if (self.dyn.nx, self.dyn.nu) != (ref.nx, ref.nu):
            raise ConfigError(
                f"--truth-set: the simulated plant has nx={self.dyn.nx}, nu={self.dyn.nu}; "
                f"the controller's has nx={ref.nx}, nu={ref.nu}"
            )
        self.plant = self.dyn.plant
        self.limits = self.dyn.effort_limits
        self.commands = 0  # actuator commands applied (steps × actuators)
        self.saturated = 0  # of them, beyond an effort limit (clipped)
        self.port = self.plant.get_applied_spatial_force_input_port()
        self._pushing = None
        self._set_force(())

    def _set_force(self, pushes: tuple[Push, ...]):
        if pushes == self._pushing:
            return
        forces = []
        for push in pushes:  # several at once add up
            body = find_body(self.plant, push.body, "--push")  # (checked before the run)
            f = ExternallyAppliedSpatialForce()
            f.body_index = body.index()
            f.p_BoBq_B = np.zeros(3)
            f.F_Bq_W = SpatialForce(np.zeros(3), push.force)
            forces.append(f)
        self.port.FixValue(self.dyn.plant_context, forces)
        self._pushing = pushes

    def step(self, x, u, k, pushes):
        """One step of the plant from x with input u at time step k (pushes active then)."""
        dt = self.dyn.dt
        active = []
        for p in pushes:  # in whole time steps: [round(t/dt), + round(duration/dt))
            k0 = int(round(p.time / dt))
            if k0 <= k < k0 + max(1, int(round(p.duration / dt))):
                active.append(p)
        self._set_force(tuple(active))
        self.commands += len(u)
        self.saturated += int(np.count_nonzero(np.abs(u) > self.limits))
        u = np.clip(u, -self.limits, self.limits)
        return self.dyn.step(x, u), u


# Task keys a controller's plan never reads: a plan override of one would change nothing.
UNPLANNED_KEYS = frozenset(
    {
        "name",
        "description",
        "mpc",
        "goal",
        "metrics",
        "metric_params",
        "smoke",
        "ensemble",
        "ensemble_weight",
        "ensemble_warm_start",
        "mismatch",
    }
)


def planning_task(task, settings: MPCConfig):
    """The task the controller plans with: ``task`` with ``settings.plan_overrides`` (itself
    without); ConfigError for overrides that change its time grid, state or inputs."""
    if not settings.plan_overrides:
        return task
    for item in settings.plan_overrides:
        top = str(item).split("=", 1)[0].strip().split(".", 1)[0]
        if top in UNPLANNED_KEYS:
            raise ConfigError(
                f"mpc.plan_overrides: {item!r}: the controller does not read {top!r} (its "
                "plans take the task's cost, model and solver settings); set it with --set"
            )
    try:
        planner = task.with_overrides(settings.plan_overrides)
        dyn = planner.dynamics
    except ConfigError as e:
        raise ConfigError(f"mpc.plan_overrides: {e}") from None
    ref = task.dynamics
    if (dyn.nx, dyn.nu, dyn.dt) != (ref.nx, ref.nu, ref.dt) or planner.steps != task.steps:
        raise ConfigError(
            "mpc.plan_overrides: the controller's task must keep the task's time grid, state "
            "and inputs (cost, model parameters and solver settings may change)"
        )
    return planner


def prepare(task, settings: MPCConfig | None = None) -> ClosedLoop:
    """The closed loop of ``task`` under ``settings``, checked and built, before any solve:
    ConfigError for settings that cannot run. ``settings``: default ``mpc_config(task)``, the
    task's ``mpc:`` section (as the ``mpc`` command uses); a bare ``MPCConfig(...)`` starts
    from generic defaults instead. ``run_mpc`` is ``prepare`` then ``ClosedLoop.run``."""
    validate_for_solve(task.config)
    if settings is None:
        settings = mpc_config(task)
    dt = task.dynamics.dt
    U_ref = check_settings(settings, task, section_checked=_as_checked(settings, task))
    planner = planning_task(task, settings)
    N = max(2, int(round(settings.horizon / dt)))
    if settings.shrinking_horizon:
        N = task.steps
        settings = dataclasses.replace(settings, horizon=N * dt)  # the caller's is unchanged
    task.check_memory(N, "mpc.horizon")
    solver = controller_solver(planner.config.solver, settings)
    if not settings.derivatives:  # recorded as the method in use (the caller's is unchanged)
        settings = dataclasses.replace(settings, derivatives=solver.derivatives)
    ctrl = Controller(planner, N, PlannerSettings.of(settings), solver, U_ref)
    h, _ = simulation_step(settings, dt)
    try:
        truth = Truth(task, settings.truth_overrides, h)
    except ConfigError as e:  # e.g. a body the overrides name that the model lacks
        if not settings.truth_overrides:
            raise
        raise ConfigError(f"mpc.truth_overrides (--truth-set): {e}") from None
    return ClosedLoop(task, settings, ctrl, truth)


def run_mpc(task, settings: MPCConfig | None = None, on_update=None) -> MPCResult:
    """Runs the closed loop for ``settings.duration`` seconds of simulated time (``prepare``:
    the settings). ``on_update(k, n)``: called with the time steps simulated so far and in
    all."""
    return prepare(task, settings).run(on_update)


def _as_checked(settings: MPCConfig, task) -> bool:
    """Whether the settings ``validate_mpc`` checks (the planner's and the goal) are the task's
    own ``mpc:`` section's, checked when the task was built (e.g. the command line changed
    only the loop's rate or duration); a warm-start plan's path is compared as given."""

    def checked_part(m: MPCConfig) -> tuple:
        return dataclasses.replace(PlannerSettings.of(m), warm_start_plan=""), m.goal

    return checked_part(settings) == checked_part(task.config.mpc)


def controller_solver(solver: SolverConfig, settings: MPCConfig) -> SolverConfig:
    """The task's solver settings with the controller's threads and derivatives."""
    return dataclasses.replace(
        solver,
        threads=settings.threads,
        derivatives=settings.derivatives or solver.derivatives,
        derivative_interval=settings.derivative_interval or solver.derivative_interval,
    )


class ClosedLoop:
    """The simulated plant under the controller's plans: states X, applied inputs U, and per
    update its time, solve seconds and iterations."""

    def __init__(self, task, settings: MPCConfig, ctrl: Controller, truth: Truth):
        self.task, self.settings, self.ctrl, self.truth = task, settings, ctrl, truth
        # The simulation's step, and its steps per plan step (1: it steps as the plan does).
        self.dt, self.substeps = simulation_step(settings, task.dynamics.dt)
        self.total = int(round(settings.duration / self.dt))
        # Updates every period_steps simulation steps: the rate may exceed the plan's grid
        # (each update re-plans from the measured state on a grid starting then).
        self.period_steps = max(1, int(round(1.0 / (settings.rate * self.dt))))
        self.x = task.x0.copy()
        self.X, self.U, self.U_asked = [self.x], [], []
        self.upd_t, self.solve_s, self.iters = [], [], []
        self.failures, self.k = 0, 0
        self.plan, self.t_plan = None, 0.0
        self.failure, self.interrupted = "", False
        self.first_info: dict = {}

    def first_plan(self) -> None:
        """The first plan, solved to convergence before the clock starts (as a robot plans
        before it moves), seeded by the task's continuation if any (not over a given
        warm-start plan), with the derivative settings this run uses."""
        ctrl, solver, x = self.ctrl, self.ctrl.solver, self.x
        t0 = time.perf_counter()
        stages = ctrl.task.stages() if ctrl.U_ref is None else []  # the planner's
        for stage in stages:
            s_stage = dataclasses.replace(
                stage.config.solver,
                threads=solver.threads,
                derivatives=solver.derivatives,
                derivative_interval=solver.derivative_interval,
            )
            try:
                problem = Problem(stage.dynamics, stage.cost, x, 0.0)
                ctrl.seed(ilqr_solve(problem, ctrl.U, s_stage, final_gains=False).U)
            except SimulationError:
                break  # plan from the controls so far
        self.plan, ok = ctrl.update(x, 0.0, solver.max_iterations, full=True)
        if self.plan is None:
            raise SimulationError("mpc: the first plan failed")
        given = self.settings.warm_start_plan
        self.first_info = {
            "from": f"warm_start_plan {given}"
            if given
            else f"initial_guess {describe_guess(ctrl.task.config.initial_guess)}",
            "continuation_stages": len(stages),
            "iterations": int(self.plan.iterations),
            "max_iterations": int(solver.max_iterations),
            "status": self.plan.status,
            "cost": float(self.plan.final_cost),
            "seconds": round(time.perf_counter() - t0, 3),
        }

    def advance(self, n: int, plan: Solution, t_plan: float) -> None:
        """Simulates up to n steps under ``plan``'s policy (measured at ``t_plan``)."""
        dt, fb, r = self.dt, self.settings.feedback_scale, self.substeps
        for _ in range(n):
            if self.k >= self.total:
                return
            # Index into the plan by the time elapsed since its state was measured: the plan
            # step's feed-forward, feedback against the plan's state at this time.
            j = max(self.k - int(round(t_plan / dt)), 0)
            i = min(j // r, plan.U.shape[0] - 1)
            x_ref = plan.X[i]
            if r > 1 and j // r == i:  # between plan steps: the plan's state interpolated
                a = (j % r) / r
                x_ref = (1.0 - a) * plan.X[i] + a * plan.X[i + 1]
            u = plan.U[i] - fb * (plan.K[i] @ (self.x - x_ref))
            if not np.all(np.isfinite(u)):
                raise SimulationError("the controller produced a non-finite input")
            self.U_asked.append(u)
            self.x, u = self.truth.step(self.x, u, self.k, self.settings.pushes)
            self.X.append(self.x)
            self.U.append(u)
            self.k += 1

    def run(self, on_update=None) -> MPCResult:
        """The first plan (``first_plan``, before the clock starts), then updates and simulates
        to the end (or a simulation failure, or Ctrl+C)."""
        if self.plan is None:
            self.first_plan()
        wall0 = time.perf_counter()
        first = True
        try:
            while self.k < self.total:
                t_now = self.k * self.dt
                if not first:
                    if not self.update(t_now):
                        break
                else:
                    self.solve_s.append(0.0)
                    self.iters.append(self.plan.iterations)
                    self.upd_t.append(0.0)
                    first = False
                # Run to the next update time (one period after this update began; in
                # real-time mode the latency already simulated counts towards it).
                k_update = int(round(t_now / self.dt))
                if not self.simulate(max(0, k_update + self.period_steps - self.k)):
                    break
                if on_update is not None:
                    on_update(self.k, self.total)
        except KeyboardInterrupt:  # Ctrl+C: stop here and keep the run so far
            self.interrupted = True
            if not self.U:
                raise  # nothing simulated yet: nothing to keep
            del self.X[len(self.U) + 1 :]
            n = min(len(self.upd_t), len(self.solve_s), len(self.iters))
            del self.upd_t[n:], self.solve_s[n:], self.iters[n:]
        return self.result(time.perf_counter() - wall0)

    def update(self, t_now: float) -> bool:
        """A control update at t_now; in real-time mode the old policy runs meanwhile.
        False if the simulation failed."""
        s = self.settings
        t0 = time.perf_counter()
        # Only where latency is felt: lock-step runs stay reproducible.
        on = s.deadline and s.realtime
        deadline = t0 + s.deadline / s.rate if on else None
        K = self.settings.iterations_per_update  # later updates: at most K iterations
        ahead = self.period_steps if (s.realtime and s.delay_compensation) else 0
        x_from, t_from = (
            (self.predict(ahead), t_now + ahead * self.dt) if ahead else (self.x, t_now)
        )
        if x_from is None:  # the prediction failed: plan from the measured state
            x_from, t_from, ahead = self.x, t_now, 0
        new_plan, ok = self.ctrl.update(x_from, t_from, K, deadline=deadline)
        w = time.perf_counter() - t0
        self.failures += 0 if ok else 1
        self.solve_s.append(w)
        self.iters.append(new_plan.iterations if (ok and new_plan) else 0)
        self.upd_t.append(t_now)
        # The old policy keeps running while the controller thinks (with delay compensation,
        # at least until the time the new plan starts from).
        if s.realtime and not self.simulate(max(int(math.ceil(w / self.dt)), ahead)):
            return False
        if ok:
            self.plan, self.t_plan = new_plan, t_from
        return True

    def predict(self, n: int) -> np.ndarray | None:
        """The state the plan in force is expected to reach n simulation steps from now: the
        controller's model (on the plan's grid) under that plan's policy from the measured
        state; None if that rollout fails."""
        plan, r = self.plan, self.substeps
        i = max(self.k - int(round(self.t_plan / self.dt)), 0) // r
        j = np.minimum(np.arange(i, i + n // r), plan.U.shape[0] - 1)  # (past its end: the last)
        K = self.settings.feedback_scale * plan.K[j]
        Xbar = plan.X[np.append(j, j[-1] + 1)]
        try:
            X, _ = self.ctrl.dyn.closed_loop_rollout(
                self.x, plan.U[j], Xbar, K, np.zeros_like(plan.U[j]), 0.0
            )
        except SimulationError:
            return None
        return X[-1]

    def simulate(self, n: int) -> bool:
        """``advance`` under the plan in force; False (and the failure kept) if the
        simulation failed."""
        try:
            self.advance(n, self.plan, self.t_plan)
        except SimulationError as e:
            self.failure = f"t = {self.k * self.dt:.3f} s: {e}"
            return False
        return True

    def result(self, wall: float) -> MPCResult:
        """The run so far; the first (pre-start) solve is reported separately and not
        counted in the percentiles."""
        ctrl = self.ctrl
        return MPCResult(
            np.array(self.X),
            np.array(self.U),
            self.dt * np.arange(len(self.X)),
            self.upd_t[1:],
            self.solve_s[1:],
            self.iters[1:],
            self.failures,
            wall,
            self.settings,
            self.failure,
            ctrl.derivative_steps[1:],
            ctrl.reused_prediction[1:],
            ctrl.phases[1:],
            self.interrupted,
            ctrl.past_deadline,
            self.truth.saturated / max(1, self.truth.commands),
            ctrl.restarts,
            np.array(self.U_asked[: len(self.U)]),
            self.first_info,
        )
