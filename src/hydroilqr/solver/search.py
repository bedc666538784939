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

import dataclasses
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
    ``search:`` section, else the defaults) over ``steps`` time steps (default: the task's)
    from state ``x0`` (default: the task's initial state) at step ``start`` (its time
    ``start·dt`` prices the cost). ``pin``: [nu] the first knot in position space (default:
    the start posture; a later window pins the target it continues from)."""

    def __init__(
        self,
        task,
        settings: SearchConfig | None = None,
        start: int = 0,
        steps: int | None = None,
        x0: np.ndarray | None = None,
        pin: np.ndarray | None = None,
    ):
        self.settings = settings or task.config.search or SearchConfig()
        cfg = self.settings
        dyn = task.dynamics
        self.start = int(start)
        self.N = int(steps) if steps is not None else task.steps
        self.dt = dyn.dt
        self.T = self.N * self.dt
        self.t0 = self.start * self.dt
        self.x0 = np.asarray(task.x0 if x0 is None else x0, float)
        self.K = min(int(cfg.knots), self.N)
        n = self.N if cfg.space == "torque" else self.N + 1
        self.W = splines.basis(self.K, self.dt * np.arange(n), self.T, cfg.order)
        self.knot_steps = np.minimum(
            np.round(splines.knot_times(self.K, self.T, cfg.order) / self.dt).astype(int),
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
            q0 = self.x0[self.qi] if pin is None else np.asarray(pin, float)
            self.lower, self.upper = np.tile(lo, (self.K, 1)), np.tile(hi, (self.K, 1))
            self.lower[0] = self.upper[0] = q0

    def nominal(self, task) -> np.ndarray:
        """θ0: [K, nu] from the task's initial guess: its controls at the knots' times
        (torque), or the joint positions its rollout reaches there (position)."""
        U0 = task.initial_guess(self.N, self.x0, start=self.start)
        if self.settings.space == "torque":
            return U0[self.knot_steps].copy()
        try:
            X0 = task.dynamics.rollout(self.x0, U0)
        except SimulationError:  # the guess blows up: hold the start posture
            X0 = np.tile(self.x0, (self.N + 1, 1))
        return np.clip(X0[self.knot_steps][:, self.qi], self.lower, self.upper)

    def decode(self, knots: np.ndarray) -> np.ndarray:
        """The command of knots θ: [K, nu]: U [N, nu] (torque) or Q_ref [N+1, nu] (position)."""
        return self.W @ knots

    def rollout(self, task, command: np.ndarray, x0=None, t0: float | None = None) -> Rollout:
        """The command's rollout on the task's plant from ``x0`` (default: the space's start
        state) and its cost from time ``t0`` (default: the space's start time; a
        SimulationError propagates). The command's length sets the steps."""
        return rollout(task, self.settings, command, self.x0 if x0 is None else x0,
                       self.t0 if t0 is None else t0)  # fmt: skip

    def cost(self, task, command: np.ndarray, x0=None, t0: float | None = None) -> float:
        """The command's cost; inf if its rollout fails."""
        try:
            return self.rollout(task, command, x0, t0).cost
        except SimulationError:
            return math.inf


def rollout(task, settings: SearchConfig, command: np.ndarray, x0, t0: float = 0.0) -> Rollout:
    """A command's rollout in ``settings.space`` on the task's plant from x0, and the task's
    cost of it from time t0 (a SimulationError propagates)."""
    dyn = task.dynamics
    if settings.space == "torque":
        U = dyn.clip_to_limits(np.asarray(command, float))
        X = dyn.rollout(x0, U)
    else:
        X, U = pd_rollout(dyn, x0, command, settings.kp, settings.kd)
    return priced(task, X, U, t0)


def priced(task, X: np.ndarray, U: np.ndarray, t0: float = 0.0) -> Rollout:
    """X, U and the task's cost of them from time t0 (inf if not finite)."""
    with np.errstate(all="ignore"):
        cost = float(task.cost.total(X, U, t0))
    return Rollout(X, U, cost if math.isfinite(cost) else math.inf)


def local_evaluator(task, space: SearchSpace):
    """``evaluate(commands, x0=None, t0=None) -> costs`` in this process, on the task's own
    plant (from ``x0`` at ``t0``; default: the space's start)."""

    def evaluate(commands, x0=None, t0=None):
        return [space.cost(task, c, x0, t0) for c in commands]

    return evaluate


def run_search(
    task, evaluate=None, settings: SearchConfig | None = None, on_iteration=None, on_window=None
):
    """(SearchSpace, SamplingResult): the task's search (``settings``: default its ``search:``
    section) with ``evaluate(commands, x0, t0)`` (default: ``local_evaluator``); the best
    ``search.polish`` distinct samples (at least 1) are kept as candidates. With
    ``search.window_steps`` the horizon is searched window by window (``receding``; its
    result is one candidate, the stitched command)."""
    cfg = settings or task.config.search or SearchConfig()
    if 0 < cfg.window_steps < task.steps:
        return receding(task, evaluate, cfg, on_iteration, on_window)
    space = SearchSpace(task, cfg)
    result = search_window(task, space, space.nominal(task), evaluate, max(1, cfg.polish),
                           on_iteration)  # fmt: skip
    return space, result


def restart_seed(seed: int, restart: int) -> int:
    """The seed of a search's restart ``restart`` (``search.restarts``; 0: ``seed`` itself):
    numpy's SeedSequence of (seed, restart), so that the restarts of a seed are independent of
    each other and of the searches seeded seed + 1, seed + 2, ... (robustness's other runs, a
    receding search's windows). -> an int in [0, 2**31)"""
    if restart == 0:
        return int(seed)
    return int(np.random.SeedSequence([int(seed), int(restart)]).generate_state(1)[0] >> 1)


def search_window(task, space: SearchSpace, nominal, evaluate=None, keep=1, on_iteration=None):
    """``sampling.search`` over ``space`` (its start state and time) from knots ``nominal``:
    [K, nu]; ``evaluate(commands, x0, t0)`` (default: this process)."""
    ev = evaluate or local_evaluator(task, space)
    return sampling.search(
        lambda commands: ev(commands, space.x0, space.t0),
        space.decode,
        nominal,
        space.scale,
        space.settings,
        space.lower,
        space.upper,
        keep=keep,
        on_iteration=on_iteration,
    )


def shifted_knots(space: SearchSpace, knots: np.ndarray, new: SearchSpace, shift: float):
    """The warm start of ``new`` from the best ``knots`` of ``space``: the old spline moved
    ``shift`` seconds earlier, read at the new knots' times (past its end, its last value
    holds), clipped to the new bounds (in position space the first knot is the pinned
    target). -> [K_new, nu]"""
    times = splines.knot_times(new.K, new.T, new.settings.order) + shift
    out = splines.evaluate(knots, times, space.T, space.settings.order)
    return np.clip(out, new.lower, new.upper)


def windows(N: int, window: int, shift: int) -> list[tuple[int, int, int]]:
    """The receding search's windows over N steps: (start, steps, kept) each; a window spans
    ``window`` steps (fewer at the end), keeps its first ``shift`` (the last keeps all)."""
    out, s = [], 0
    while s < N:
        W = min(window, N - s)
        kept = W if s + W >= N else min(shift, W)
        out.append((s, W, kept))
        s += kept
    return out


@dataclass
class WindowPlan:
    """One window's search: its space, result, and the steps it kept."""

    space: SearchSpace
    result: sampling.SamplingResult
    kept: int


def receding(task, evaluate=None, settings: SearchConfig | None = None, on_iteration=None,
             on_window=None):  # fmt: skip
    """Receding-horizon search (long motions): the horizon in windows of
    ``search.window_steps`` steps, each searched from the state the kept steps before it
    reach, its first ``search.shift_steps`` kept (0: half the window; the last window keeps
    all), the next warm-started by the best spline shifted (``shifted_knots``), in position
    space its first knot pinned at the target the kept command ends on, so the stitched
    command's rollout from the start is the windows' rollouts end to end. Window i's noise is
    seeded ``seed + i``. Returns (SearchSpace of the whole horizon, SamplingResult): best =
    the stitched command, its whole-horizon cost; ``costs`` and ``history`` every window's
    iterations (each entry with its ``window``, whose costs price that window only).
    ``on_window(info)`` after each window (start, steps, kept, cost, seconds); True stops."""
    cfg = settings or task.config.search or SearchConfig()
    whole = SearchSpace(task, cfg)
    shift = cfg.shift_steps or max(1, cfg.window_steps // 2)
    x, pin, prev = whole.x0, None, None
    pieces, plans = [], []
    interrupted = False
    for i, (start, steps, kept) in enumerate(windows(task.steps, cfg.window_steps, shift)):
        wcfg = dataclasses.replace(cfg, seed=cfg.seed + i)
        space = SearchSpace(task, wcfg, start, steps, x, pin)
        nominal = space.nominal(task) if prev is None else shifted_knots(*prev[:2], space, prev[2])
        tagged = _tagged(on_iteration, i, int(cfg.iterations))
        res = search_window(task, space, nominal, evaluate, 1, tagged)
        plans.append(WindowPlan(space, res, kept))
        command = res.best.command
        r = space.rollout(task, command)
        x = r.X[kept]
        pieces.append(command[:kept])
        if cfg.space == "position":
            pin = command[kept] if kept < steps else None
        prev = (space, res.best.knots, kept * space.dt)
        info = {"window": i, "start": start, "steps": steps, "kept": kept,
                "cost": res.best.cost, "seconds": res.seconds}  # fmt: skip
        if res.interrupted or (on_window is not None and on_window(info)):
            interrupted = True
            break
    return whole, _stitched(task, whole, plans, pieces, interrupted)


def _tagged(on_iteration, window: int, iterations: int):
    """The callback of window ``window``: its info with the window and the iteration
    counted over all windows (a progress bar's)."""
    if on_iteration is None:
        return None
    return lambda info: on_iteration(
        {**info, "window": window, "iteration": window * iterations + info["iteration"]}
    )


def total_iterations(config) -> int:
    """The iterations in all of a task's search (``config``: its TaskConfig; a receding
    search's over all its windows)."""
    cfg = config.search or SearchConfig()
    if not 0 < cfg.window_steps < config.steps:
        return int(cfg.iterations)
    shift = cfg.shift_steps or max(1, cfg.window_steps // 2)
    return int(cfg.iterations) * len(windows(config.steps, cfg.window_steps, shift))


def _stitched(task, whole: SearchSpace, plans: list, pieces: list, interrupted: bool):
    """The windows' kept commands end to end as one SamplingResult (over the steps done)."""
    command = np.concatenate(pieces)
    if whole.settings.space == "position":
        last = plans[-1]
        end = last.result.best.command[last.kept] if last.kept < last.space.N else command[-1]
        command = np.vstack([command, end[None]])  # targets at N+1 states
    cost = whole.cost(task, command)
    best = sampling.Candidate(plans[-1].result.best.knots, command, cost, 0, 0)
    history = [{**h, "window": w} for w, p in enumerate(plans) for h in p.result.history]
    rows = [p.result.costs for p in plans]
    return sampling.SamplingResult(
        best=best,
        candidates=[best],
        mean=plans[-1].result.mean,
        costs=np.concatenate(rows) if rows else np.zeros((0, whole.settings.samples)),
        history=history,
        interrupted=interrupted,
        seconds=float(sum(p.result.seconds for p in plans)),
        windows=[
            {
                "start": p.space.start,
                "steps": p.space.N,
                "kept": p.kept,
                "cost": p.result.best.cost,
                "seconds": p.result.seconds,
            }  # fmt: skip
            for p in plans
        ],
    )


def as_solution(task, space: SearchSpace, result: sampling.SamplingResult) -> Solution:
    """The best sample as a Solution (its rollout; no gains): ``costs`` the best cost after
    each iteration, led by the nominal's (``record`` says what the search did)."""
    r = space.rollout(task, result.best.command)
    costs = np.concatenate([result.costs[:1, 0], result.best_costs]) if result.history else [r.cost]
    if result.windows:  # (a receding search's iterations price windows, not the horizon)
        costs = [r.cost]
    return Solution(
        X=r.X,
        U=r.U,
        K=np.zeros(0),
        kappa=np.zeros(0),
        t=space.dt * np.arange(len(r.X)),
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
        "windows": result.windows,
        "candidates": [
            {"cost": c.cost, "iteration": c.iteration, "index": c.index} for c in result.candidates
        ],
    }
