"""Command-line interface: ``hydroilqr <command> ...`` (see ``hydroilqr --help``).

Every command reports bad input as one line on stderr and exits non-zero; set
HYDROILQR_DEBUG=1 to see tracebacks. Warnings of a run also go to stderr (``warn``), its report
to stdout.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from pathlib import Path

from rich.console import Console

from hydroilqr.output.progress import IterationTable
from hydroilqr.problem.config import DERIVATIVES, ConfigError

# Piped or logged output gets a wide console, so names that users copy into task files
# (block, joint and geometry names in tables) are not cut to fit 80 columns.
console = Console(stderr=False, highlight=False, width=None if sys.stdout.isatty() else 160)
# Warnings go to stderr, so they stay visible when a run's report on stdout is piped or kept.
err_console = Console(stderr=True, highlight=False, width=None if sys.stderr.isatty() else 160)


def warn(message: str) -> None:
    """Prints ``warning: message`` on stderr (rich markup allowed)."""
    err_console.print(f"[yellow]warning:[/yellow] {message}")


# ------------------------------------------------------------------------------------------
# Shared pieces
# ------------------------------------------------------------------------------------------


def add_task_args(p: argparse.ArgumentParser, positional: bool = True) -> None:
    if positional:
        p.add_argument("task", nargs="?", help="built-in task name or a task YAML file")
    p.add_argument("--task-file", help="a task YAML file (same as giving its path as TASK)")
    p.add_argument("--config", help="YAML file merged over the task")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a task key, e.g. solver.max_iterations=20 (repeatable)",
    )
    p.add_argument("--smoke", action="store_true", help="shrink the task (tests, quick tries)")


def task_name_from_args(args) -> str | None:
    """TASK or --task-file (not both: which one was meant would be a guess)."""
    task, task_file = getattr(args, "task", None), getattr(args, "task_file", None)
    if task and task_file:
        raise ConfigError(f"give a task name or --task-file, not both ({task!r}, {task_file!r})")
    return task_file or task


def load_task_from_args(args, extra_overrides: list[str] | None = None):
    from hydroilqr.problem.task import Task

    name = task_name_from_args(args)
    if not name:
        raise ConfigError("no task given (try `hydroilqr tasks`)")
    overrides = list(args.set or []) + list(extra_overrides or [])
    task = Task.load(name, overrides, args.config, args.smoke)
    task.validate()
    return task


# ------------------------------------------------------------------------------------------
# Commands
# ------------------------------------------------------------------------------------------


def cmd_tasks(args) -> int:
    from hydroilqr.problem.config import TASKS_DIR, list_tasks, load_raw

    for name in list_tasks():
        desc = load_raw(TASKS_DIR / f"{name}.yaml").get("description", "")
        console.print(f"[bold]{name:<22}[/bold] {desc}")
    return 0


def cmd_solve(args) -> int:
    from hydroilqr import metrics as metrics_mod
    from hydroilqr.output import report
    from hydroilqr.solver import api, receding

    extra = []
    if args.derivatives:
        extra.append(f"solver.derivatives={args.derivatives}")
    if args.max_iterations is not None:
        extra.append(f"solver.max_iterations={args.max_iterations}")
    if args.threads is not None:
        extra.append(f"solver.threads={args.threads}")
    resume_dir = args.resume
    task = load_task_from_args(args, extra)
    if resume_dir:
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
    out = Path(args.out or resume_dir or f"runs/{task.name}{'-smoke' if args.smoke else ''}")
    ck = out / receding.CHECKPOINT
    restart = False
    if ck.exists() and not resume_dir:
        if not receding.finished_run(out):
            try:
                receding.load_checkpoint(task, out)
            except ConfigError:  # torn, or from other arguments: --resume cannot help; say why
                raise
            raise ConfigError(
                f"{out} holds the checkpoint of an unfinished run: pass --resume {out} to "
                "continue it, or choose another --out"
            )
        restart = True
    report.output_dir(out, task.name)
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
    from hydroilqr.problem.check import start_warning

    warning = "" if resume_dir else start_warning(task)  # a resumed run starts elsewhere
    if warning:
        warn(f"{warning} (see `hydroilqr check`)")
    t0 = time.perf_counter()
    if cfg.receding_horizon is not None:
        from hydroilqr.output.progress import ResolveProgress

        rh = cfg.receding_horizon
        console.print(
            f"receding horizon: {rh.resolves} windows of {rh.window_steps} steps, each keeps "
            f"{rh.shift_steps}: {rh.resolves * rh.shift_steps} steps "
            f"({rh.resolves * rh.shift_steps * dyn.dt:g} s; horizon and num_steps are not used)"
        )

        if restart:
            # The old results stay until the new run has finished; only its checkpoint goes.
            console.print(f"{out} holds a finished run: solving it again from the start")
            ck.unlink()
        with ResolveProgress(cfg.receding_horizon.resolves) as prog:
            try:
                sol = api.solve(task, checkpoint_dir=out, on_resolve=prog.update)
            except KeyboardInterrupt:
                if ck.exists():
                    raise KeyboardInterrupt(
                        f"finished resolves are saved in {ck}: continue with --resume {out}"
                    ) from None
                raise
    else:
        sol = api.solve(task, callbacks=[IterationTable(console)], stop_on_interrupt=True)
    wall = time.perf_counter() - t0
    console.print(
        f"{'converged' if sol.converged else 'stopped'} ({sol.reason}) after "
        f"{sol.iterations} iterations, cost {sol.final_cost:.6g}, {wall:.2f} s"
    )
    cold = [i for i, r in enumerate(sol.extra.get("resolves", [])) if r.get("cold_start")]
    if cold:
        console.print(
            f"note: {len(cold)} window(s) started from the initial guess (resolves "
            f"{', '.join(map(str, cold[:8]))}{' ...' if len(cold) > 8 else ''}): the shifted "
            "previous window blew the simulation up when rolled out (extra.resolves)"
        )
    if args.view:
        from hydroilqr.output.replay import meshcat_instance

        console.print(f"live view: {meshcat_instance().web_url()}")
    # An earlier solve's results are replaced only now that this one has a trajectory: a
    # failed or killed solve leaves them as they were.
    with report.deferred_interrupt():  # Ctrl+C here: after the new results are complete
        _clear_previous(out, keep=(receding.CHECKPOINT,))
        summary = report.write_outputs(task, sol, out, replay=not args.no_replay, wall_seconds=wall)
    for line in metrics_mod.summary_lines(summary["metrics"]):
        console.print(line, soft_wrap=True)  # one line each: a terminal wraps, a log keeps it
    written = [p.name for p in report.solve_outputs(out) if p.is_file()]
    first = ["summary.json", "solution.npz"]
    console.print(f"wrote {out}/" + ", ".join(first + sorted(set(written) - set(first))))
    stepped = any(e > 0 for e in sol.eps)
    if (
        cfg.receding_horizon is None
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
    if sol.reason == "interrupted":
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
        return 130
    if args.view:
        if args.no_replay:  # the replay (published to the live page as it is written) is due
            from hydroilqr.output.replay import write_replay

            write_replay(task, sol.X, sol.t, out / "replay.html", inputs=sol.U)
        console.print("serving the replay on the live page above; press Ctrl+C to stop")
        try:
            while True:
                time.sleep(1)
        except KeyboardInterrupt:
            pass
    return 0


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


def cmd_check(args) -> int:
    from hydroilqr.problem.check import check_task

    task = load_task_from_args(args)
    if not args.smoke:  # the task's `smoke:` section must work too (tests rely on it)
        from hydroilqr.problem.task import Task

        Task.load(task_name_from_args(args), list(args.set or []), args.config, True).validate()
    check_task(task, console)
    return 0


COMMANDS = {}


class _Parser(argparse.ArgumentParser):
    """Argument errors as one line (``hydroilqr: error: ...``), like every other error."""

    def error(self, message):
        self.exit(2, f"hydroilqr: error: {message} (see `{self.prog} --help`)\n")


def _version_line() -> str:
    from hydroilqr import __version__
    from hydroilqr.output.report import environment

    e = environment()
    return (
        f"hydroilqr {__version__} (code {e['code'] or 'unknown'}; drake {e['drake']}, "
        f"numpy {e['numpy']}, "
        f"OpenBLAS kernels {e['blas_core'] or 'unknown'}, Python {e['python']}, "
        f"{e['cores']} cores)"
    )


class _VersionAction(argparse.Action):
    """--version, computed only when asked (it runs git and reads the BLAS library)."""

    def __init__(self, option_strings, dest, **kwargs):
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        print(_version_line())
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="hydroilqr",
        description="Contact-implicit trajectory optimization: iLQR over Drake's hydroelastic "
        "contact.",
    )
    parser.add_argument(
        "--version",
        action=_VersionAction,
        help="the version and what decides the last bits of a result (drake, numpy, BLAS)",
    )
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("tasks", help="list the built-in tasks")
    p.set_defaults(func=cmd_tasks)

    p = sub.add_parser("solve", help="solve a task and write its results")
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
    p.set_defaults(func=cmd_solve)

    p = sub.add_parser("check", help="validate a task and report its layout and contacts")
    add_task_args(p)
    p.set_defaults(func=cmd_check)

    for name, (helptext, setup) in COMMANDS.items():
        p = sub.add_parser(name, help=helptext)
        setup(p)
    return parser


def register(name: str, helptext: str):
    """Decorator for commands defined in other modules: fn(parser) sets args and func."""

    def deco(setup):
        COMMANDS[name] = (helptext, setup)
        return setup

    return deco


def _load_plugins() -> None:
    import importlib

    for mod in ("studies.sweep", "control.playback", "studies.bench", "control.mpc"):
        try:
            importlib.import_module(f"hydroilqr.{mod}")
        except ModuleNotFoundError as e:
            if e.name != f"hydroilqr.{mod}":
                raise


def _join_negative_values(argv: list[str]) -> list[str]:
    """``--values -5,1e6`` -> ``--values=-5,1e6`` (argparse takes "-5,1e6" for an option);
    the same for ``--push -1:cart:...``."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        if argv[i] in ("--values", "--push") and i + 1 < len(argv) and argv[i + 1].startswith("-"):
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
        else:
            out.append(argv[i])
            i += 1
    return out


def _escape_unencodable_output() -> None:
    """Output streams that cannot encode every character (PYTHONIOENCODING=ascii, or
    PYTHONUTF8=0 under LANG=C) print the units and symbols the messages use (μ, ε, τ, ū, ≥)
    as escapes such as ``\\u03bc`` instead of failing on them."""
    import codecs

    for stream in (sys.stdout, sys.stderr):
        encoding = getattr(stream, "encoding", None)
        if not encoding or getattr(stream, "errors", None) != "strict":
            continue
        try:
            if codecs.lookup(encoding).name != "utf-8":
                stream.reconfigure(errors="backslashreplace")
        except (AttributeError, LookupError, ValueError, OSError):
            pass


def _first_line(e: object) -> str:
    """The first line of an error's text (at most 500 characters)."""
    text = str(e).strip()
    return text.splitlines()[0][:500] if text else ""


def main(argv: list[str] | None = None) -> int:
    import logging

    _escape_unencodable_output()
    # Drake's INFO lines (e.g. "Meshcat listening ...") are noise for a command-line user;
    # warnings and errors still show.
    logging.getLogger("drake").setLevel(logging.WARNING)
    try:
        _load_plugins()  # imports Drake: Ctrl+C here is an interruption like any other
        from hydroilqr.model.plant import SimulationError
    except KeyboardInterrupt:
        print("hydroilqr: interrupted", file=sys.stderr)
        return 130
    parser = build_parser()
    argv = _join_negative_values(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    if isinstance(getattr(args, "out", None), str) and not args.out.strip():
        print("hydroilqr: error: --out: an empty directory name", file=sys.stderr)
        return 2
    import shlex

    from hydroilqr.output import report

    report.COMMAND = shlex.join(["hydroilqr", *argv])
    from hydroilqr.output.report import discard_empty_outputs

    try:
        try:
            return int(args.func(args) or 0)
        except BaseException:
            discard_empty_outputs()  # a failed command leaves no empty results directory
            raise
    except ConfigError as e:
        if os.environ.get("HYDROILQR_DEBUG"):
            raise
        print(f"hydroilqr: error: {e}", file=sys.stderr)
        return 2
    except SimulationError as e:
        if os.environ.get("HYDROILQR_DEBUG"):
            raise
        print(f"hydroilqr: simulation failed: {e}", file=sys.stderr)
        return 3
    except KeyboardInterrupt as e:
        detail = f": {e}" if str(e) else ""
        print(f"hydroilqr: interrupted{detail}", file=sys.stderr)
        return 130
    except SystemExit as e:  # e.g. from pydrake: its message, as one line
        if isinstance(e.code, int) or e.code is None or os.environ.get("HYDROILQR_DEBUG"):
            raise
        print(f"hydroilqr: error: {_first_line(e.code)}", file=sys.stderr)
        return 1
    except OSError as e:  # e.g. a full disk or a directory made read-only during the run
        if os.environ.get("HYDROILQR_DEBUG"):
            raise
        where = f"{e.filename}: " if getattr(e, "filename", None) else ""
        print(f"hydroilqr: error: {where}{e.strerror or e}", file=sys.stderr)
        return 1
    except Exception as e:  # noqa: BLE001 - the promise is one line, never a traceback
        if os.environ.get("HYDROILQR_DEBUG"):
            raise
        if isinstance(e, RuntimeError) and str(e).lstrip().startswith("Failure at "):
            print(f"hydroilqr: Drake failure: {_first_line(e)}", file=sys.stderr)
            return 3
        msg = str(e).strip().splitlines()[0] if str(e).strip() else ""
        print(
            f"hydroilqr: internal error: {type(e).__name__}: {msg} "
            "(set HYDROILQR_DEBUG=1 for a traceback)",
            file=sys.stderr,
        )
        return 1
    finally:
        report.COMMAND = None  # a later Python call in this process is not this command


if __name__ == "__main__":
    sys.exit(main())
