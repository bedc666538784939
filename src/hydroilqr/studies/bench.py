"""``hydroilqr bench``: the paper's method against the project's fastest configuration.

For each task, both configurations start from the same initial guess and run the same number
of iLQR iterations *in the same process, alternating* (a block of iterations of one, then of
the other), so that load from other processes hits both alike:

(a) the paper's method: TAMSI contact, AutoDiffXd derivatives, one time step after another;
(a') the paper's method on (b)'s contact solver (``PAPER_SAME_SOLVER``: AutoDiffXd, serial,
     every step, no interpolation, and (b)'s ``plant.contact_approximation``), so that the
     ratio a'/b is what hydroilqr's derivatives and solver gain, not what Drake's SAP gains;
(b) the fast configuration (``FAST``, or ``--fast KEY=VALUE`` overrides).
Path (a) needs a Drake with TAMSI (``drake_has_tamsi``); on one without it, (a) and the
timing at (b)'s iterates (``SameIterates``, (a)'s method) are skipped with a note in
bench.json, and (a') and (b) run as always.

The solves run in Python threads (in the order (a), (b), (a')) that hand a baton on from the
solver's per-iteration callback; only the holder of the baton computes, and iteration times are
taken inside the solver (the wait is outside them). Receding-horizon tasks are benchmarked on their
first window (``window_steps``).

Outputs in ``--out``: ``bench.json`` (per task: per-iteration median and p10/p90, phase shares,
speed-ups a/b and a'/b, final costs and their relative differences, contact polygons,
derivative accuracy against AutoDiff, FD thread scaling, and the limit analysis of
``limit_analysis``) and ``iterations.png`` (box plots, paper Fig. 8).
"""

from __future__ import annotations

import dataclasses
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hydroilqr.io.environment import environment
from hydroilqr.io.figures import pyplot, savefig
from hydroilqr.metrics import validate_task
from hydroilqr.model import workers
from hydroilqr.model.derivatives import (
    _finite_differences,
    _force_differences,
    autodiff_serial,
    keypoints,
    linearize,
    num_threads,
)
from hydroilqr.model.plant import SimulationError, hydroelastic_kind
from hydroilqr.model.task import Task
from hydroilqr.output.report import output_dir
from hydroilqr.output.studies import write_bench
from hydroilqr.problem.capabilities import drake_has_tamsi, no_tamsi_message
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.load import load_task
from hydroilqr.problem.solver import DerivativeMethod
from hydroilqr.solver.ilqr import backward_pass
from hydroilqr.solver.loop import solve
from hydroilqr.solver.solution import PHASES

plt = pyplot()

PAPER = [
    "plant.contact_approximation=tamsi",
    "solver.derivatives=autodiff",
    "solver.derivative_interval=1",
    "solver.autodiff_workers=1",  # serial, one step after another
    "solver.line_search_workers=1",  # one trial after another
    "solver.derivative_reuse_tolerance=0",
    "solver.derivative_secant_updates=0",  # exact partials every iteration
]
# (a'): the paper's method on the fast configuration's contact solver (its
# plant.contact_approximation is appended per task by ``bench_tasks``).
PAPER_SAME_SOLVER = [c for c in PAPER if not c.startswith("plant.contact_approximation=")]
# The fast configuration (docs/performance.md), on the task's own contact approximation (what
# its users run: SAP for the cart-pole and the cheetah, "similar" for kinova-forward and
# kinova-left); the cheaper
# of AutoDiff (in one worker process per core) and batched forward differences (on threads),
# chosen per task by a short probe
# (``probe_derivatives``; ``--fast solver.derivatives=...`` skips it); exact derivatives at
# every other step and on both sides of every contact event, interpolated in between; the
# task's own solver.derivative_secant_updates (Kinova: secant partials between exact ones).
# (``--fast solver.fd_forces=true``: finite differences over generalized forces, see
# docs/performance.md.)
FAST = [
    "solver.derivative_interval=2",
    "solver.derivative_adaptive=true",
    "solver.autodiff_workers=0",
]


# ------------------------------------------------------------------------------------------
# Alternating runner
# ------------------------------------------------------------------------------------------


class _Baton:
    """Runners take turns in order (0, 1, ..., n-1, 0, ...); a finished runner is skipped and
    never blocks the others."""

    def __init__(self, n: int = 2):
        self.cond = threading.Condition()
        self.turn = 0
        self.done = [False] * n

    def _next(self, i: int) -> int:
        n = len(self.done)
        for j in range(1, n + 1):
            if not self.done[(i + j) % n]:
                return (i + j) % n
        return i

    def wait(self, i: int) -> None:
        with self.cond:
            self.cond.wait_for(lambda: self.turn == i)

    def give(self, i: int) -> None:
        with self.cond:
            self.turn = self._next(i)
            self.cond.notify_all()

    def finish(self, i: int) -> None:
        with self.cond:
            self.done[i] = True
            if self.turn == i:
                self.turn = self._next(i)
            self.cond.notify_all()


def run_alternating(tasks, U0, iterations: int, block: int = 1, shadow=None) -> list:
    """Solves each of ``tasks`` (two or more) from U0 for ``iterations`` iterations, taking
    turns in blocks of ``block`` iterations (tasks[0], tasks[1], ...). Returns [Solution or
    Exception, ...] in the order of ``tasks``; a task that is None (a path this Drake cannot
    run) is skipped and its result is None.

    ``shadow(U, mu)``, if given, is called in (b)'s turn after each of (b)'s iterations with the
    nominal controls U: [N, nu] that iteration started from (U0, then (b)'s iterates) and the μ
    it started with, outside (b)'s timed iterations (``same_iterates``): one call per
    iteration (b) ran, also when (b) stops early."""

    baton = _Baton(len(tasks))
    results: list = [None] * len(tasks)

    def runner(i: int) -> None:
        task = tasks[i]
        count = [0]

        def cb(info) -> None:
            count[0] += 1
            if shadow is not None and i == 1:
                shadow(*pending[0])  # the nominal this iteration started from
                if info is not None:
                    pending[0] = (info.U.copy(), info.mu)
            if count[0] % block == 0:
                baton.give(i)
                baton.wait(i)

        pending = [None]
        if task is None:
            baton.finish(i)
            return
        try:
            baton.wait(i)
            if shadow is not None and i == 1:
                pending[0] = (U0.copy(), task.config.solver.regularization_init)
            results[i] = solve(
                task.problem(),
                U0.copy(),
                task.config.solver,
                [cb],
                max_iterations=iterations,
                final_gains=False,
            )
        except Exception as e:  # noqa: BLE001 - reported per task
            results[i] = e
        finally:
            baton.finish(i)

    threads = [threading.Thread(target=runner, args=(i,), daemon=True) for i in range(len(tasks))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return results


class SameIterates:
    """The paper's method timed at the fast run's own iterates: one iteration of (a) from each
    nominal U that an iteration of (b) starts from (with (b)'s μ there), so both methods are
    timed on the same trajectories and contact configurations. (The alternating runs compare
    each method on its own path, which can differ: a TAMSI run that has not yet reached
    contact differentiates cheap contact-free steps.) The time counted is the iteration's
    without its initial rollout (in a normal run the nominal comes from the line search)."""

    def __init__(self, task):
        self.task = task
        self.solver = task.config.solver
        self.seconds: list[float] = []
        self.phases: dict[str, list[float]] = {p: [] for p in PHASES}
        self.polygons: list[int] = []
        self.errors: list[str] = []

    def __call__(self, U: np.ndarray, mu: float) -> None:
        settings = dataclasses.replace(self.solver, regularization_init=float(mu))
        try:
            sol = solve(self.task.problem(), U, settings, max_iterations=1, final_gains=False)
        except (SimulationError, ValueError, ConfigError) as e:
            self._failed(str(e).strip().splitlines()[0])
            return
        if not sol.iteration_seconds:
            self._failed(sol.reason)
            return
        ph = {p: float(sol.phase_seconds[p][0]) for p in PHASES}
        self.seconds.append(float(sol.iteration_seconds[0]) - ph["rollout"])
        ph["rollout"] = 0.0
        for p in PHASES:
            self.phases[p].append(ph[p])
        try:  # the nominal it started from (a rollout that just succeeded inside solve)
            X = self.task.dynamics.rollout(self.task.x0, U)
            self.polygons.append(max(contact_state(self.task.dynamics, x)[0] for x in X))
        except SimulationError:
            self.polygons.append(-1)

    def _failed(self, why: str) -> None:
        """A shadow iteration that could not run: NaN in its place (alignment with (b))."""
        self.errors.append(why)
        self.seconds.append(float("nan"))
        for p in PHASES:
            self.phases[p].append(float("nan"))
        self.polygons.append(-1)

    def stats(self, fast) -> dict:
        """Against the fast run's Solution ``fast`` (its iterations without their rollout
        phase, which only the first one has)."""
        a = np.asarray(self.seconds, float)
        b = np.asarray(fast.iteration_seconds, float) - np.asarray(fast.phase_seconds["rollout"])
        n = min(a.size, b.size)  # equal unless (b) failed inside an iteration
        out: dict = {"iterations": int(a.size), "errors": self.errors}
        ok = np.isfinite(a[:n])  # iteration pairs where both methods ran
        if not ok.any():
            return out
        a, b = a[:n][ok], b[:n][ok]
        phases = {p: np.asarray(v[:n], float)[ok] for p, v in self.phases.items()}
        out.update(
            {
                "paper_iteration_seconds": [float(v) for v in a],
                "paper_median_s": float(np.median(a)),
                "paper_phase_median_s": {p: float(np.median(v)) for p, v in phases.items()},
                "paper_max_faces": [int(v) for v, k in zip(self.polygons, ok) if k],
                "fast_median_s": float(np.median(b)),
                "speedup_median": float(np.median(a) / np.median(b)),
            }
        )
        return out


# ------------------------------------------------------------------------------------------
# Contact polygons and derivative accuracy
# ------------------------------------------------------------------------------------------


def contact_state(dyn, x: np.ndarray) -> tuple[int, str]:
    """(contact polygons at x, class): class is "free", "compliant-rigid" (AutoDiff exact)
    or "compliant-compliant"/"point" (AutoDiff approximate, see drake-notes.md). A geometry
    query only: no contact solve, so it works for any state and contact solver."""
    surfaces, points = dyn.contact_query(x)
    inspector = dyn.scene_graph.model_inspector()
    faces, cls = 0, "free"
    for s in surfaces:
        faces += s.num_faces()
        kinds = {
            hydroelastic_kind(inspector.GetProximityProperties(g)) for g in (s.id_M(), s.id_N())
        }
        if kinds == {"compliant"}:
            cls = "compliant-compliant"
        elif cls == "free":
            cls = "compliant-rigid"
    if points:
        faces += len(points)
        cls = "point"
    return faces, cls


def polygons(dyn, X: np.ndarray) -> dict:
    """Contact polygon counts (max, mean, per state) along X: [T, nx]."""
    states = [contact_state(dyn, x) for x in X]
    faces = [f for f, _ in states]
    return {
        "max_faces": int(max(faces, default=0)),
        "mean_faces": float(np.mean(faces)),
        "contact_steps": int(sum(f > 0 for f in faces)),
    }


def derivative_accuracy(task, X, U, threads: int, intervals=(2, 4)) -> dict:
    """Relative error of forward/central/interval-k derivatives against AutoDiff along (X, U),
    max and median over the steps of each contact class (error at step k:
    max|J − J_AD| / max|J_AD|, J = [A B])."""

    dyn = task.dynamics
    s = task.config.solver
    N = U.shape[0]
    classes = [contact_state(dyn, x)[1] for x in X[:N]]

    def jac(method, interval=1, adaptive=False):
        t = time.perf_counter()
        A, B = linearize(
            dyn,
            X,
            U,
            method,
            s.fd_epsilon,
            threads,
            interval,
            rollout=True,
            adaptive=adaptive,
            autodiff_workers=s.autodiff_workers,
            fd_forces=s.fd_forces,
        )
        return np.concatenate([A, B], axis=2), time.perf_counter() - t

    ref, t_ad = jac("autodiff")
    scale = np.maximum(np.abs(ref).reshape(N, -1).max(axis=1), 1e-12)
    out: dict = {
        "reference": "autodiff",
        "contact_classes": {c: int(classes.count(c)) for c in sorted(set(classes))},
        "seconds": {"autodiff": t_ad},
    }
    modes = [("forward", "forward", 1, False), ("central", "central", 1, False)]
    modes += [(f"interval-{k} ({s.derivatives})", s.derivatives, k, False) for k in intervals]
    modes += [(f"adaptive-{k} ({s.derivatives})", s.derivatives, k, True) for k in intervals]
    for label, method, k, adaptive in modes:
        J, sec = jac(method, k, adaptive)
        err = np.abs(J - ref).reshape(N, -1).max(axis=1) / scale
        out["seconds"][label] = sec
        by = {
            c: np.array([e for e, cc in zip(err, classes) if cc == c]) for c in sorted(set(classes))
        }
        by["all"] = err
        out[label] = {
            "max": {c: float(v.max()) for c, v in by.items()},
            "median": {c: float(np.median(v)) for c, v in by.items()},
        }
    return out


def thread_scaling(task, X, U, threads: int, repeats: int = 3) -> dict:
    """Seconds of the batched FD derivative phase with 1 and ``threads`` threads (alternated,
    median of ``repeats``)."""

    dyn = task.dynamics
    s = task.config.solver
    method = DerivativeMethod(s.derivatives)
    if method is DerivativeMethod.AUTODIFF:  # threads serve the finite differences only
        method = DerivativeMethod.FORWARD
    counts = sorted({1, num_threads(threads)})
    times: dict[int, list[float]] = {n: [] for n in counts}
    for _ in range(repeats):
        for n in counts:
            t = time.perf_counter()
            linearize(dyn, X, U, method, s.fd_epsilon, n, 1, fd_forces=s.fd_forces)
            times[n].append(time.perf_counter() - t)
    med = {n: float(np.median(v)) for n, v in times.items()}
    return {
        "method": method.value,
        "seconds": {str(n): v for n, v in med.items()},
        "speedup": {str(n): med[1] / v for n, v in med.items()},
    }


def probe_derivatives(task, U0, threads: int, steps: int = 12, repeats: int = 3) -> dict:
    """Times AutoDiff and batched forward differences on ``steps`` states spread evenly over
    the initial rollout (so contact and free steps both count; alternating, best of
    ``repeats``). Returns seconds per step and the faster method."""

    dyn = task.dynamics
    X = dyn.rollout(task.x0, U0)
    idx = np.unique(np.linspace(0, U0.shape[0] - 1, min(steps, U0.shape[0])).astype(int))
    Xs, Us = X[idx], U0[idx]
    dyn.autodiff()  # one-time conversion, not part of the per-step cost
    best = {"autodiff": np.inf, "forward": np.inf}
    for _ in range(repeats):
        for m in best:
            t = time.perf_counter()
            s = task.config.solver  # AutoDiff with the task's processes, as it would run
            linearize(
                dyn,
                Xs,
                Us,
                m,
                s.fd_epsilon,
                threads,
                1,
                autodiff_workers=s.autodiff_workers,
                fd_forces=s.fd_forces,
            )
            best[m] = min(best[m], (time.perf_counter() - t) / idx.size)
    return {"seconds_per_step": best, "choice": min(best, key=best.get)}


def limit_analysis(task, sol, row: dict | None = None, threads: int = 0, repeats: int = 1) -> dict:
    """Where the limit of one iteration is, for ``task`` (the fast configuration) at the
    trajectory of its Solution ``sol`` (X: [N+1, nx], U: [N, nu]).

    Times (seconds, best of ``repeats``): one rollout; one exact linearization of all N steps
    on each path (AutoDiff serial in this process, AutoDiff in one worker process per core,
    batched forward differences on C++ threads, the same over generalized forces where the
    model allows it); one backward pass. The fastest possible iteration on this machine's
    cores with today's Drake is then the exact partials of only the keypoints the fast
    configuration needs (``derivatives.keypoints``) on the cheapest path (serial AutoDiff
    counted as perfectly split over the cores), plus the backward pass, plus a line search
    that accepts its first trial (one rollout). ``row`` (bench_task's result so far) adds the
    measured medians of (b) and (a') and how close (b) comes (``limit_s / fast_median_s``)."""

    dyn, s = task.dynamics, task.config.solver
    X, U = np.asarray(sol.X, float), np.asarray(sol.U, float)
    N = U.shape[0]
    cores = workers.cores()

    def best(fn) -> float:
        t_best = np.inf
        for _ in range(max(1, repeats)):
            t = time.perf_counter()
            fn()
            t_best = min(t_best, time.perf_counter() - t)
        return float(t_best)

    out: dict = {"steps": int(N), "cores": int(cores)}
    out["rollout_s"] = best(lambda: dyn.rollout(task.x0, U))
    dyn.autodiff()  # one-time conversion, not part of a linearization
    lin = {"autodiff_serial": best(lambda: autodiff_serial(dyn, X[:N], U))}
    n_workers = workers.resolve(0)
    if n_workers > 1 and N >= 2 * n_workers:
        try:
            workers.warm_up(dyn, n_workers)
            lin["autodiff_workers"] = best(lambda: workers.autodiff(dyn, X[:N], U, n_workers))
        except workers.Unavailable:
            pass
    nxt = X[1 : N + 1]

    def fd():
        _finite_differences(dyn, X[:N], U, False, s.fd_epsilon, threads, nxt, forces=False)

    lin["forward_threads"] = best(fd)
    if dyn.force_path() is not None:
        lin["fd_forces_threads"] = best(
            lambda: _force_differences(dyn, X[:N], U, False, s.fd_epsilon, threads, nxt)
        )
    out["linearization_all_steps_s"] = lin
    per_step = {k: v / N for k, v in lin.items()}
    # the cheapest per step on all cores: serial AutoDiff ideally split over the cores
    on_cores = dict(per_step)
    on_cores["autodiff_serial"] = per_step["autodiff_serial"] / cores
    cheapest = min(on_cores, key=on_cores.get)
    out["linearization_per_step_s"] = per_step
    out["cheapest_path"] = cheapest
    keys = keypoints(dyn, X, N, s.derivative_interval, s.derivative_adaptive)
    out["keypoints"] = len(keys)
    A, B = autodiff_serial(dyn, X[:N], U)
    quad = task.problem().cost.quadratize(X, U, task.problem().t0)
    out["backward_pass_s"] = best(lambda: backward_pass(A, B, quad, s.regularization_init))
    out["line_search_one_trial_s"] = out["rollout_s"]
    out["limit_all_steps_s"] = (
        N * on_cores[cheapest] + out["backward_pass_s"] + out["line_search_one_trial_s"]
    )
    out["limit_s"] = (
        len(keys) * on_cores[cheapest] + out["backward_pass_s"] + out["line_search_one_trial_s"]
    )
    for key in ("fast", "paper_same_solver"):
        m = (row or {}).get(key, {})
        if "median_s" in m:
            out[f"{key}_median_s"] = m["median_s"]
            out[f"{key}_phase_median_s"] = m["phase_median_s"]
    if "fast_median_s" in out:
        out["fast_share_of_limit"] = out["limit_s"] / out["fast_median_s"]
    if "paper_same_solver_median_s" in out:
        # the most any configuration could gain per iteration over (a') at this trajectory
        out["max_speedup_same_solver"] = out["paper_same_solver_median_s"] / out["limit_s"]
    return out


# ------------------------------------------------------------------------------------------
# One task
# ------------------------------------------------------------------------------------------


def _stats(sol) -> dict:
    it = np.asarray(sol.iteration_seconds, float)
    # Shares of the summed phases (the first iteration's time and phases both include the
    # initial rollout).
    total = float(sum(np.sum(sol.phase_seconds[p]) for p in PHASES)) or 1.0
    return {
        "iterations": int(it.size),
        "iteration_seconds": [float(v) for v in it],
        "median_s": float(np.median(it)) if it.size else float("nan"),
        "p10_s": float(np.percentile(it, 10)) if it.size else float("nan"),
        "p90_s": float(np.percentile(it, 90)) if it.size else float("nan"),
        "total_s": float(it.sum()),
        "phase_share": {p: float(np.sum(sol.phase_seconds[p])) / total for p in PHASES},
        "phase_median_s": {
            p: float(np.median(sol.phase_seconds[p])) if it.size else 0.0 for p in PHASES
        },
        "initial_cost": float(sol.costs[0]),
        "final_cost": sol.final_cost,
        "reason": sol.reason,
    }


def bench_tasks(name: str, threads: int, smoke: bool, sets, fast) -> tuple[dict, list]:
    """The configurations ({"paper": [...], "fast": [...], "paper_same_solver": [...]}) and
    the validated Tasks of one benchmark in the order (a), (b), (a'); ConfigError if ``fast``
    changes the problem being timed (its length or time step: the runs share one initial guess
    and are compared per iteration). (a') takes (b)'s contact approximation. (a) is None where
    the Drake has no TAMSI."""

    sets = list(sets or [])
    th = [f"solver.threads={threads}"]
    cfgs = {"paper": PAPER + th, "fast": FAST + th + list(fast or [])}
    tasks = [
        Task.load(name, sets + cfgs["paper"], smoke=smoke) if drake_has_tamsi() else None,
        Task.load(name, sets + cfgs["fast"], smoke=smoke),
    ]
    approx = tasks[1].config.plant.contact_approximation
    cfgs["paper_same_solver"] = PAPER_SAME_SOLVER + [f"plant.contact_approximation={approx}"] + th
    tasks.append(Task.load(name, sets + cfgs["paper_same_solver"], smoke=smoke))
    for t in tasks:
        if t is not None:
            validate_task(t)
    a, b = tasks[0] or tasks[2], tasks[1]
    if b.config.ensemble:
        raise ConfigError(
            f"{b.name} has an ensemble: bench times one model's iterations (the paper's method "
            "has no ensemble); remove it with --set ensemble=[] to time the nominal"
        )
    if a.steps != b.steps or a.config.plant.time_step != b.config.plant.time_step:
        raise ConfigError(
            f"--fast: {a.name}'s fast configuration has {b.steps} steps of "
            f"{b.config.plant.time_step:g} s, the paper's {a.steps} of "
            f"{a.config.plant.time_step:g} s: both must solve the same trajectory (use --set)"
        )
    return cfgs, tasks


def bench_task(
    name: str,
    iterations: int,
    threads: int,
    smoke: bool = False,
    sets: list[str] | None = None,
    fast: list[str] | None = None,
    block: int = 1,
    accuracy: bool = True,
    same_iterates: bool = True,
    on_message: Callable[[str], None] | None = None,
) -> dict:
    """Times the two configurations of task ``name``; returns its row of bench.json.
    ``on_message`` receives a line (rich markup) saying what is timed before it starts."""
    fast = list(fast or [])
    cfgs, tasks = bench_tasks(name, threads, smoke, sets, fast)
    # One initial guess for all (a 'hold' guess depends on the contact solver: take (a)'s,
    # or (a')'s where this Drake has no TAMSI for (a)).
    ref = tasks[0] or tasks[2]
    N = ref.steps
    U0 = ref.initial_guess(N)
    probe = None
    if not any(f.startswith("solver.derivatives=") for f in fast):
        probe = probe_derivatives(tasks[1], U0, threads)
        cfgs["fast"].append(f"solver.derivatives={probe['choice']}")
        tasks[1] = tasks[1].with_overrides(cfgs["fast"][-1])
    name = ref.name  # the task's own name, also when given as a file
    paths = "(a), (b), (a')" if tasks[0] is not None else "(b), (a') ((a) needs TAMSI)"
    (on_message or _ignore)(
        f"[bold]{name}[/bold]: N={N} nx={ref.dynamics.nx} "
        f"nu={ref.dynamics.nu}, {iterations} iterations each of {paths}, alternating"
    )
    for t in filter(None, tasks):  # worker processes start here, not inside a timed iteration
        s = t.config.solver
        size = max(workers.resolve(n) for n in (s.autodiff_workers, s.line_search_workers))
        workers.warm_up(t.dynamics, size)
    same = SameIterates(tasks[0]) if same_iterates and tasks[0] is not None else None
    t0 = time.perf_counter()
    res = run_alternating(tasks, U0, iterations, block, shadow=same)
    wall = time.perf_counter() - t0
    out: dict = {
        "task": name,
        "requested_iterations": int(iterations),
        "steps": int(N),
        "nx": int(ref.dynamics.nx),
        "nu": int(ref.dynamics.nu),
        "receding_window": ref.config.receding_horizon is not None,
        "wall_s": wall,
        "load_average": list(os.getloadavg()),
        "configs": cfgs,
        "derivative_probe": probe,
    }
    X0 = tasks[1].dynamics.rollout(tasks[1].x0, U0)
    out["initial_polygons"] = polygons(tasks[1].dynamics, X0)
    for key, task, r in zip(("paper", "fast", "paper_same_solver"), tasks, res):
        if task is None:
            out[key] = {"skipped": no_tamsi_message("path (a), the paper's method,")}
            continue
        if isinstance(r, Exception):
            out[key] = {"error": f"{type(r).__name__}: {str(r).strip().splitlines()[0]}"}
            continue
        out[key] = _stats(r)
        # A geometry query: each run's own meshes (resolution hints may differ).
        out[key]["polygons"] = polygons(task.dynamics, r.X)
    if all("median_s" in out[k] for k in ("paper", "fast")):
        a, b = out["paper"], out["fast"]
        out["speedup_median"] = a["median_s"] / b["median_s"]
        out["speedup_total"] = a["total_s"] / b["total_s"]
        out["cost_rel_diff"] = (b["final_cost"] - a["final_cost"]) / max(
            abs(a["final_cost"]), 1e-12
        )
    if all("median_s" in out.get(k, {}) for k in ("paper_same_solver", "fast")):
        a, b = out["paper_same_solver"], out["fast"]
        out["speedup_same_solver_median"] = a["median_s"] / b["median_s"]
        out["speedup_same_solver_total"] = a["total_s"] / b["total_s"]
        out["cost_rel_diff_same_solver"] = (b["final_cost"] - a["final_cost"]) / max(
            abs(a["final_cost"]), 1e-12
        )
    if "median_s" in out["fast"]:
        out["limits"] = limit_analysis(tasks[1], res[1], out, threads)
    if "median_s" in out["fast"] and "error" not in out["paper"]:
        if accuracy:
            sol_b = res[1]
            out["accuracy"] = derivative_accuracy(tasks[1], sol_b.X, sol_b.U, threads)
            out["threads"] = thread_scaling(tasks[1], sol_b.X, sol_b.U, threads)
    if same is not None and not isinstance(res[1], Exception):
        out["same_iterates"] = same.stats(res[1])
    return out


# ------------------------------------------------------------------------------------------
# Output
# ------------------------------------------------------------------------------------------


def _series(r: dict) -> list[tuple[str, list]]:
    """A row's boxes: (a), (b) and (a) at (b)'s iterates; (a') in (a)'s place where (a) did
    not run (a Drake without TAMSI)."""
    if "iteration_seconds" in r.get("paper", {}):
        series = [("paper", r["paper"]["iteration_seconds"])]
    elif "iteration_seconds" in r.get("paper_same_solver", {}):
        series = [("same_solver", r["paper_same_solver"]["iteration_seconds"])]
    else:
        return []
    series.append(("fast", r["fast"]["iteration_seconds"]))
    si = r.get("same_iterates") or {}
    if si.get("paper_iteration_seconds"):
        series.append(("same", si["paper_iteration_seconds"]))
    return series


def plot(rows: list[dict], path: Path) -> None:
    rows = [r for r in rows if "iteration_seconds" in r.get("fast", {}) and _series(r)]
    fig, ax = plt.subplots(figsize=(max(4.0, 2.8 * len(rows) + 1), 4))
    data, pos, labels, colors = [], [], [], []
    names = {
        "paper": "(a) paper: TAMSI, serial AutoDiff",
        "fast": "(b) fast configuration",
        "same": "(a) at (b)'s iterates",
        "same_solver": "(a') paper's method on (b)'s contact solver",
    }
    first: dict[str, int] = {}  # the first box of each kind, for the legend
    for i, r in enumerate(rows):
        series = _series(r)
        for j, (key, values) in enumerate(series):
            first.setdefault(key, len(data))
            data.append(values)
            pos.append(4 * i + j)
            colors.append(
                {"paper": "tab:red", "fast": "tab:blue", "same": "tab:orange"}.get(key, "tab:gray")
            )
        labels.append((4 * i + (len(series) - 1) / 2, r["task"]))
    if data:
        # black medians: the default orange one vanished in the orange "(a) at (b)'s iterates" box
        bp = ax.boxplot(
            data, positions=pos, widths=0.8, patch_artist=True, medianprops={"color": "k"}
        )
        for patch, c in zip(bp["boxes"], colors):
            patch.set_facecolor(c)
            patch.set_alpha(0.5)
        ax.set_xticks([p for p, _ in labels], [n for _, n in labels])
        ax.set_yscale("log")
        ax.legend(  # below the task names: inside, it hid the tallest boxes' whiskers
            [bp["boxes"][i] for i in first.values()],
            [names[k] for k in first],
            fontsize="small",
            loc="upper center",
            bbox_to_anchor=(0.5, -0.1),
        )
    ax.set_ylabel("iteration time [s]")
    ax.set_title("iLQR iteration times (paper Fig. 8)")
    savefig(fig, path)


BENCH_MARK = "bench"  # the "task" of a bench directory: other commands refuse to write there


def run_bench(
    names: list[str],
    out: str | Path,
    iterations: int = 10,
    threads: int = 0,
    smoke: bool = False,
    sets=None,
    fast=None,
    block: int = 1,
    accuracy: bool = True,
    same_iterates: bool = True,
    command: str | None = None,
    on_message: Callable[[str], None] | None = None,
) -> dict:
    """Benchmarks each task of ``names`` into ``out`` (bench.json rewritten after each);
    returns bench.json's dict, whose ``"tasks"`` are the rows in order. ``command``: the
    command line, recorded as ``environment.command``; ``on_message``: see ``bench_task``."""

    seen: dict[str, str] = {}
    for name in names:
        key = load_task(name, sets, smoke=smoke).name  # results are stored by task name
        # Every task's mistakes (e.g. a --fast key only one of them has) before bench.json
        # is written: a failed bench keeps the directory's earlier results.
        bench_tasks(name, threads, smoke, sets, fast)
        if key in seen:
            raise ConfigError(f"bench: {seen[key]!r} and {name!r} are both task {key!r}")
        seen[key] = name
    out = output_dir(out, BENCH_MARK)  # refuses a directory holding a task's results
    rows = []
    for name in names:
        rows.append(
            bench_task(
                name,
                iterations,
                threads,
                smoke,
                sets,
                fast,
                block,
                accuracy,
                same_iterates,
                on_message=on_message,
            )
        )
        _write(out, rows, iterations, threads, command)
    return _write(out, rows, iterations, threads, command)


def _ignore(text: str) -> None:
    pass


def _write(out: Path, rows, iterations, threads, command: str | None = None) -> dict:
    doc = {
        "task": BENCH_MARK,  # marks the directory as a bench's (io.rundir.RESULT_MARKERS)
        "iterations": iterations,
        "threads": num_threads(threads),
        "cpu_count": os.cpu_count(),
        "load_average_end": list(os.getloadavg()),
        "paper": PAPER,
        "paper_same_solver": PAPER_SAME_SOLVER,
        "fast": FAST,
        "tasks": {r["task"]: r for r in rows},
        "environment": environment(command),
    }
    return write_bench(out, doc, lambda path: plot(rows, path))
