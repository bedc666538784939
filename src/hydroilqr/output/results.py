"""Result sets: the one home of every command's files. A solve (``write_solve``), a closed
loop (``write_mpc``) and a playback (``write_playback``) each write their files beside the
earlier set and swap them in whole (``io.rundir.result_set``) with Ctrl+C deferred until the
set is complete; a reader or a killed run sees the earlier set or the new one, never a mix.
A sweep point (``write_sweep_point``) is two atomic files, its arrays before its row. A
receding-horizon run's checkpoint (``write_checkpoint``) replaces the earlier one the same way.
Controllers, playback and the solver return data; only this module (and ``output/studies.py``
for the studies' files) writes their files."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hydroilqr import metrics as metrics_mod
from hydroilqr.control.mpc import MPCResult, loop_metrics
from hydroilqr.control.playback import PlaybackResult, executed_goal
from hydroilqr.io import rundir
from hydroilqr.io.environment import environment
from hydroilqr.io.files import atomic_savez, atomic_write, content_hash
from hydroilqr.metrics.goals import judge, judge_loop
from hydroilqr.output.plots import (
    plot_convergence,
    plot_mpc,
    plot_playback,
    plot_search,
    write_playback_replay,
    write_reference_csv,
)
from hydroilqr.output.replay import write_replay
from hydroilqr.output.report import PLAYBACK_FILES, deferred_interrupt, solve_outputs, write_json
from hydroilqr.solver.receding import CHECKPOINT, Checkpoint, checkpoint_arrays

MPC_FILES = ("mpc.json", "mpc.npz", "mpc.png", "mpc.html")
POINT_HASH = "_sha256"  # in a sweep point's .npz: its arrays' and its row's content hash


def write_set(out: str | Path, retire: list[str], write: Callable[[Path], dict]) -> dict:
    """The skeleton of every writer: ``write(stage)`` fills a staging directory beside
    ``out`` and returns the set's JSON dict; the set then replaces the files ``retire`` of the
    earlier set in one commit. Ctrl+C during it takes effect once the set is complete."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with deferred_interrupt(), rundir.result_set(out, list(retire)) as stage:
        return write(stage)


def write_solve(
    task,
    sol,
    out: str | Path,
    replay: bool = True,
    wall_seconds: float | None = None,
    command: str | None = None,
    extra_summary: dict | None = None,
    search_costs: np.ndarray | None = None,
) -> dict:
    """summary.json, solution.npz, convergence.png, the metrics' plots and replay.html (unless
    ``replay`` is false) in ``out``, replacing the earlier solve's set and the playbacks of its
    plan (a receding run's checkpoint stays until the caller removes it); returns the summary
    dict. ``wall_seconds``: the solve's wall time as the caller measured it (setup included),
    recorded last; ``command``: the command line (``environment.command``); ``extra_summary``:
    more top-level entries (e.g. ``multistart``, ``search``); ``search_costs``: [iterations,
    samples] a sampling search's sample costs, written as search.npz and plotted in
    search.png."""
    out = Path(out)
    retire = [p.name for p in solve_outputs(out) if p.name != CHECKPOINT]

    def write(stage: Path) -> dict:
        sol.save(stage / "solution.npz")
        metrics = metrics_mod.compute(task, sol)
        summary = {
            "task": task.name,
            **sol.stats(),
            # judged: false for a smoke-sized run (its goal is the full task's; exit code 0)
            "goal": judge(task.config, metrics),
            "smoke": bool(task.config.smoke_run),  # a shrunk task: its goal is the full task's
            "metrics": metrics,
            "reports": metrics_mod.report_rows(task.config.metrics, metrics),
            **(extra_summary or {}),
            "extra": sol.extra,
            "config": task.config.to_dict(),
            # Directory the config's relative paths resolve against (rebuild with
            # config.task_from_dict(summary["config"], summary["base_dir"])).
            "base_dir": task.config.base_dir,
            "environment": environment(command),
        }
        if wall_seconds is not None:
            summary["wall_seconds"] = wall_seconds
        write_json(stage / "summary.json", summary)
        plot_convergence(sol, stage / "convergence.png", task.name)
        if search_costs is not None:
            atomic_savez(stage / "search.npz", costs=np.asarray(search_costs, float))
            plot_search(search_costs, stage / "search.png", task.name)
        metrics_mod.plot(task, sol, stage)
        if replay:
            write_replay(task, sol.X, sol.t, stage / "replay.html", inputs=sol.U)
        return summary

    return write_set(out, retire, write)


def write_mpc(
    task, res: MPCResult, out: str | Path, replay: bool = True, command: str | None = None
) -> dict:
    """mpc.npz, mpc.png, mpc.html (unless ``replay`` is false) and mpc.json in ``out``;
    returns the mpc.json dict (``res.stats()``, the task's metrics on the simulated plant and
    the environment, the task's ``goal`` judged on them; ``command`` its command line)."""
    stats = res.stats()
    task_metrics = loop_metrics(task, res)
    data = {
        "task": task.name,
        **stats,
        "goal": judge_loop(task.config, task_metrics),
        "metrics": task_metrics,
        "reports": metrics_mod.report_rows(task.config.metrics, task_metrics),
        "environment": environment(command),
    }

    def write(stage: Path) -> dict:
        atomic_savez(
            stage / "mpc.npz",
            X=res.X,
            U=res.U,
            t=res.t,
            update_times=np.array(res.update_times),
            solve_seconds=np.array(res.solve_seconds),
            cpu_seconds=np.array(res.cpu_seconds),
        )
        plot_mpc(task, res, stage / "mpc.png")
        if replay:
            write_replay(task, res.X, res.t, stage / "mpc.html", inputs=res.U)
        write_json(stage / "mpc.json", data)
        return data

    return write_set(out, list(MPC_FILES), write)


def write_playback(
    task,
    r: PlaybackResult,
    out: str | Path,
    replay: bool = True,
    run_dir: str | Path | None = None,
    command: str | None = None,
    plan=None,
) -> dict:
    """playback.json, playback.png, reference.csv, playback.npz and (optionally)
    playback.html in ``out``. Returns the JSON dict (``command``: the command line that ran the
    playback, recorded as ``environment.command``; ``plan``: the played Solution, whose task
    metrics and goal are then judged on the executed motion: ``executed_metrics``, ``goal``)."""
    data = {"task": task.name, "run": str(run_dir) if run_dir else None, **r.metrics}
    if plan is not None:
        judged = executed_goal(task, plan, r)
        data["goal"], data["executed_metrics"] = judged["goal"], judged["metrics"]
        data["reports"] = metrics_mod.report_rows(task.config.metrics, judged["metrics"])
        # (final values: where the hold left things, unlike object.final_gap at the plan's end)
        data["executed_metrics_final_state"] = (
            "end of the hold after the plan"
            if r.hold is not None and len(r.hold.X)
            else "end of the plan"
        )
    data["environment"] = environment(command)

    def write(stage: Path) -> dict:
        write_json(stage / "playback.json", data)
        write_reference_csv(r, stage / "reference.csv")
        hold = {}
        if r.hold is not None:
            hold = {
                "hold_t": r.hold.t,
                "hold_X": r.hold.X,
                "hold_U": r.hold.U,
                "hold_X_plan": r.hold.X_plan,
            }
        atomic_savez(
            stage / "playback.npz",
            t=r.t,
            X=r.X,
            U=r.U,
            X_plan=r.X_plan,
            ref_t=r.reference.t,
            ref_q=r.reference.q,
            ref_v=r.reference.v,
            ref_u=r.reference.u,
            **hold,
        )
        plot_playback(r, stage / "playback.png", task.name)
        if replay:
            write_playback_replay(task, r, stage / "playback.html")
        return data

    return write_set(out, list(PLAYBACK_FILES), write)


def write_sweep_point(points_dir: Path, result: dict) -> None:
    """A sweep point's ``{"row", "arrays"}``: ``ID.npz`` (the arrays and their content hash)
    first, then ``ID.json`` (the row), whose presence marks the point done."""
    row = result["row"]
    pid = row["id"]
    if result.get("arrays"):
        arrays = {k: np.asarray(v) for k, v in result["arrays"].items()}
        digest = content_hash(arrays, json.dumps(row, sort_keys=True))
        atomic_savez(points_dir / f"{pid}.npz", **arrays, **{POINT_HASH: np.array(digest)})
    atomic_write(points_dir / f"{pid}.json", json.dumps(row, indent=1))


def write_checkpoint(directory: str | Path, st: Checkpoint) -> Path:
    """A receding-horizon run's state after its latest resolve as ``checkpoint.npz`` in
    ``directory``, replacing the earlier one (the rest of the directory stays as it is);
    a later run continues from it (``solver.receding``, ``--resume``)."""

    def write(stage: Path) -> dict:
        atomic_savez(stage / CHECKPOINT, compressed=False, **checkpoint_arrays(st))
        return {}

    write_set(directory, [CHECKPOINT], write)
    return Path(directory) / CHECKPOINT


def checkpointer(directory: str | Path) -> Callable[[Checkpoint], None]:
    """The ``on_checkpoint`` of ``solve`` that saves each state in ``directory``."""
    return lambda st: write_checkpoint(directory, st)
