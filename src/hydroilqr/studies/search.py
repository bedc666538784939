"""A task's sampling search on Dask workers, then iLQR polish of its best samples.

``run_search(task_ref, ...)`` runs ``solver.search.run_search`` with an evaluator that sends
each iteration's samples in batches to Dask workers (``studies/cluster.py``: a local cluster
by default, an existing scheduler by address). Each worker builds the task's plant once and
holds it (``held``, by the task's reference) for every batch it gets; the samples themselves
are drawn in this process from the search's one seeded generator, so the same seed gives
the same samples, costs and best with any number of workers.

``polish(task_ref, candidates, ...)`` solves the task with iLQR from each candidate's
torques (as Dask jobs too), and with ``search.polish_guess`` from the task's own initial guess
as iLQR alone solves it (its continuation stages included; after the first search's
candidates), then each restart's (``search.restarts``), and ``select`` picks among them in
that order: the first
whose plan meets the task's goal, else the lowest final cost (``search.select: goal``); the
lowest final cost (``cost``); the first whose PD+ playback at half speed on the finer
simulation meets the goal, else as ``goal`` (``transfer``); among those that meet the goal,
the one whose ``search.robust_runs`` perturbed re-solves (iLQR from its torques perturbed by a
relative ``search.robust_noise``, as ``hydroilqr robustness`` perturbs a guess) meet it most
often, the first on a tie, else as ``goal`` (``robust``). With ``search.restarts``, while no
polished plan meets the goal the search runs again from restart r's seed (``solver.search.
restart_seed``) and its best samples are polished too (``_restart``; in a robustness run's
own process ``_restart_here``), all read by ``select`` in order.

``throughput(task_ref, worker_counts, ...)`` measures samples per second with each number of
workers side by side, and the fixed cost of a batch.

A cluster that loses every worker does not stall a search: ``gather_within`` gives up once
the scheduler has had no worker for ``WORKERLESS_SECONDS``, and the search ends there with
the best found so far (``SearchRun.lost`` says why).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
from distributed import wait

from hydroilqr import metrics as metrics_mod
from hydroilqr.metrics.goals import evaluate as evaluate_goal
from hydroilqr.model.task import Task
from hydroilqr.problem.load import load_task
from hydroilqr.solver import search as search_mod
from hydroilqr.solver.api import solve
from hydroilqr.solver.receding import files_fingerprint
from hydroilqr.studies.cluster import kill_workers, open_client
from hydroilqr.studies.multistart import StartResult, _close, guess_start, perturbation
from hydroilqr.studies.robustness import played_back

#: Per worker process: the task and search space of the last task reference it evaluated.
_HELD: dict = {}


def held(task_ref: dict):
    """(task, SearchSpace) of ``task_ref`` ({name, overrides, config, smoke}, and ``content``
    from ``with_content``), built once per process and kept (a new reference replaces it)."""
    key = json.dumps(task_ref, sort_keys=True, default=str)
    if key not in _HELD:
        _HELD.clear()
        task = Task.load(
            task_ref["name"], task_ref["overrides"], task_ref["config"], task_ref["smoke"]
        )
        _HELD[key] = (task, search_mod.SearchSpace(task))
    return _HELD[key]


def with_content(task_ref: dict, task: Task) -> dict:
    """``task_ref`` with a hash of what ``task``, loaded from it, read (its resolved settings
    and the files they name): a worker that holds the plant of an earlier version of a task
    file changed since at the same path (a long-lived ``--scheduler``) builds it again
    instead of evaluating the old one."""
    settings = json.dumps(dataclasses.asdict(task.config), sort_keys=True, default=str)
    digest = hashlib.sha256(settings.encode()).hexdigest()[:16]
    return {**task_ref, "content": f"{digest}-{files_fingerprint(task.config)}"}


def evaluate_batch(task_ref: dict, commands: list, x0=None, t0=None) -> list[float]:
    """Runs on a worker: the costs of a batch of commands on its held plant, from x0 at t0
    (default: the task's start; a receding search's window gives its own)."""
    task, space = held(task_ref)
    return [space.cost(task, c, x0, t0) for c in commands]


def timed_batch(task_ref: dict, commands: list) -> tuple[list[float], float]:
    """``evaluate_batch`` and the worker's CPU seconds for it (``throughput``)."""
    c0 = time.process_time()
    costs = evaluate_batch(task_ref, commands)
    return costs, time.process_time() - c0


#: A search whose cluster has had no worker for this long stops with its best so far.
WORKERLESS_SECONDS = 60.0


class WorkersLost(RuntimeError):
    """Every Dask worker was gone for ``WORKERLESS_SECONDS``: the jobs cannot finish."""


def gather_within(client, futures: list, patience: float = WORKERLESS_SECONDS, poll=1.0):
    """``client.gather(futures)``, or WorkersLost once the scheduler has had no worker for
    ``patience`` seconds in a row (a plain gather then waits forever)."""
    since = None
    while True:
        try:
            wait(futures, timeout=poll)
            return client.gather(futures)
        except TimeoutError:
            pass
        if client.nthreads():
            since = None
            continue
        since = time.monotonic() if since is None else since
        if time.monotonic() - since >= patience:
            raise WorkersLost(f"every Dask worker was gone for {patience:g} s")


class DaskEvaluator:
    """``evaluate(commands) -> costs`` over a Dask client: ``batches`` batches per call (0:
    one per worker), gathered in order. When every worker is gone (``gather_within``) the
    call's costs are inf and ``lost`` says why; ``stop`` then ends the search."""

    def __init__(self, client, task_ref: dict, batches: int = 0, patience=WORKERLESS_SECONDS):
        self.client = client
        self.task_ref = task_ref
        self.workers = max(1, len(client.scheduler_info().get("workers", {})))
        self.batches = batches or self.workers
        self.calls = 0
        self.patience = patience
        self.lost: str | None = None

    def stop(self, on_iteration=None):
        """``on_iteration`` for the search: True (stop) once the workers are lost."""

        def check(info) -> bool:
            asked = bool(on_iteration(info)) if on_iteration is not None else False
            return asked or self.lost is not None

        return check

    def __call__(self, commands: list, x0=None, t0=None) -> list[float]:
        if self.lost is not None:
            return [math.inf] * len(commands)
        n = max(1, min(self.batches, len(commands)))
        bounds = np.linspace(0, len(commands), n + 1).round().astype(int)
        futures = [
            self.client.submit(
                evaluate_batch,
                self.task_ref,
                commands[a:b],
                x0,
                t0,
                pure=False,
                key=f"search-{self.calls}-{i}",
            )
            for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:]))
        ]
        self.calls += 1
        try:
            parts = gather_within(self.client, futures, self.patience)
        except WorkersLost as e:
            self.lost = str(e)
            return [math.inf] * len(commands)
        return [c for part in parts for c in part]


def load(task_ref: dict) -> Task:
    return Task.load(task_ref["name"], task_ref["overrides"], task_ref["config"], task_ref["smoke"])


@dataclass
class Restart:
    """A search run again (``search.restarts``): its number (1, 2, ...), seed, space and
    sampling result; its polished plans are in the run's ``polished``, their ``search`` its
    number."""

    restart: int
    seed: int
    space: object
    result: object

    def record(self) -> dict:
        out = search_mod.record(self.space, self.result)
        del out["settings"]  # (the first search's, but for the seed)
        return {"restart": self.restart, "seed": self.seed, **out}


def restart_settings(settings, restart: int):
    """The search settings of restart ``restart``: the seed ``solver.search.restart_seed``."""
    return dataclasses.replace(settings, seed=search_mod.restart_seed(settings.seed, restart))


@dataclass
class SearchRun:
    """A search's outcome: the space, the sampling result, the best sample as a Solution."""

    space: object
    result: object
    solution: object
    workers: int = 0
    polished: list = field(default_factory=list)  # StartResult per candidate
    chosen: int | None = None  # index into polished
    polish_interrupted: bool = False  # Ctrl+C during the polish: the finished ones kept
    lost: str | None = None  # every worker gone: why the search or polish stopped early
    restarts: list = field(default_factory=list)  # Restart per search run again

    @property
    def interrupted(self) -> bool:
        stopped = self.result.interrupted or any(r.result.interrupted for r in self.restarts)
        return bool(stopped or self.polish_interrupted) and self.lost is None

    def met(self) -> bool:
        """Whether a polished plan meets the task's goal."""
        return any_met(self.polished)

    def record(self) -> dict:
        """summary.json's ``search``: the search (``solver.search.record``), and the polish."""
        out = search_mod.record(self.space, self.result)
        out["workers"] = self.workers
        if self.lost is not None:
            out["workers_lost"] = self.lost
        if self.restarts:
            out["restarts"] = [r.record() for r in self.restarts]
        if self.polished or self.polish_interrupted:
            out["polish"] = {
                "select": self.space.settings.select,
                "chosen": self.chosen,
                "interrupted": self.polish_interrupted,
                "results": [r.record() for r in self.polished],
            }
        return out

    @property
    def chosen_solution(self):
        """The chosen polished plan, else the search's best sample."""
        if self.chosen is None:
            return self.solution
        return next(r.solution for r in self.polished if r.index == self.chosen)


def run_search(
    task_ref: dict,
    scheduler: str | None = None,
    workers: int | None = None,
    on_iteration=None,
    polish: bool = False,
    on_polish=None,
    on_restart=None,
) -> SearchRun:
    """The task's search on Dask (and, with ``polish``, iLQR from its best
    ``search.polish`` samples on the same workers, then ``search.restarts``: ``_restart``,
    ``on_restart(restart, seed)`` before each); Ctrl+C keeps the best so far."""
    task = load(task_ref)
    client, cluster = open_client(scheduler, workers)
    try:
        ev = DaskEvaluator(
            client,
            with_content(task_ref, task),
            task.config.search.batches if task.config.search else 0,
        )
        space, result = search_mod.run_search(task, ev, on_iteration=ev.stop(on_iteration))
        run = SearchRun(space, result, search_mod.as_solution(task, space, result), ev.workers)
        run.lost = ev.lost
        if polish and not result.interrupted and space.settings.polish > 0:
            run.polished, run.polish_interrupted, run.lost = _polish(
                client, task, task_ref, space, result, on_polish, ev.patience
            )
            _restart(run, client, task, task_ref, ev, on_iteration, on_polish, on_restart)
            run.chosen = select(run.polished, space.settings.select)
        if (run.interrupted or run.lost) and cluster is not None:
            kill_workers(cluster)  # (their unfinished batches or solves are abandoned)
    except KeyboardInterrupt:
        if cluster is not None:
            kill_workers(cluster)
        raise
    finally:
        _close(client, cluster)
    return run


@dataclass
class PolishResult(StartResult):
    """A polished candidate (``guess``: the task's own initial guess, solved as iLQR alone
    solves it; else a search sample); with ``select: transfer`` also its plan's playback
    (``studies.robustness.played_back``: goal_met on the executed motion, resting_gap);
    with ``select: robust`` its perturbed re-solves ({runs, met, goal_met: [per re-solve]})."""

    transfer: dict | None = None
    robust: dict | None = None
    guess: bool = False
    search: int = 0  # the search its start came from: 0 the first, r restart r

    def record(self) -> dict:
        out = super().record()
        out["start"] = "guess" if self.guess else "sample"
        if self.search:
            out["search"] = self.search
        if self.transfer is not None:
            out["transfer"] = self.transfer
        if self.robust is not None:
            out["robust"] = self.robust
        return out


def perturbed_starts(task, settings, U0: np.ndarray) -> list[np.ndarray]:
    """``select: robust``: the ``robust_runs`` perturbed copies of a candidate's torques U0:
    [N, nu] its re-solves start from (``multistart.perturbation``, seeded by the search's
    seed and the re-solve's number 1..robust_runs)."""
    limits = getattr(task.dynamics, "effort_limits", np.full(U0.shape[1], np.inf))
    return [
        perturbation(U0, limits, settings.robust_noise, settings.seed, k)
        for k in range(1, settings.robust_runs + 1)
    ]


def robust_record(resolves: list) -> dict:
    """A candidate's re-solves in plain data: how many ran and met the goal."""
    met = [r.goal.get("met") is True for r in resolves]
    return {"runs": len(resolves), "met": int(sum(met)), "goal_met": met}


def polish_one(
    task_ref: dict, U0: np.ndarray, index: int, transfer: bool = False, guess: bool = False
):
    """Runs on a worker: iLQR from the controls U0 on the task as written (without its
    ``continuation`` stages: a searched sample has already found what an approach stage
    looks for, and a stage's own cost would pull it elsewhere; with ``guess``, U0 is the
    task's own guess and the stages run, as iLQR alone solves the task), the metrics and the
    goal, and with ``transfer`` the plan's PD+ playback. Never raises: a PolishResult."""
    t0 = time.perf_counter()
    res = PolishResult(index=index, guess=guess)
    try:
        task = load(task_ref)
        if task.config.continuation and not guess:  # the samples replace the stages
            task = task.with_overrides(["continuation=[]"])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            res.solution = solve(task, U0=U0)
        res.metrics = metrics_mod.compute(task, res.solution)
        res.goal = evaluate_goal(task.config.goal, res.metrics)
        if transfer:
            res.transfer = played_back(task_ref, res.solution)
    except Exception as e:  # noqa: BLE001 - a failed polish is data; the others go on
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        res.error = f"{type(e).__name__}: {first}"[:300]
    res.seconds = time.perf_counter() - t0
    return res


def polish_starts(
    task, space, result, noise: float = 0.0, seed: int = 0, k: int = 0, with_guess: bool = True
):
    """The polish's starts, in the order ``select`` reads them: (U0 [N, nu], guess) per
    candidate sample (its rollout's torques), then with ``search.polish_guess`` (and
    ``with_guess``: not in a restart, whose guess is the same) the task's own initial guess
    (with ``noise``: perturbed as run ``k`` of ``hydroilqr robustness --seed SEED`` perturbs
    it for iLQR alone, ``guess_start``)."""
    out = [(space.rollout(task, cand.command).U, False) for cand in result.candidates]
    if space.settings.polish_guess and with_guess:
        out.append((guess_start(task, noise, seed, k), True))
    return out


def _polish(
    client, task, task_ref, space, result, on_polish, patience=WORKERLESS_SECONDS, restart=0,
    first=0,
):  # fmt: skip
    """iLQR from each start (``polish_starts``; a restart's without the guess) as Dask jobs,
    numbered from ``first``: (results in that order, interrupted, why the workers were lost
    or None); with ``select: robust``, each plan that meets the goal is then re-solved from
    perturbed torques (``perturbed_starts``). Ctrl+C or the loss of every worker keeps the
    ones that had finished."""
    cfg = space.settings
    transfer = cfg.select == "transfer"
    starts = polish_starts(task, space, result, with_guess=restart == 0)
    futures = [
        client.submit(polish_one, task_ref, U0, first + i, transfer, guess, pure=False,
                      key=f"polish-{first + i}")
        for i, (U0, guess) in enumerate(starts)
    ]  # fmt: skip
    out: list[StartResult] = []
    again: dict = {}
    try:
        for fut in futures:
            (r,) = gather_within(client, [fut], patience)
            r.search = restart
            out.append(r)
            if on_polish is not None:
                on_polish(r)
            if cfg.select == "robust" and r.goal.get("met") is True:
                U0, guess = starts[r.index - first]
                again[r.index] = [  # (while the other candidates' polishes run)
                    client.submit(
                        polish_one,
                        task_ref,
                        U,
                        r.index,
                        False,
                        guess,
                        pure=False,
                        key=f"re-{r.index}-{k}",
                    )  # fmt: skip
                    for k, U in enumerate(perturbed_starts(task, cfg, U0), 1)
                ]
        for r in out:
            if r.index in again:
                r.robust = robust_record(gather_within(client, again[r.index], patience))
    except KeyboardInterrupt:
        return out, True, None
    except WorkersLost as e:
        return out, True, str(e)
    return out, False, None


def _restart(run, client, task, task_ref, ev, on_iteration=None, on_polish=None, on_restart=None):
    """``search.restarts``: while no plan in ``run.polished`` meets the task's goal (and
    nothing stopped the run), the search again with restart r's seed (``restart_settings``)
    on the same workers, and the polish of its best samples (the guess is not polished
    again), appended to ``run.polished`` and ``run.restarts``."""
    cfg = run.space.settings
    for r in range(1, cfg.restarts + 1):
        if run.met() or run.interrupted or run.lost:
            return
        settings = restart_settings(cfg, r)
        if on_restart is not None:
            on_restart(r, settings.seed)
        tagged = None if on_iteration is None else _tag_restart(on_iteration, r)
        space, result = search_mod.run_search(task, ev, settings, ev.stop(tagged))
        run.restarts.append(Restart(r, settings.seed, space, result))
        run.lost = ev.lost
        if result.interrupted:
            return
        more, run.polish_interrupted, run.lost = _polish(
            client, task, task_ref, space, result, on_polish, ev.patience, r, len(run.polished)
        )
        run.polished += more


def _tag_restart(on_iteration, restart: int):
    return lambda info: on_iteration({**info, "restart": restart})


def select(polished: list, how: str = "goal") -> int | None:
    """The chosen polished plan, the candidates in order (the first search's by search
    cost, the task's guess when polished, then each restart's): ``goal``: the first
    whose goal is met, else the lowest final cost; ``cost``: the lowest final cost;
    ``transfer``: the first whose playback meets the goal, else as ``goal``; ``robust``: of
    those whose goal is met, the one whose perturbed re-solves meet it most often (the first
    on a tie), else as ``goal``. None if none finished."""
    ok = [r for r in polished if math.isfinite(r.cost)]
    if not ok:
        return None
    if how == "transfer":
        moved = [r for r in ok if (getattr(r, "transfer", None) or {}).get("goal_met") is True]
        if moved:
            return moved[0].index
    if how == "robust":
        held = [r for r in ok if r.goal.get("met") is True and getattr(r, "robust", None)]
        if held:  # (max keeps the first of equals: the lower search cost)
            return max(held, key=lambda r: r.robust["met"]).index
    if how in ("goal", "transfer", "robust"):
        met = [r for r in ok if r.goal.get("met") is True]
        if met:
            return met[0].index
    return min(ok, key=lambda r: r.cost).index


def throughput(
    task_ref: dict, worker_counts=(1, 2), samples: int = 64, rounds: int = 3
) -> list[dict]:
    """Samples per second of the task's search rollouts with each number of local workers,
    side by side in one run: per count, a warm-up call (the workers build their plants),
    then ``rounds`` calls of ``samples`` random samples in one batch per worker; the
    overhead of a batch (an empty batch's round trip), the workers' CPU seconds per sample
    and the share of a core each worker got (below 1: the machine is busy with other work,
    and the rates say more about that than about the workers)."""
    task = load(task_ref)
    space = search_mod.SearchSpace(task)
    rng = np.random.default_rng(0)
    nominal = space.nominal(task)
    commands = [
        space.decode(np.clip(nominal + 0.3 * space.scale * rng.standard_normal(nominal.shape),
                             space.lower, space.upper))
        for _ in range(samples)
    ]  # fmt: skip
    out = []
    for n in worker_counts:
        client, cluster = open_client(None, n)
        try:
            ev = DaskEvaluator(client, task_ref)
            ev(commands[: ev.workers])  # warm-up: each worker builds its plant
            bounds = np.linspace(0, samples, ev.workers + 1).round().astype(int)
            cpu = 0.0
            t0 = time.perf_counter()
            for _ in range(rounds):
                parts = client.gather(
                    [
                        client.submit(timed_batch, task_ref, commands[a:b], pure=False)
                        for a, b in zip(bounds[:-1], bounds[1:])
                    ]
                )
                cpu += sum(c for _, c in parts)
            seconds = time.perf_counter() - t0
            t1 = time.perf_counter()
            for _ in range(rounds):
                client.gather([client.submit(evaluate_batch, task_ref, [], pure=False)])
            overhead = (time.perf_counter() - t1) / rounds
        finally:
            _close(client, cluster)
        out.append(
            {
                "workers": n,
                "samples": samples * rounds,
                "seconds": seconds,
                "samples_per_second": samples * rounds / seconds,
                "batch_overhead_seconds": overhead,
                "cpu_seconds_per_sample": cpu / (samples * rounds),
                # the share of its own core each worker got (1: an idle machine)
                "cpu_share": cpu / (n * seconds),
            }
        )
    return out


@dataclass
class SearchStart(StartResult):
    """A run of ``search_start``; ``polish``: which start was chosen and what each met
    ({chosen, start: guess | sample, goal_met: [per polished start]})."""

    polish: dict | None = None


def search_start(task_ref: dict, k: int, seed: int, noise: float = 0.0) -> SearchStart:
    """Runs on a worker (``hydroilqr robustness --search``): run ``k`` (1..runs) of a task
    with a ``search:`` section as ``hydroilqr solve`` does it, the search's seed set to
    ``seed + k - 1``: the search in this process (no Dask inside a Dask job), iLQR from its
    best ``search.polish`` samples (and from the task's guess, perturbed as run ``k`` of
    iLQR alone perturbs it with ``noise``: ``polish_starts``), the plan chosen by
    ``search.select``. Never raises: a failure is a SearchStart with its error."""
    t0 = time.perf_counter()
    res = SearchStart(index=k)
    try:
        cfg = load_task(
            task_ref["name"], task_ref["overrides"], task_ref["config"], task_ref["smoke"]
        )
        if cfg.search is None:  # (a search.seed override would make one)
            raise ValueError(f"{cfg.name} has no search: section")
        ref = dict(task_ref, overrides=[*task_ref["overrides"], f"search.seed={seed + k - 1}"])
        task = load(ref)
        space, result = search_mod.run_search(task)
        starts = polish_starts(task, space, result, noise, seed, k)
        polished = _polish_here(task, ref, space, result, starts)
        restarts = _restart_here(task, ref, space.settings, polished)
        chosen = select(polished, space.settings.select)
        if chosen is None:
            raise RuntimeError("no polished candidate finished: " + polished[0].error)
        best = polished[chosen]
        res.solution, res.metrics, res.goal = best.solution, best.metrics, best.goal
        res.polish = {
            "chosen": chosen,
            "start": "guess" if best.guess else "sample",
            "goal_met": [r.goal.get("met") for r in polished],
        }
        if space.settings.restarts:
            res.polish["restarts"] = restarts
    except Exception as e:  # noqa: BLE001 - a failed run is data; the others go on
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        res.error = f"{type(e).__name__}: {first}"[:300]
    res.seconds = time.perf_counter() - t0
    return res


def any_met(polished: list) -> bool:
    """Whether a plan among ``polished`` meets the task's goal."""
    return any(p.goal.get("met") is True for p in polished)


def _restart_here(task, task_ref: dict, settings, polished: list) -> int:
    """``_restart`` in this process: while no plan in ``polished`` meets the goal, restart r's
    search and polish (appended to ``polished``), at most ``search.restarts`` times. -> the
    restarts run."""
    done = 0
    for r in range(1, settings.restarts + 1):
        if any_met(polished):
            break
        space, result = search_mod.run_search(task, settings=restart_settings(settings, r))
        starts = polish_starts(task, space, result, with_guess=False)
        polished += _polish_here(task, task_ref, space, result, starts, r, len(polished))
        done = r
    return done


def _polish_here(task, task_ref: dict, space, result, starts=None, restart=0, first=0) -> list:
    """``_polish`` in this process (a Dask job's own): each start's polish (``starts``:
    default ``polish_starts``), numbered from ``first``, and with ``select: robust`` its
    perturbed re-solves."""
    cfg = space.settings
    out = []
    for i, (U0, guess) in enumerate(starts or polish_starts(task, space, result), first):
        r = polish_one(task_ref, U0, i, cfg.select == "transfer", guess)
        r.search = restart
        if cfg.select == "robust" and r.goal.get("met") is True:
            again = [polish_one(task_ref, U, i, False, guess)
                     for U in perturbed_starts(task, cfg, U0)]  # fmt: skip
            r.robust = robust_record(again)
        out.append(r)
    return out
