"""``hydroilqr solve``: solve a task and write its results."""

from __future__ import annotations

import shutil
import time
from pathlib import Path

from hydroilqr.cli.common import add_task_args, command_line, console, load_task_from_args, warn
from hydroilqr.problem.config import DERIVATIVES, ConfigError

HELP = "solve a task and write its results"


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


def run(args) -> int:
    from hydroilqr.output import report

    task = load_task_from_args(args, _solver_overrides(args))
    if args.resume:
        _check_resume(task, args)
    out, restart = _output_dir(task, args)
    _print_header(task, out)
    if not args.resume:  # a resumed run starts elsewhere
        _warn_about_start(task)
    t0 = time.perf_counter()
    sol = _solve(task, out, restart)
    wall = time.perf_counter() - t0
    _print_outcome(sol, task, wall)
    if args.view:
        from hydroilqr.output.replay import meshcat_instance

        console.print(f"live view: {meshcat_instance().web_url()}")
    # An earlier solve's results are replaced only now that this one has a trajectory: a
    # failed or killed solve leaves them as they were.
    with report.deferred_interrupt():  # Ctrl+C here: after the new results are complete
        _write_results(task, sol, out, args, wall)
    _print_notes(task, sol)
    if sol.reason == "interrupted":
        _print_interrupted(sol, out)
        return 130
    if args.view:
        _serve_view(task, sol, out, args.no_replay)
    return 0


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
    if cfg.continuation:
        steps = "; ".join(
            ", ".join(f"{k}={v}" for k, v in stage.items()) for stage in cfg.continuation
        )
        console.print(
            f"continuation: {len(cfg.continuation)} stage(s) first ({steps}), each warm-starting "
            "the next, then the task as written (the iteration count restarts per stage)"
        )


def _warn_about_start(task) -> None:
    from hydroilqr.problem.check import start_warning

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
            return api.solve(task, checkpoint_dir=out, on_resolve=prog.update)
        except KeyboardInterrupt:
            if ck.exists():
                raise KeyboardInterrupt(
                    f"finished resolves are saved in {ck}: continue with --resume {out}"
                ) from None
            raise


def _print_outcome(sol, task, wall: float) -> None:
    console.print(
        f"{'converged' if sol.converged else 'stopped'} ({sol.reason}) after "
        f"{sol.iterations} iterations, cost {sol.final_cost:.6g}, {wall:.2f} s"
    )
    from hydroilqr.solver.explain import explain

    console.print(f"status {sol.status}: {explain(sol, task)}", soft_wrap=True)
    cold = [i for i, r in enumerate(sol.extra.get("resolves", [])) if r.get("cold_start")]
    if cold:
        console.print(
            f"note: {len(cold)} window(s) started from the initial guess (resolves "
            f"{', '.join(map(str, cold[:8]))}{' ...' if len(cold) > 8 else ''}): the shifted "
            "previous window blew the simulation up when rolled out (extra.resolves)"
        )


def _write_results(task, sol, out: Path, args, wall: float) -> None:
    from hydroilqr import metrics as metrics_mod
    from hydroilqr.output import report
    from hydroilqr.solver import receding

    _clear_previous(out, keep=(receding.CHECKPOINT,))
    summary = report.write_outputs(
        task,
        sol,
        out,
        replay=not args.no_replay,
        wall_seconds=wall,
        command=command_line(args),
    )
    for line in metrics_mod.summary_lines(summary["metrics"]):
        console.print(line, soft_wrap=True)  # one line each: a terminal wraps, a log keeps it
    written = [p.name for p in report.solve_outputs(out) if p.is_file()]
    first = ["summary.json", "solution.npz"]
    console.print(f"wrote {out}/" + ", ".join(first + sorted(set(written) - set(first))))


def _clear_previous(out: Path, keep: tuple[str, ...] = ()) -> None:
    """Removes what an earlier solve wrote into ``out`` (plots, replay, checkpoint, playbacks of
    its solution), so the directory never mixes two runs. Other files, and the names in
    ``keep`` (this run's own checkpoint), are left alone."""
    from hydroilqr.output import report

    stale = [p for p in report.solve_outputs(out) if p.name not in keep]
    if stale:
        console.print(f"replacing the previous results in {out} ({len(stale)} files/directories)")
    for p in stale:
        if p.is_dir():
            shutil.rmtree(p)
        else:
            p.unlink()


def _print_notes(task, sol) -> None:
    """A note when the solver hardly moved from the initial guess."""
    stepped = any(e > 0 for e in sol.eps)
    if (
        task.config.receding_horizon is None
        and sol.reason not in ("interrupted", "max_iterations")
        and sol.iterations <= 1
    ):
        moved = "one step was taken" if stepped else "no step was taken"
        console.print(
            f"[yellow]note:[/yellow] {moved}: the initial guess is already (nearly) stationary "
            "for the model the solver sees. If the cost depends on a contact that never happens "
            "along it, or on an object that static friction holds still, there is no gradient "
            "to follow: try a guess that makes contact or pushes harder (docs/guide.md, "
            "section 3)"
        )


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
