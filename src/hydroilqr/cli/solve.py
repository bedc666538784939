"""``hydroilqr solve``: solve a task and write its results."""

from __future__ import annotations

import math
import time
from pathlib import Path

from hydroilqr.cli.common import (
    GOAL_NOT_MET,  # noqa: F401 - the exit code of an unmet goal (tests read it here)
    add_connect_timeout,
    add_task_args,
    command_line,
    console,
    load_task_from_args,
    print_goal,
    scheduler_arg,
    warn,
)
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.load import worker_ref
from hydroilqr.problem.search import check_searchable
from hydroilqr.problem.solver import DERIVATIVES

# Multi-start's seed and perturbation size when --starts N is given without them (None on
# the command line means "not given": they are refused without --starts).
MULTISTART_SEED = 0
MULTISTART_NOISE = 0.1

HELP = "solve a task and write its results"

#: The most starts one multi-start runs (each is a whole solve; their records are kept).
MAX_STARTS = 1000


def setup(p) -> None:
    add_task_args(p)
    p.add_argument(
        "--derivatives",
        choices=DERIVATIVES,
        help="how the partials are taken (default: the task's solver.derivatives; autodiff is "
        "the paper's)",
    )
    p.add_argument(
        "--max-iterations",
        type=int,
        help="sets solver.max_iterations (a receding-horizon task: its first window's)",
    )
    p.add_argument("--threads", type=int, help="threads for batched derivatives (0 = all)")
    p.add_argument("--out", help="output directory (default runs/TASK, runs/TASK-smoke)")
    p.add_argument("--resume", metavar="DIR", help="continue an interrupted receding-horizon run")
    p.add_argument(
        "--view",
        action="store_true",
        help="after the solve, play the result on a local Meshcat page until Ctrl+C",
    )
    p.add_argument("--no-replay", action="store_true", help="skip writing replay.html")
    p.add_argument(
        "--starts",
        type=int,
        default=1,
        metavar="N",
        help="multi-start: N solves from perturbed initial guesses (the first unperturbed) as "
        "Dask jobs; the best (goal met, then cost) is kept and the spread reported",
    )
    p.add_argument(
        "--seed",
        type=int,
        help=f"multi-start: the perturbations' seed (default {MULTISTART_SEED})",
    )
    p.add_argument(
        "--start-noise",
        type=float,
        metavar="F",
        help="multi-start: perturbation size, a fraction of each input's scale: its RMS over "
        f"the guess, or its effort limit where the guess is zero (default {MULTISTART_NOISE})",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="multi-start: an existing Dask scheduler (default: a local cluster)",
    )
    add_connect_timeout(p)
    p.add_argument(
        "--workers", type=int, help="multi-start: local worker processes (default: cores)"
    )
    p.add_argument(
        "--check-robust",
        type=int,
        default=0,
        metavar="K",
        help="after the solve, K more solves here from the guess perturbed by a relative 1e-9 "
        "(last-bit sized, as `robustness`): the goal's pass rate and each check's spread, a "
        "hint of a result on a knife edge (K times the solve's time)",
    )


def run(args) -> int:
    task = load_task_from_args(args, _solver_overrides(args))  # (before Drake is loaded)

    _check_starts(task, args)
    if args.resume:
        _check_resume(task, args)
    out, restart = _output_dir(task, args)
    _print_header(task, out)
    if not args.resume:  # a resumed run starts elsewhere
        _warn_about_start(task)
    t0 = time.perf_counter()
    srun = None
    if task.config.search is not None:  # a search across basins, then iLQR polish
        srun = _search_then_polish(task, args)
        sol, extra = srun.chosen_solution, {"search": srun.record()}
    elif args.starts > 1:
        sol, extra = _solve_many(task, args)
    else:
        sol, extra = _solve(task, out, restart), {}
    wall = time.perf_counter() - t0
    if extra.get("multistart"):  # multi-start: the best start's line, with its own solve's time
        ms = extra["multistart"]
        best = next(r for r in ms["results"] if r["index"] == ms["best"])
        console.print(f"all {args.starts} starts took {wall:.2f} s; the best start:")
        _print_outcome(sol, task, best["seconds"])
    else:
        _print_outcome(sol, task, wall)
    if args.check_robust and sol.reason != "interrupted":
        extra["check_robust"] = _check_robust(task, args)
    if args.view:
        from hydroilqr.output.replay import meshcat_instance

        console.print(f"live view: {meshcat_instance().web_url()}")
    # An earlier solve's results are replaced only once this one's are complete: a failed or
    # killed run leaves them as they were (output/rundir.py).
    summary = _write_results(
        task, sol, out, args, wall, extra, srun.result.costs if srun else None
    )  # Ctrl+C: after the set
    if srun is not None and srun.lost:
        from hydroilqr.cli.search import workers_lost

        return workers_lost(srun, out, _kept_at_interrupt(srun).replace(" before Ctrl+C", ""))
    if srun is not None and srun.interrupted:
        console.print(f"interrupted: {out} holds {_kept_at_interrupt(srun)}")
        print_goal(summary["goal"], args.smoke, "the plan kept at Ctrl+C")
        return 130
    if extra.get("multistart", {}).get("interrupted"):
        ms = extra["multistart"]
        console.print(
            f"interrupted: {out} holds the best of the {ms['finished']} start(s) of "
            f"{ms['requested']} that had finished (multistart.interrupted in summary.json)"
        )
        print_goal(summary["goal"], args.smoke, "the best finished start")
        return 130
    if sol.reason == "interrupted":
        _print_interrupted(sol, out)
        print_goal(summary["goal"], args.smoke, "the plan kept at Ctrl+C")  # as summary.json
        return 130
    code = print_goal(summary["goal"], args.smoke)
    if args.view:
        _serve_view(task, sol, out, args.no_replay)
    return code


def _seed(args) -> int:
    return MULTISTART_SEED if args.seed is None else args.seed


def _noise(args) -> float:
    return MULTISTART_NOISE if args.start_noise is None else args.start_noise


def _check_starts(task, args) -> None:
    """Refuses multi-start arguments that cannot work, before any work."""
    if not 1 <= args.starts <= MAX_STARTS:
        raise ConfigError(f"--starts: must be from 1 to {MAX_STARTS}, got {args.starts}")
    if args.starts == 1 and (args.seed is not None or args.start_noise is not None):
        raise ConfigError("--seed and --start-noise go with --starts N (N > 1)")
    if not (0 <= _noise(args) < math.inf):  # (NaN fails too)
        raise ConfigError(f"--start-noise: must be a finite number >= 0, got {args.start_noise}")
    if _seed(args) < 0:
        raise ConfigError(f"--seed: must be at least 0, got {args.seed}")
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers: must be at least 1, got {args.workers}")
    if args.starts > 1 and task.config.receding_horizon is not None:
        raise ConfigError(
            "--starts: multi-start perturbs a single solve's initial guess; "
            f"{task.name} is a receding-horizon task"
        )
    if args.starts > 1 and (args.resume or args.view):
        raise ConfigError("--starts does not combine with --resume or --view")
    if args.starts == 1 and (args.scheduler or args.workers) and task.config.search is None:
        raise ConfigError(
            "--scheduler and --workers go with --starts N (N > 1) or a task's search: section"
        )
    scheduler_arg(args)  # (--connect-timeout checked)
    check_searchable(task.config)
    if task.config.search is not None and (args.starts > 1 or args.resume or args.view):
        raise ConfigError(
            f"{task.name} has a search: section (the search's best samples are the starts): "
            "--starts, --resume and --view do not combine with it"
        )
    if not 0 <= args.check_robust <= MAX_STARTS:
        raise ConfigError(
            f"--check-robust: must be from 0 to {MAX_STARTS}, got {args.check_robust}"
        )
    if args.check_robust and (
        args.starts > 1
        or args.resume
        or task.config.receding_horizon is not None
        or task.config.search is not None
    ):
        raise ConfigError(
            "--check-robust re-solves a single solve's guess: not with --starts, --resume, "
            "a receding-horizon task or a search: section (hydroilqr robustness runs those)"
        )


def _check_robust(task, args) -> dict:
    """K solves from the guess perturbed by a relative 1e-9 (robustness's runs 1..K, seed 0,
    in this process): the goal's pass rate and each check's spread, printed and returned for
    summary.json's ``check_robust``."""
    from hydroilqr.studies.robustness import DEFAULT_NOISE, solve_run, spread_lines, summarize

    ref = _worker_ref(args, label=task.name)
    k = args.check_robust
    console.print(f"check-robust: {k} more solves from the guess perturbed by {DEFAULT_NOISE:g}")
    runs = []
    for i in range(1, k + 1):
        runs.append(solve_run(ref, i, 0, DEFAULT_NOISE))
        console.print(f"  run {i}: {start_line(runs[-1].record())}", soft_wrap=True)
    s = summarize(task.name, runs)
    costs = sorted(r.final_cost for r in runs if r.final_cost is not None)
    goal = f"goal met in {s['goal_met']} of {k}" if s["goal_declared"] else "no goal"
    cost = (
        f"; cost best {costs[0]:.6g} / median {costs[len(costs) // 2]:.6g} / worst {costs[-1]:.6g}"
        if costs
        else ""
    )
    console.print(f"check-robust: {goal}{cost}", soft_wrap=True)
    for line in spread_lines({"tasks": [s]}):
        console.print(line, soft_wrap=True)
    return {"noise": DEFAULT_NOISE, "seed": 0, **s}


def _solve_many(task, args):
    """Multi-start (studies/multistart.py): the best start's solution and the summary entry
    with every start's outcome and the spread."""
    from hydroilqr.studies.multistart import Interrupted, best_index, run_multistart, spread

    ref = _worker_ref(args)
    where = args.scheduler or "a local Dask cluster"
    console.print(f"multi-start: {args.starts} solves (seed {_seed(args)}) on {where}")

    def done(r) -> None:
        console.print(f"  start {r.index}: {start_line(r.record())}", soft_wrap=True)

    interrupted = False
    try:
        results, best = run_multistart(
            ref, args.starts, _seed(args), _noise(args), scheduler_arg(args), args.workers, done
        )
    except Interrupted as e:  # Ctrl+C: the starts that finished are kept
        results, best, interrupted = e.results, best_index(e.results), True
        if best is None:
            raise KeyboardInterrupt("no start had finished: nothing was written") from None
    if best is None:
        raise ConfigError(f"multi-start: none of the {args.starts} starts finished")
    s = spread(results)
    console.print(
        f"multi-start: best start {best}; cost best {s['best_cost']:.6g} / median "
        f"{s['median_cost']:.6g} / worst {s['worst_cost']:.6g}; {s['finished']} of "
        f"{s['starts']} finished; goal met by {s['goal_met']} of {s['starts']}"
    )
    entry = {
        "seed": _seed(args),
        "noise": _noise(args),
        "best": best,
        **s,
        "requested": args.starts,
        "interrupted": interrupted,  # Ctrl+C: only the starts that had finished
        "results": [r.record() for r in results],
    }
    solution = next(r.solution for r in results if r.index == best)
    return solution, {"multistart": entry}


def _search_then_polish(task, args):
    """The task's sampling search on Dask, then iLQR from its best ``search.polish`` samples
    (studies/search.py), the plan chosen by ``search.select``: a SearchRun."""
    from hydroilqr.cli.search import print_search_line
    from hydroilqr.output.progress import SearchProgress
    from hydroilqr.solver.search import total_iterations
    from hydroilqr.studies.search import run_search

    sc = task.config.search
    where = args.scheduler or "a local Dask cluster"
    console.print(
        f"search: {sc.method} over {sc.knots} knots ({sc.space} space), {sc.samples} samples x "
        f"{sc.iterations} iterations on {where}, then iLQR from the best {sc.polish}"
        + (" and from the task's guess" if sc.polish_guess and sc.polish > 0 else "")
        + (f"; up to {sc.restarts} restart(s) while none meets the goal" if sc.restarts else "")
    )
    ref = _worker_ref(args)

    def polished(r) -> None:
        what = " (the task's guess)" if getattr(r, "guess", False) else ""
        what += f" (restart {r.search})" if getattr(r, "search", 0) else ""
        console.print(f"  polish {r.index}{what}: {start_line(r.record())}", soft_wrap=True)

    def restarting(restart: int, seed: int) -> None:
        console.print(f"restart {restart} (seed {seed}): no polished plan met the goal")

    t0 = time.perf_counter()
    with SearchProgress(total_iterations(task.config), console) as prog:
        srun = run_search(
            ref, scheduler_arg(args), args.workers, prog.update, True, polished, restarting
        )
    print_search_line(srun, time.perf_counter() - t0)
    if srun.polished:
        chosen = "none finished" if srun.chosen is None else f"polish {srun.chosen}"
        held = [
            f"polish {r.index} {r.robust['met']} of {r.robust['runs']}"
            for r in srun.polished
            if getattr(r, "robust", None)
        ]
        how = f" (perturbed re-solves meeting the goal: {', '.join(held)})" if held else ""
        console.print(f"select ({sc.select}): {chosen}{how}", soft_wrap=True)
    return srun


def _kept_at_interrupt(srun) -> str:
    if srun.chosen is not None:
        return f"the chosen plan of the {len(srun.polished)} polished before Ctrl+C"
    return "the search's best sample found before Ctrl+C (not polished)"


def start_line(rec: dict) -> str:
    """One start of a multi-start, in words: ``status converged after 12 iterations, cost
    8.27, goal met, 19.1 s``; a start that raised: ``failed (the error), 3.2 s``."""
    secs = f"{rec['seconds']:.1f} s"
    if rec.get("error") and rec["final_cost"] is None:
        return f"failed ({rec['error']}), {secs}"
    parts = [f"status {rec['status']} after {rec['iterations']} iterations"]
    parts.append("no finite cost" if rec["final_cost"] is None else f"cost {rec['final_cost']:.6g}")
    goal = {True: "goal met", False: "goal not met", None: ""}[rec["goal_met"]]
    parts += [goal] if goal else []
    detail = f" ({rec['error']})" if rec.get("error") else ""
    return ", ".join([*parts, secs]) + detail


def _worker_ref(args, **extra) -> dict:
    """What a Dask worker loads this solve's task from (``problem.load.worker_ref``)."""
    overrides = [*args.set, *_solver_overrides(args)]
    return worker_ref(args.task_file or args.task, overrides, args.config, args.smoke, **extra)


def _solver_overrides(args) -> list[str]:
    """The --set entries that the solve's own options stand for."""
    extra = []
    if args.derivatives:
        extra.append(f"solver.derivatives={args.derivatives}")
    if args.max_iterations is not None:
        extra.append(f"solver.max_iterations={args.max_iterations}")
    if args.threads is not None:
        extra.append(f"solver.threads={args.threads}")
    return extra


def _check_resume(task, args) -> None:
    """Refuses a --resume that cannot continue this task; warns of a changed environment."""
    from hydroilqr.solver import receding

    resume_dir = args.resume
    if task.config.receding_horizon is None:
        raise ConfigError(f"--resume: {task.name} is not a receding-horizon task")
    if args.out and Path(args.out) != Path(resume_dir):
        raise ConfigError("--resume DIR writes into DIR; drop --out or make it the same")
    # refuses a foreign or missing checkpoint
    ck_state = receding.load_checkpoint(task, resume_dir)
    unfinished = ck_state.done < task.config.receding_horizon.resolves
    changed = receding.environment_change(ck_state) if unfinished else ""
    if changed:
        warn(
            f"resuming in another environment ({changed}): the "
            "finished windows keep their last bits and the rest get this environment's, so "
            "the result will match an uninterrupted run in neither (extra.environments)"
        )


def _output_dir(task, args) -> tuple[Path, bool]:
    """The output directory, and whether it holds a finished run to solve again."""
    from hydroilqr.output import report
    from hydroilqr.solver import receding

    resume_dir = args.resume
    out = Path(args.out or resume_dir or f"runs/{task.name}{'-smoke' if args.smoke else ''}")
    restart = False
    if (out / receding.CHECKPOINT).exists() and not resume_dir:
        if not receding.finished_run(out):
            # torn, or from other arguments: --resume cannot help; this says why
            receding.load_checkpoint(task, out)
            raise ConfigError(
                f"{out} holds the checkpoint of an unfinished run: pass --resume {out} to "
                "continue it, or choose another --out"
            )
        restart = True
    report.output_dir(out, task.name)
    return out, restart


def _print_header(task, out: Path) -> None:
    cfg = task.config
    dyn = task.dynamics
    console.print(
        f"[bold]{task.name}[/bold]: nx={dyn.nx} nu={dyn.nu} dt={dyn.dt} "
        f"steps={task.steps} contact={cfg.plant.contact_approximation} "
        f"derivatives={cfg.solver.derivatives} -> {out}"
    )
    if cfg.smoke_run:
        rh = cfg.receding_horizon
        n = rh.resolves * rh.shift_steps if rh is not None else task.steps
        console.print(
            f"--smoke: the task shrunk to {n} steps ({n * dyn.dt:g} s of motion) and a few "
            "iterations (its smoke: section), a quick check that everything runs: the plan and "
            "its replay last only that long, too short for the motion the task is for, and "
            "its goal is not judged"
        )
    if cfg.continuation:
        steps = "; ".join(
            ", ".join(f"{k}={v}" for k, v in stage.items()) for stage in cfg.continuation
        )
        console.print(
            f"continuation: {len(cfg.continuation)} stage(s) first ({steps}), each warm-starting "
            "the next, then the task as written (the iteration count restarts per stage)"
        )
    realize = getattr(cfg.initial_guess, "realize", None)
    if realize is not None:
        weights = ", ".join(f"{w:g}" for w in realize.weights)
        console.print(
            f"initial_guess.realize: {len(realize.weights)} stage(s) first with virtual forces "
            f"on the guess's unactuated coordinates (their weights {weights}), then the task on "
            "its own plant (the iteration count restarts per stage)"
        )
    if cfg.ensemble:
        members = "; ".join(", ".join(f"{k}={v}" for k, v in m.items()) for m in cfg.ensemble)
        console.print(
            f"ensemble: one plan against the task and {len(cfg.ensemble)} perturbed model(s) "
            f"({members}), each weighted {cfg.ensemble_weight:g}; costs are the weighted sum"
            + (
                ", after the task alone has been solved (ensemble_warm_start; the iteration "
                "count restarts at the ensemble stage)"
                if cfg.ensemble_warm_start
                else ""
            )
        )


def _warn_about_start(task) -> None:
    from hydroilqr.studies.check import start_warning

    warning = start_warning(task)
    if warning:
        warn(f"{warning} (see `hydroilqr check`)")


def _solve(task, out: Path, restart: bool):
    from hydroilqr.solver import api

    if task.config.receding_horizon is not None:
        return _solve_receding(task, out, restart)
    from hydroilqr.output.progress import IterationTable

    return api.solve(task, callbacks=[IterationTable(console)], stop_on_interrupt=True)


def _solve_receding(task, out: Path, restart: bool):
    from hydroilqr.output.progress import ResolveProgress
    from hydroilqr.output.results import checkpointer
    from hydroilqr.solver import api, receding

    rh = task.config.receding_horizon
    console.print(
        f"receding horizon: {rh.resolves} windows of {rh.window_steps} steps, each keeps "
        f"{rh.shift_steps}: {rh.resolves * rh.shift_steps} steps "
        f"({rh.resolves * rh.shift_steps * task.dynamics.dt:g} s; horizon and num_steps are "
        "not used)"
    )
    ck = out / receding.CHECKPOINT
    if restart:
        # The old results stay until the new run has finished; only its checkpoint goes.
        console.print(f"{out} holds a finished run: solving it again from the start")
        ck.unlink()
    with ResolveProgress(rh.resolves) as prog:
        try:
            return api.solve(
                task, checkpoint_dir=out, on_resolve=prog.update, on_checkpoint=checkpointer(out)
            )
        except KeyboardInterrupt:
            if ck.exists():
                raise KeyboardInterrupt(
                    f"finished resolves are saved in {ck}: continue with --resume {out}"
                ) from None
            raise


def _print_outcome(sol, task, wall: float) -> None:
    from hydroilqr.solver.explain import explain, stop_line

    console.print(stop_line(sol, wall), soft_wrap=True)
    console.print(f"  {explain(sol, task)}", soft_wrap=True)
    cold = [i for i, r in enumerate(sol.extra.get("resolves", [])) if r.get("cold_start")]
    if cold:
        console.print(
            f"note: {len(cold)} window(s) started from the initial guess (resolves "
            f"{', '.join(map(str, cold[:8]))}{' ...' if len(cold) > 8 else ''}): the shifted "
            "previous window blew the simulation up when rolled out (extra.resolves)"
        )
    rescues = [r["rescue"] for r in sol.extra.get("resolves", []) if r.get("rescue")]
    if rescues:
        rh = task.config.receding_horizon
        console.print(
            f"note: {len(rescues)} window(s) ended above {rh.rescue_factor:g}x the recent windows' "
            f"median cost and were solved on for up to {rh.rescue_iterations} more iterations "
            f"({sum(r['kept'] for r in rescues)} lowered it; extra.resolves: rescue)"
        )


def _print_realize(r: dict | None) -> None:
    """How a realization (initial_guess.realize) ended: the largest virtual force left in each
    stage, and the hand-off's cost on the task against the last stage's."""
    if not r:
        return
    forces = ", ".join(f"{s['weight']:g}: {s['max_virtual_force']:.3g}" for s in r["stages"])
    console.print(
        f"realize: largest virtual force per stage (weight: N or N·m) {forces}; hand-off "
        f"({r['handoff']}) cost {r['handoff_cost']:.6g} against the last stage's "
        f"{r['stages'][-1]['final_cost']:.6g}",
        soft_wrap=True,
    )


def _write_results(task, sol, out: Path, args, wall: float, extra: dict, search_costs=None) -> dict:
    """Writes the new result set beside the earlier one, then swaps it in whole; the earlier
    set's files and the playbacks of its plan are retired in the same commit."""
    from hydroilqr import metrics as metrics_mod
    from hydroilqr.output import report
    from hydroilqr.output.results import write_solve
    from hydroilqr.solver import receding

    retire = [p.name for p in report.solve_outputs(out) if p.name != receding.CHECKPOINT]
    if retire:
        console.print(f"replacing the previous results in {out} ({len(retire)} files/directories)")
    summary = write_solve(
        task,
        sol,
        out,
        replay=not args.no_replay,
        wall_seconds=wall,
        command=command_line(args),
        extra_summary=extra,
        search_costs=search_costs,
    )
    _print_realize(sol.extra.get("realize"))
    units = metrics_mod.final_error_units(task, summary["metrics"])
    for line in metrics_mod.summary_lines(summary["metrics"], units):
        console.print(line, soft_wrap=True)  # one line each: a terminal wraps, a log keeps it
    for line in metrics_mod.report_lines(summary.get("reports") or {}, "plan"):
        console.print(line, soft_wrap=True)
    written = [p.name for p in report.solve_outputs(out) if p.is_file()]
    first = ["summary.json", "solution.npz"]
    console.print(f"wrote {out}/" + ", ".join(first + sorted(set(written) - set(first))))
    if not args.no_replay:
        from hydroilqr.output.replay import camera_note

        note = camera_note(task)
        if note:
            console.print(note, soft_wrap=True, markup=False)
    return summary


def _print_interrupted(sol, out: Path) -> None:
    in_stage = any(
        st.get("overrides") and st.get("reason") == "interrupted"
        for st in sol.extra.get("continuation", [])
    )
    what = (
        "the controls of the continuation stage that was running, simulated on the task's "
        "own model (its cost is the task's, not the stage's)"
        if in_stage
        else "the best trajectory found before Ctrl+C"
    )
    console.print(f"interrupted: {out} holds {what} ({sol.iterations} iterations)")


def _serve_view(task, sol, out: Path, no_replay: bool) -> None:
    """Keeps the live Meshcat page up (with the replay on it) until Ctrl+C."""
    if no_replay:  # the replay (published to the live page as it is written) is due
        from hydroilqr.output.replay import write_replay

        write_replay(task, sol.X, sol.t, out / "replay.html", inputs=sol.U)
    console.print("serving the replay on the live page above; press Ctrl+C to stop")
    try:
        while True:
            time.sleep(1)
    except KeyboardInterrupt:
        pass
