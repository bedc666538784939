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

import numpy as np
from pydrake.multibody.math import SpatialForce
from pydrake.multibody.plant import ExternallyAppliedSpatialForce

from hydroilqr import metrics as metrics_mod
from hydroilqr.control.ilqr_planner import Controller, UpdateResult
from hydroilqr.control.mpc_settings import (
    Push,
    check_settings,
    controller_solver,
    mpc_config,
    plan_controls,
    planning_task,
    simulation_step,
)
from hydroilqr.control.sampling_planner import SamplingPlanner
from hydroilqr.metrics.common import SATURATION_WARNING, beyond_limits
from hydroilqr.model.guess import describe as describe_guess
from hydroilqr.model.names import find_body
from hydroilqr.model.plant import Dynamics, SimulationError
from hydroilqr.model.task import Problem
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.load import with_overrides
from hydroilqr.problem.mpc import MPCConfig, PlannerSettings
from hydroilqr.problem.task import validate_for_solve
from hydroilqr.solver.loop import solve as ilqr_solve
from hydroilqr.solver.solution import PHASES, Solution

__all__ = [
    "SATURATION_WARNING",
    "SMOKE_UPDATES",
    "ClosedLoop",
    "Controller",
    "MPCResult",
    "Push",
    "Truth",
    "UpdateResult",
    "check_settings",
    "controller_solver",
    "loop_metrics",
    "mpc_config",
    "plan_controls",
    "planning_task",
    "prepare",
    "run_mpc",
    "simulation_step",
]


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
    # mpc.planner sampling / hybrid: per update, the sampler's samples, seconds and costs
    sampling: list[dict] = field(default_factory=list)
    # process (CPU) seconds of each update, all threads of this process: unlike the wall
    # seconds, not lengthened by other processes on a shared machine
    cpu_seconds: list[float] = field(default_factory=list)

    def _achieved_rate(self, sim: float, period: float) -> float:
        """Updates after the first plan per second of the time they could have run in: the
        last update slot is one period before the end, so a loop whose one slow update let
        the plant run the rest of the horizon on one plan reports that, not the rate of the
        slot it started in."""
        span = max(self.update_times[-1] if self.update_times else 0.0, sim - period)
        return len(self.solve_seconds) / span if span > 0 else 0.0

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
            "achieved_rate_hz": self._achieved_rate(sim, period),
            "horizon_s": self.settings.horizon,
            "iterations_per_update": self.settings.iterations_per_update,
            "mean_iterations": float(np.mean(self.iterations)) if self.iterations else 0.0,
            "realtime_mode": self.settings.realtime,
            "lockstep_latency_s": self.settings.lockstep_latency,
            "delay_compensation": self.settings.delay_compensation,
            "threads": self.settings.threads,
            "derivatives": self.settings.derivatives,
            "solve_seconds": _percentiles(list(s)),
            "solve_cpu_seconds": _percentiles(self.cpu_seconds),
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
            "planner": self.settings.planner,
            "sampling": sampling_stats(self.sampling),
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


def _percentiles(seconds: list[float]) -> dict | None:
    """p50, p95, max and mean of per-update seconds (None: no update)."""
    if not seconds:
        return None
    s = np.array(seconds, float)
    return {
        "p50": float(np.percentile(s, 50)),
        "p95": float(np.percentile(s, 95)),
        "max": float(s.max()),
        "mean": float(s.mean()),
    }


def sampling_stats(per_update: list[dict]) -> dict | None:
    """The sampler's per-update numbers summed up (None for the iLQR planner): samples per
    update, the sampling's seconds per update (p50, mean) and samples per second (of the
    updates after the first plan), the mean iLQR iterations of a hybrid update."""
    if not per_update:
        return None
    n = np.array([u["samples"] for u in per_update], float)
    s = np.array([u["sampling_seconds"] for u in per_update], float)
    return {
        "updates": len(per_update),
        "samples_per_update_mean": float(n.mean()),
        "sampling_seconds_p50": float(np.percentile(s, 50)),
        "sampling_seconds_mean": float(s.mean()),
        "samples_per_second": float(n.sum() / s.sum()) if s.sum() > 0 else None,
        "ilqr_iterations_mean": float(np.mean([u["ilqr_iterations"] for u in per_update])),
    }


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
    ctrl = planner_of(planner, N, PlannerSettings.of(settings), solver, U_ref)
    h, _ = simulation_step(settings, dt)
    try:
        truth = Truth(task, settings.truth_overrides, h)
    except ConfigError as e:  # e.g. a body the overrides name that the model lacks
        if not settings.truth_overrides:
            raise
        raise ConfigError(f"mpc.truth_overrides (--truth-set): {e}") from None
    return ClosedLoop(task, settings, ctrl, truth)


def _as_checked(settings: MPCConfig, task) -> bool:
    """Whether the settings ``validate_mpc`` checks (the planner's and the goal) are the task's
    own ``mpc:`` section's, checked when the task was built (e.g. the command line changed
    only the loop's rate or duration); a warm-start plan's path is compared as given."""

    def checked_part(m: MPCConfig) -> tuple:
        return dataclasses.replace(PlannerSettings.of(m), warm_start_plan=""), m.goal

    return checked_part(settings) == checked_part(task.config.mpc)


def planner_of(task, N: int, settings: PlannerSettings, solver, U_ref):
    """The loop's planner (``mpc.planner``): the iLQR ``Controller`` or a ``SamplingPlanner``
    (sampling, hybrid); ConfigError for settings only the iLQR planner has."""
    if settings.planner == "ilqr":
        return Controller(task, N, settings, solver, U_ref)
    for given, what in (
        (settings.shrinking_horizon, "shrinking_horizon"),
        (settings.warm_start_plan, "warm_start_plan"),
        (settings.candidates, "candidates"),
    ):
        if given:
            raise ConfigError(
                f"mpc.{what}: the ilqr planner's (mpc.planner {settings.planner} samples a "
                "receding horizon from the task's guess and its own shifted plans)"
            )
    return SamplingPlanner(task, N, settings, solver)


def run_mpc(task, settings: MPCConfig | None = None, on_update=None) -> MPCResult:
    """Runs the closed loop for ``settings.duration`` seconds of simulated time (``prepare``:
    the settings). ``on_update(k, n)``: called with the time steps simulated so far and in
    all."""
    return prepare(task, settings).run(on_update)


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
        self.cpu_s: list[float] = []  # process time of each update after the first plan
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
        seeded = ctrl.U_ref is not None or not getattr(ctrl, "uses_stages", True)
        stages = [] if seeded else ctrl.task.stages()  # the planner's
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
            del self.upd_t[n:], self.solve_s[n:], self.iters[n:], self.cpu_s[max(0, n - 1) :]
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
        late = s.realtime or s.lockstep_latency > 0  # the old plan runs during the update
        ahead = self.period_steps if (late and s.delay_compensation) else 0
        x_from, t_from = (
            (self.predict(ahead), t_now + ahead * self.dt) if ahead else (self.x, t_now)
        )
        if x_from is None:  # the prediction failed: plan from the measured state
            x_from, t_from, ahead = self.x, t_now, 0
        c0 = time.process_time()
        new_plan, ok = self.ctrl.update(x_from, t_from, K, deadline=deadline)
        self.cpu_s.append(time.process_time() - c0)
        w = time.perf_counter() - t0
        self.failures += 0 if ok else 1
        self.solve_s.append(w)
        self.iters.append(new_plan.iterations if (ok and new_plan) else 0)
        self.upd_t.append(t_now)
        # The old policy keeps running while the controller thinks (with delay compensation,
        # at least until the time the new plan starts from); lock-step: for lockstep_latency.
        felt = w / self.dt if s.realtime else s.lockstep_latency / self.dt - 1e-9
        if late and not self.simulate(max(int(math.ceil(felt)), ahead)):
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
            list(getattr(ctrl, "sampling", [])[1:]),
            list(self.cpu_s),
        )
