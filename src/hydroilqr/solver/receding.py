"""Receding-horizon solves (paper §IV-A): solve a W-step window, keep its first S steps, shift
the start by S steps, warm-start the next window with the previous controls shifted by S (the
last control repeated at the end, or the task's initial guess there: ``warm_start_tail``),
repeat R times. The result has R·S steps. A warm start that cannot be rolled out from the kept
state is replaced by the task's initial guess (a cold start, recorded in the window's entry).
With ``rescue_factor`` > 0, a window whose cost ends above that factor times the median of the
previous (up to ``RESCUE_WINDOWS``) windows' costs is solved on from where it stopped, for up
to ``rescue_iterations`` more iterations, and the better result is kept (``rescue`` in the
window's entry): the few iterations a window gets refine a motion that goes well, not one that
has started to go wrong.

After each resolve the run's state (a ``Checkpoint``) goes to ``on_checkpoint``; the command
line writes it as ``checkpoint.npz`` in the run directory (``output.results.write_checkpoint``:
this module reads checkpoints and writes none), so an interrupted run continues where it
stopped and ends with the same trajectory as an uninterrupted one.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hydroilqr.io.environment import environment
from hydroilqr.io.files import content_hash
from hydroilqr.model.plant import SimulationError
from hydroilqr.model.task import Problem
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.guess import GUESS_KEYWORDS
from hydroilqr.problem.inputs import MAX_ARRAY_FILE_BYTES, MAX_MODEL_BYTES, check_npz, read_bounded
from hydroilqr.problem.solver import SolverConfig
from hydroilqr.solver import stopping
from hydroilqr.solver.ilqr import IterationInfo
from hydroilqr.solver.loop import solve
from hydroilqr.solver.solution import PHASES, Solution

CHECKPOINT = "checkpoint.npz"
#: How many previous windows' costs the rescue test compares a window's cost with.
RESCUE_WINDOWS = 5


@dataclasses.dataclass
class Checkpoint:
    """A receding-horizon run after ``done`` resolves of S steps (what ``checkpoint.npz``
    holds). X: [1 + done*S, nx], U: [done*S, nu], K: [done*S, nu, nx], kappa: [done*S, nu]
    (the kept steps so far), guess: [W, nu] (the next window's warm start)."""

    X: np.ndarray
    U: np.ndarray
    K: np.ndarray
    kappa: np.ndarray
    guess: np.ndarray
    done: int = 0
    costs: list = dataclasses.field(default_factory=list)  # every iteration's cost, in order
    iteration_seconds: list = dataclasses.field(default_factory=list)
    phase_seconds: dict = dataclasses.field(default_factory=lambda: {p: [] for p in PHASES})
    resolves: list = dataclasses.field(default_factory=list)  # per window: iterations, ...
    fingerprint: str = ""  # of the task (``fingerprint``): a resume must match it
    files: str = ""  # of the files the task reads (``files_fingerprint``)
    environments: list = dataclasses.field(default_factory=list)  # who computed which windows

    @classmethod
    def start(cls, x0: np.ndarray, guess: np.ndarray, nx: int, nu: int) -> Checkpoint:
        """No resolve done yet: x0: [nx], guess: [W, nu]."""
        return cls(
            X=x0[None, :].copy(),
            U=np.zeros((0, nu)),
            K=np.zeros((0, nu, nx)),
            kappa=np.zeros((0, nu)),
            guess=guess,
        )


def shift_guess(U: np.ndarray, shift: int) -> np.ndarray:
    """Warm start for the next window. U: [W, nu] -> [W, nu]."""
    return np.vstack([U[shift:], np.tile(U[-1], (shift, 1))])


def _warm_start(task, guess: np.ndarray, x0: np.ndarray, k0: int):
    """The window's initial controls and their rollout: the shifted previous window
    (guess: [W, nu]) or, if its rollout from x0: [nx] fails (a previous window can end in a
    motion that blows up once its last control is held longer), the task's initial guess for
    these time steps (from step k0). Returns (U: [W, nu], X: [W+1, nx], cold: bool); the
    SimulationError of the initial guess if that fails as well."""
    dyn = task.dynamics
    try:
        return guess, dyn.rollout(x0, guess), False
    except SimulationError:
        pass
    cold = task.initial_guess(guess.shape[0], x0, start=k0)
    try:
        return cold, dyn.rollout(x0, cold), True
    except SimulationError as e:
        raise SimulationError(
            f"initial rollout failed from the shifted previous window and from the task's "
            f"initial guess: {e}"
        ) from None


def solve_receding(
    task,
    callbacks: list[Callable[[IterationInfo], bool | None]] | None = None,
    checkpoint_dir: str | Path | None = None,
    on_resolve: Callable[[int, int, Solution], None] | None = None,
    solver: SolverConfig | None = None,
    U0: np.ndarray | None = None,
    on_checkpoint: Callable[[Checkpoint], None] | None = None,
) -> Solution:
    """Runs the task's receding-horizon schedule. Returns the stitched Solution.

    ``checkpoint_dir``: a directory whose ``checkpoint.npz`` (if there is one) the run
    continues; ``on_checkpoint(state)``: called after every resolve with the run's state, to
    be saved (``output.results.write_checkpoint``) for a later run to continue.

    ``U0``: the first window's guess, [W, nu] (default: the task's initial guess); a
    checkpoint being resumed keeps its own.

    ``solver``: the solver settings of every window (default: the task's ``solver``
    section); they are part of the checkpoint's fingerprint. The status of the stitched
    Solution is that of its worst window (see ``stopping.worst``): a run is only as good as
    its least successful window. A window warm-started from the previous one that did not
    improve on its start is judged by its stop test alone (its start was already a local
    minimum); the first window, and one started cold, must improve on the task's guess."""
    solver = solver or task.config.solver
    R = task.config.receding_horizon.resolves
    st = _start(task, checkpoint_dir, solver, U0)
    while st.done < R:
        sol, cold, wall, t_roll = _solve_window(task, solver, st, callbacks)
        _keep(task, st, sol, cold, wall, t_roll)
        if on_checkpoint is not None:
            on_checkpoint(st)
        if on_resolve is not None:
            on_resolve(st.done, R, sol)
    return _stitched(task, st, solver)


def _start(
    task, checkpoint_dir: str | Path | None, solver: SolverConfig, U0: np.ndarray | None = None
) -> Checkpoint:
    """The run's state before its next window: a fresh start, or the checkpoint in
    ``checkpoint_dir`` (if there is one), with the environment computing the windows to
    come recorded."""
    cfg = task.config
    W = cfg.receding_horizon.window_steps
    dyn = task.dynamics
    guess = task.initial_guess(W) if U0 is None else np.array(U0, float)
    st = Checkpoint.start(task.x0, guess, dyn.nx, dyn.nu)
    ck = Path(checkpoint_dir) / CHECKPOINT if checkpoint_dir else None
    run_id = fingerprint(cfg, solver)
    if ck is not None and ck.exists():
        st = load_checkpoint(task, ck.parent, solver)
    st.fingerprint = run_id
    st.files = files_fingerprint(cfg)
    # The environments that computed the windows (a resumed run may mix two: its results
    # then match neither, as last bits differ; summary.json's extra lists them).
    env = numeric_environment()
    envs = st.environments
    if st.done < cfg.receding_horizon.resolves and (not envs or envs[-1]["environment"] != env):
        envs.append({"from_resolve": st.done, "environment": env})
    return st


def _solve_window(task, solver: SolverConfig, st: Checkpoint, callbacks):
    """Solves window ``st.done`` from the last kept state, warm-started. Returns (its
    Solution, whether it started cold, its wall time, the seconds of its initial
    rollout(s))."""
    rh = task.config.receding_horizon
    r, dyn = st.done, task.dynamics
    x0 = st.X[-1]
    t0 = r * rh.shift_steps * dyn.dt
    max_it = solver.max_iterations if r == 0 else rh.max_iterations
    t_start = time.perf_counter()
    try:
        t_roll = time.perf_counter()
        guess, X0, cold = _warm_start(task, st.guess, x0, r * rh.shift_steps)
        t_roll = time.perf_counter() - t_roll  # the window's initial rollout(s)
        # final_gains: the kept steps' K, kappa are those of eq. (8) around the kept
        # trajectory (one more linearization per window), as playback --policy ilqr needs.
        # exactly the kept state (not re-normalized: the stitched X is a replay of U)
        problem = Problem(dyn, task.cost, x0, t0)
        sol = solve(problem, guess, solver, callbacks, max_it, final_gains=True, X0=X0)
        sol = _rescued(problem, sol, st, rh, solver, callbacks)
    except SimulationError as e:
        raise SimulationError(f"resolve {r}: {e}") from None
    return sol, cold, time.perf_counter() - t_start, t_roll


def _rescued(problem: Problem, sol: Solution, st: Checkpoint, rh, solver, callbacks) -> Solution:
    """``sol``, or with ``rh.rescue_factor`` > 0 and its cost above that factor times the
    median of the previous windows' costs: the window solved on from ``sol`` for up to
    ``rh.rescue_iterations`` more iterations, if that lowered the cost (its iterations
    appended to ``sol``'s). ``sol.extra["rescue"]`` records a rescue either way."""
    prev = [w["cost"] for w in st.resolves[-RESCUE_WINDOWS:] if w.get("cost") is not None]
    if (
        rh.rescue_factor <= 0
        or not prev
        or not sol.final_cost > rh.rescue_factor * float(np.median(prev))
    ):
        return sol
    try:
        on = solve(
            problem, sol.U, solver, callbacks, rh.rescue_iterations, final_gains=True, X0=sol.X
        )
    except SimulationError:  # the window as solved stands; a rescue never ends the run
        return sol
    kept = on.final_cost < sol.final_cost
    record = {
        "cost_before": sol.final_cost,
        "cost_after": on.final_cost,
        "iterations": on.iterations,
        "kept": bool(kept),
    }
    if not kept:  # (its time is in the window's wall time)
        sol.extra["rescue"] = record
        return sol
    joined = dataclasses.replace(
        on,
        costs=np.concatenate([sol.costs, on.costs[1:]]),
        iteration_seconds=list(sol.iteration_seconds) + list(on.iteration_seconds),
        phase_seconds={p: list(sol.phase_seconds[p]) + list(on.phase_seconds[p]) for p in PHASES},
        eps=list(sol.eps) + list(on.eps),
        mu=list(sol.mu) + list(on.mu),
        extra={**on.extra, "rescue": record},
    )
    # judged as one solve from the window's start (it improved on the warm start or not)
    joined.status = stopping.status(joined.reason, joined.costs)
    joined.converged = stopping.is_converged(joined.status)
    return joined


def _keep(task, st: Checkpoint, sol: Solution, cold: bool, wall: float, t_roll: float) -> None:
    """Appends the window's first S steps and its statistics to ``st``; sets the next
    window's warm start."""
    rh = task.config.receding_horizon
    W, S, r = rh.window_steps, rh.shift_steps, st.done
    st.X = np.vstack([st.X, sol.X[1 : S + 1]])
    st.U = np.vstack([st.U, sol.U[:S]])
    st.K = np.concatenate([st.K, sol.K[:S]])
    st.kappa = np.vstack([st.kappa, sol.kappa[:S]])
    st.guess = shift_guess(sol.U, S)
    if rh.warm_start_tail == "guess":  # the next window's last S steps: the task's guess
        k_end = (r + 1) * S + W  # the time step after the next window's end
        st.guess[W - S :] = task.initial_guess(S, st.X[-1], start=k_end - S)
    st.costs += [float(c) for c in sol.costs[1:]]
    st.iteration_seconds += sol.iteration_seconds
    if sol.iteration_seconds:  # counted in the first iteration, as in a single solve
        sol.iteration_seconds[0] += t_roll
        sol.phase_seconds["rollout"][0] += t_roll
    for p in PHASES:
        st.phase_seconds[p] += sol.phase_seconds[p]
    status, converged = sol.status, sol.converged
    if r > 0 and not cold and status == "no_progress":
        # A warm start that is already a local minimum is the window's answer, not a failure.
        status = stopping.status(sol.reason, sol.costs, require_improvement=False)
        converged = stopping.is_converged(status)
    st.resolves.append(
        {
            "iterations": sol.iterations,
            "seconds": wall,
            "cost": sol.final_cost,
            "converged": converged,
            "reason": sol.reason,
            "status": status,
            **({"cold_start": True} if cold else {}),
            **({"rescue": sol.extra["rescue"]} if "rescue" in sol.extra else {}),
        }
    )
    if r == 0:
        st.costs.insert(0, float(sol.costs[0]))
    st.done = r + 1


def _stitched(task, st: Checkpoint, solver: SolverConfig) -> Solution:
    """The run's Solution from its kept steps and per-window statistics."""
    res = st.resolves
    N = st.U.shape[0]
    status = stopping.worst([r_.get("status", "") for r_ in res]) if res else "failed"
    return Solution(
        X=st.X,
        U=st.U,
        K=st.K,
        kappa=st.kappa,
        t=task.dynamics.dt * np.arange(N + 1),
        costs=np.array(st.costs),
        iteration_seconds=st.iteration_seconds,
        phase_seconds=st.phase_seconds,
        converged=all(r_["converged"] for r_ in res) if res else False,
        reason=f"{sum(r_['converged'] for r_ in res)}/{len(res)} windows converged",
        derivatives=solver.derivatives,
        status=status,
        # costs are the windows' iteration costs one after another (final_cost: the last
        # window's); trajectory_cost is the task's cost (3a) of the stitched trajectory.
        extra={
            "resolves": res,
            "window_steps": task.config.receding_horizon.window_steps,
            "shift_steps": task.config.receding_horizon.shift_steps,
            "trajectory_cost": float(task.cost.total(st.X, st.U, 0.0)),
            "environments": st.environments,
        },
    )


def load_checkpoint(task, directory: str | Path, solver: SolverConfig | None = None) -> Checkpoint:
    """The saved state of an interrupted run of ``task`` in ``directory``; ConfigError if the
    checkpoint is missing, unreadable or from a different run (``solver``: the settings the
    run solves with, default the task's own)."""
    ck = Path(directory) / CHECKPOINT
    if not ck.exists():
        raise ConfigError(f"{directory}: no {CHECKPOINT} there to continue")
    try:
        st = _load(ck, raise_damage=False)  # reported after the consistency checks
    except ConfigError:
        raise
    except Exception as e:  # torn or foreign file
        raise ConfigError(
            f"{ck}: not a readable checkpoint ({type(e).__name__}); remove it to start over"
        ) from None
    known = (fingerprint(task.config, solver), fingerprint(task.config, solver, legacy=True))
    if st.fingerprint and st.fingerprint not in known:
        raise ConfigError(
            f"{directory}: its checkpoint is from a different run (task, --set or --smoke "
            "differ); repeat that run's arguments or choose another --out"
        )
    files = files_fingerprint(task.config)
    if st.files and st.files != files:  # (a checkpoint from before fingerprints: accepted)
        raise ConfigError(
            f"{directory}: a model or initial-guess file of the task changed since its "
            "checkpoint was written; resuming would mix two models (restore the file, or "
            "choose another --out)"
        )
    rh = task.config.receding_horizon
    done, S = st.done, rh.shift_steps
    nx, nu = task.dynamics.nx, task.dynamics.nu
    consistent = (
        isinstance(done, int)
        and 0 <= done <= rh.resolves
        and len(st.resolves) == done
        and st.X.shape == (1 + done * S, nx)
        and st.U.shape == (done * S, nu)
        and st.K.shape == (done * S, nu, nx)
        and st.kappa.shape == (done * S, nu)
        and st.guess.shape == (rh.window_steps, nu)
    )
    if not consistent:
        raise ConfigError(
            f"{ck}: its contents disagree with each other (resolves done {done!r}, "
            f"{st.X.shape[0]} states); remove it to start over"
        )
    if st._damage:
        raise ConfigError(f"{ck}: {st._damage}; remove it to start over")
    return st


def finished_run(directory: str | Path) -> bool:
    """True if ``directory`` holds a run that ran to the end: its summary.json was written
    after its last checkpoint (a rerun in place may start over without losing work)."""
    d = Path(directory)
    ck, summary = d / CHECKPOINT, d / "summary.json"
    return summary.exists() and (not ck.exists() or summary.stat().st_mtime >= ck.stat().st_mtime)


def fingerprint(cfg, solver: SolverConfig | None = None, legacy: bool = False) -> str:
    """What makes two runs the same computation: the resolved task (with ``solver`` for its
    solver section, if given) minus the settings that only change speed (threads, worker
    processes), other commands (mpc) or the report (metrics, their params, the goal).
    ``legacy``: as checkpoints written before the report's keys were left out computed it
    (they still resume)."""
    if solver is not None:
        cfg = dataclasses.replace(cfg, solver=solver)
    d = dataclasses.asdict(cfg)  # (not to_dict: checkpoints keep their fingerprints)
    d.pop("base_dir", None)
    for key in ("threads", "autodiff_workers", "line_search_workers"):
        d.get("solver", {}).pop(key, None)
    d.pop("mpc", None)
    d.pop("base_dir", None)
    # What only the report reads: a run that failed while reporting (a bad metric parameter,
    # say) is finished or re-reported from its checkpoint with the reporting corrected.
    report_keys = ("metrics", "metric_params", "description", "smoke")
    for key in ("goal", "smoke_run", *(() if legacy else report_keys)):
        d.pop(key, None)
    if not d.get("actuators"):
        d.pop("actuators", None)
    for m in d.get("models", []):
        if not m.get("name"):
            m.pop("name", None)
    # Keys added after checkpoints existed leave a fingerprint unchanged at their defaults.
    if (d.get("receding_horizon") or {}).get("warm_start_tail") == "last":
        del d["receding_horizon"]["warm_start_tail"]
    if (d.get("receding_horizon") or {}).get("rescue_factor") == 0:
        del d["receding_horizon"]["rescue_factor"]
        d["receding_horizon"].pop("rescue_iterations", None)
    if not (d.get("solver") or {}).get("fd_forces", True):
        del d["solver"]["fd_forces"]
    for o in d.get("scene", []):
        if not o.get("no_contact_with"):
            o.pop("no_contact_with", None)
    text = json.dumps(d, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def numeric_environment() -> dict:
    """What decides a run's last bits: code, package versions, BLAS kernels, vector units."""

    env = environment()
    keys = ("code", "drake", "numpy", "scipy", "blas_core", "cpu_features")
    return {k: env.get(k) for k in keys}


def environment_change(st: Checkpoint) -> str:
    """ "" if a checkpoint's state ``st`` (``load_checkpoint``) was computed in this
    environment, else what differs (a resumed run mixes both: bitwise reproducible in
    neither)."""
    envs = st.environments
    if not envs:
        return ""
    old, new = envs[-1]["environment"], numeric_environment()
    diff = [f"{k} {old.get(k)} -> {new.get(k)}" for k in new if old.get(k) != new.get(k)]
    return "; ".join(diff)


def files_fingerprint(cfg) -> str:
    """The contents of the files the task reads (model files given by path, an initial-guess
    file): a run resumed after one of them changed would mix two models."""
    h = hashlib.sha256()
    paths = [m.file for m in cfg.models if not m.file.startswith("package://")]
    if isinstance(cfg.initial_guess, str) and cfg.initial_guess not in GUESS_KEYWORDS:
        paths.append(cfg.initial_guess)
    for p in paths:
        f = cfg.resolve_path(p)
        h.update(str(p).encode())
        try:
            h.update(read_bounded(f, "file", MAX_MODEL_BYTES))
        except (OSError, ConfigError):
            h.update(b"<unreadable>")
    return h.hexdigest()[:16]


_ARRAYS = ("X", "U", "K", "kappa", "guess")


def checkpoint_arrays(st: Checkpoint) -> dict[str, np.ndarray]:
    """What ``checkpoint.npz`` holds for the state ``st`` (``output.results.write_checkpoint``
    writes it, ``_load`` reads it back): the arrays as arrays, the rest as JSON in ``meta``,
    and the content hash of both in ``sha256``."""
    meta = {f.name: getattr(st, f.name) for f in dataclasses.fields(st) if f.name not in _ARRAYS}
    arrays = {k: np.asarray(getattr(st, k)) for k in _ARRAYS}
    text = json.dumps(meta)
    return {**arrays, "meta": np.array(text), "sha256": np.array(content_hash(arrays, text))}


class CorruptCheckpoint(ValueError):
    """A checkpoint whose content does not match its hash, or holds non-finite values."""


def _load(path: Path, raise_damage: bool = True) -> Checkpoint:
    """Raises for a file that is not a checkpoint (missing arrays or meta, unknown keys), and
    CorruptCheckpoint for one changed since it was written (its content hash; checkpoints
    written before hashes have none and are accepted) or holding NaN or infinite values."""
    check_npz(path, "checkpoint", MAX_ARRAY_FILE_BYTES)
    with np.load(path, allow_pickle=False) as d:
        text = str(d["meta"])
        meta = json.loads(text)
        arrays = {k: np.array(d[k]) for k in _ARRAYS}
        saved = str(d["sha256"]) if "sha256" in d.files else None
    damage = ""
    if saved is not None and saved != content_hash(arrays, text):
        damage = "its content does not match its hash (changed since written)"
    for k, a in arrays.items():
        if not damage and (a.dtype.kind not in "fiu" or not np.all(np.isfinite(a))):
            damage = f"its {k} holds NaN, infinite or non-numeric values"
    if not isinstance(meta, dict):
        raise ValueError("meta is not a mapping")
    st = Checkpoint(**arrays, **meta)  # (older checkpoints lack some meta keys: defaults)
    if raise_damage and damage:
        raise CorruptCheckpoint(damage)
    st._damage = damage  # (not a field: never saved) load_checkpoint reports it
    return st
