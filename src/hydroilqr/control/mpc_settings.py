"""The settings of closed-loop MPC, checked before any solve: ``mpc_config`` (a task's
``mpc:`` section with overrides), ``check_settings`` (rate, horizon, time steps, pushes, the
simulated plant's overrides, a warm-start plan), ``planning_task`` (the controller's task) and
``controller_solver``; ``Push``, an external force of ``--push``. ``control/mpc.py`` runs the
loop with them.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from hydroilqr.io.rundir import previous_task
from hydroilqr.model.names import body_labels, find_body
from hydroilqr.problem.checks import MAX_STEPS, unknown_key
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.mpc import MPCConfig, validate_mpc
from hydroilqr.problem.solver import SolverConfig
from hydroilqr.problem.variants import check_truth_overrides
from hydroilqr.solver.solution import load_run_solution


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
    _check_latency(settings)
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


def _check_latency(settings: MPCConfig) -> None:
    """mpc.lockstep_latency: finite, >= 0, shorter than the run, and lock-step only."""
    lat = settings.lockstep_latency
    if isinstance(lat, bool) or not (math.isfinite(lat) and 0 <= lat < settings.duration):
        raise ConfigError(
            f"mpc.lockstep_latency: seconds from 0 to below the duration "
            f"({settings.duration:g} s), got {lat!r}"
        )
    if lat > 0 and settings.realtime:
        raise ConfigError(
            "mpc.lockstep_latency: lock-step only (--realtime feels the controller's own "
            "latency); add --set mpc.lockstep_latency=0 or --no-realtime"
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


def controller_solver(solver: SolverConfig, settings: MPCConfig) -> SolverConfig:
    """The task's solver settings with the controller's threads and derivatives."""
    return dataclasses.replace(
        solver,
        threads=settings.threads,
        derivatives=settings.derivatives or solver.derivatives,
        derivative_interval=settings.derivative_interval or solver.derivative_interval,
    )
