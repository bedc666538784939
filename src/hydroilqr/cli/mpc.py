"""``hydroilqr mpc``: closed-loop MPC over hydroelastic contact."""

from __future__ import annotations

import argparse

from rich.progress import Progress

from hydroilqr.cli.common import (
    add_task_args,
    command_line,
    console,
    load_task_from_args,
    print_goal,
    warn,
)
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.mpc import MPC_PLANNERS
from hydroilqr.problem.solver import DERIVATIVES

HELP = "closed-loop MPC over hydroelastic contact"


def setup(p) -> None:
    add_task_args(p)
    p.add_argument(
        "--duration", type=float, help="simulated seconds (default: the task's mpc.duration)"
    )
    p.add_argument(
        "--rate",
        type=float,
        help="control updates per second, at most one per simulation step (default: mpc.rate)",
    )
    p.add_argument(
        "--horizon", type=float, help="planning horizon in seconds (default: mpc.horizon)"
    )
    p.add_argument(
        "--iterations-per-update",
        type=int,
        help="iLQR iterations per update (default: mpc.iterations_per_update)",
    )
    p.add_argument(
        "--realtime",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="simulated time advances by the controller's wall time (latency felt); "
        "--no-realtime: lock-step, the simulation waits for each update (default: mpc.realtime)",
    )
    p.add_argument(
        "--push",
        action="append",
        default=[],
        metavar="TIME:BODY:FX,FY,FZ",
        help="apply a force (N, world frame) to BODY from TIME s on (repeatable)",
    )
    p.add_argument("--push-duration", type=float, help="seconds each push lasts (default 0.1)")
    p.add_argument(
        "--truth-set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a task key of the simulated plant only (model mismatch), e.g. "
        "ball.friction=0.3 (repeatable; after the task's mpc.truth_overrides)",
    )
    p.add_argument(
        "--plan-set",
        action="append",
        default=None,
        metavar="KEY=VALUE",
        help="override a task key of the controller's plans only (mpc.plan_overrides), e.g. "
        "cost.terms.approach.weight=1e5 to keep an approach term on (repeatable; after the "
        "task's mpc.plan_overrides)",
    )
    p.add_argument(
        "--plant-time-step",
        type=float,
        metavar="S",
        help="the simulated robot's time step, a divisor of the plan's plant.time_step "
        "(default: mpc.plant_time_step, 0 = the plan's)",
    )
    p.add_argument(
        "--planner",
        choices=MPC_PLANNERS,
        help="the loop's planner: ilqr, sampling (the task's search: settings, warm-started "
        "by the shifted best spline) or hybrid (iLQR iterations on the best sample); default "
        "mpc.planner",
    )
    p.add_argument("--threads", type=int, help="threads for derivatives (default: mpc.threads)")
    p.add_argument(
        "--derivatives",
        choices=DERIVATIVES,
        help="derivative method of the controller (default: mpc.derivatives, else the task's)",
    )
    p.add_argument(
        "--feedback-scale",
        type=float,
        help="scale of the iLQR feedback gains between updates (0: feedforward; default: "
        "mpc.feedback_scale)",
    )
    p.add_argument(
        "--warm-start-plan",
        metavar="DIR",
        help="a solved run (e.g. from `hydroilqr solve`) whose controls, by time, seed the "
        "first plan and each shifted plan's new steps (mpc.warm_start_plan)",
    )
    p.add_argument("--out", help="output directory (default runs/TASK-mpc, runs/TASK-smoke-mpc)")
    p.add_argument("--no-replay", action="store_true", help="skip writing mpc.html")


def run(args) -> int:
    from hydroilqr.model.plant import SimulationError
    from hydroilqr.output.results import write_mpc

    task, settings, loop = _settings(args)
    out = _output_dir(task, args)
    _print_header(task, settings)
    res = _simulate(loop)
    if res.failure and len(res.U) == 0:  # nothing to keep: an earlier run's files stay
        raise SimulationError(f"the controlled plant failed at {res.failure} (no step completed)")
    data = write_mpc(task, res, out, replay=not args.no_replay, command=command_line(args))
    _print_summary(data, settings, task)
    console.print(
        f"wrote {out}/mpc.json, mpc.npz, mpc.png" + ("" if args.no_replay else ", mpc.html")
    )
    if res.interrupted:
        console.print(f"interrupted at t = {res.t[-1]:.3f} s: {out} holds the run up to then")
        return 130
    if res.failure:
        raise SimulationError(
            f"the controlled plant failed at {res.failure} (results up to then are in {out})"
        )
    where = "on the closed loop"
    if (data.get("goal") or {}).get("source") == "mpc.goal":
        where = "mpc.goal, on the closed loop"
    return print_goal(data.get("goal"), args.smoke, where)


def _settings(args):
    """The task, its MPC settings with the command line's options applied, and the closed
    loop they build (checked: ConfigError before any work)."""
    from hydroilqr.control.mpc import SMOKE_UPDATES, Push, mpc_config, prepare

    if args.push_duration is not None and not args.push:
        raise ConfigError("--push-duration: given without --push")
    push_duration = 0.1 if args.push_duration is None else args.push_duration
    task = load_task_from_args(args)
    settings = mpc_config(
        task,
        duration=args.duration,
        rate=args.rate,
        horizon=args.horizon,
        iterations_per_update=args.iterations_per_update,
        realtime=args.realtime,
        pushes=[Push.parse(s, push_duration) for s in args.push],
        threads=args.threads,
        derivatives=args.derivatives,
        feedback_scale=args.feedback_scale,
        # the command line's after the task file's (the later one wins on a key)
        truth_overrides=list(task.config.mpc.truth_overrides) + list(args.truth_set),
        plant_time_step=args.plant_time_step,
        plan_overrides=list(task.config.mpc.plan_overrides) + list(args.plan_set or []),
        warm_start_plan=args.warm_start_plan,
        planner=args.planner,
    )
    if args.horizon is not None and settings.shrinking_horizon:
        raise ConfigError(
            f"--horizon: {task.name} plans to its own end (mpc.shrinking_horizon: true), so a "
            "horizon does not apply; add --set mpc.shrinking_horizon=false for a receding one"
        )
    if args.smoke and args.duration is None and settings.rate > 0:  # a quick try: at most
        settings.duration = min(settings.duration, SMOKE_UPDATES / settings.rate)  # 10 updates
    return task, settings, prepare(task, settings)


def _output_dir(task, args):
    from hydroilqr.output import report

    default = f"runs/{task.name}{'-smoke' if args.smoke else ''}-mpc"
    return report.output_dir(args.out or default, task.name)


def _print_header(task, settings) -> None:
    horizon = "to the task's end" if settings.shrinking_horizon else f"{settings.horizon:g} s"
    per_update = f"{settings.iterations_per_update} it/update"
    if settings.planner != "ilqr":
        sc = task.config.search
        samples = settings.samples or (sc.samples if sc else 64)
        per_update = (
            f"planner {settings.planner}: {samples} samples x {settings.sampling_iterations} "
            f"per update ({sc.space if sc else 'torque'} space)"
            + (f" + up to {per_update} of iLQR" if settings.planner == "hybrid" else "")
        )
    console.print(
        f"[bold]mpc {task.name}[/bold]: {settings.rate:g} Hz, horizon "
        f"{horizon}, {per_update}, "
        f"{'real time' if settings.realtime else 'lock-step'}"
        + (f" (latency {settings.lockstep_latency:g} s)" if settings.lockstep_latency else "")
        + f", {settings.duration:g} s"
    )
    if settings.truth_overrides:
        console.print(f"simulated plant differs: {', '.join(settings.truth_overrides)}")
    if task.config.ensemble:
        console.print(
            f"ensemble: not used; mpc re-plans on the task's own model (the task's "
            f"{len(task.config.ensemble)} perturbed member(s) are for `solve`)"
        )


def _simulate(loop):
    """The closed loop's run under a transient progress bar."""

    with Progress(transient=True) as prog:
        bar = prog.add_task("simulating", total=1.0)
        return loop.run(lambda k, n: prog.update(bar, completed=k / n))


def _print_summary(data: dict, settings, task) -> None:
    from hydroilqr import metrics

    fp = data.get("first_plan") or {}
    if fp:  # before the clock started
        stages = fp["continuation_stages"]
        console.print(
            f"first plan (before the clock starts): from the {fp['from']}"
            + (f" through {stages} continuation stage(s)" if stages else "")
            + f", status {fp['status']} after {fp['iterations']} of up to "
            f"{fp['max_iterations']} iterations, cost {fp['cost']:.6g}, {fp['seconds']:.2f} s",
            soft_wrap=True,
        )

    s = data["solve_seconds"]
    console.print(
        f"rate {data['achieved_rate_hz']:.1f} Hz, solve p50 {1e3 * s['p50']:.1f} ms, "
        f"p95 {1e3 * s['p95']:.1f} ms, max {1e3 * s['max']:.1f} ms, controller real-time factor "
        f"{data['controller_realtime_factor']:.2f}, loop real-time factor "
        f"{data['realtime_factor']:.2f}"
    )
    cpu = data.get("solve_cpu_seconds")
    if cpu:  # the process's own time, summed over its threads (one thread: an idle core's)
        console.print(
            "CPU per update (summed over threads): "
            f"p50 {1e3 * cpu['p50']:.1f} ms, p95 {1e3 * cpu['p95']:.1f} ms, "
            f"max {1e3 * cpu['max']:.1f} ms"
        )
    sp = data.get("sampling")
    if sp:
        console.print(
            f"sampler ({data['planner']}): {sp['samples_per_update_mean']:.0f} samples per "
            f"update in {1e3 * sp['sampling_seconds_p50']:.1f} ms (p50), "
            f"{sp['samples_per_second']:.0f} samples/s"
            + (
                f", {sp['ilqr_iterations_mean']:.1f} iLQR it/update"
                if sp["ilqr_iterations_mean"]
                else ""
            )  # fmt: skip
        )
    phases = data.get("phase_seconds_mean") or {}
    if phases:  # where an update's time goes
        console.print(
            "per update (mean): "
            + ", ".join(f"{k.replace('_', ' ')} {1e3 * v:.1f} ms" for k, v in phases.items())
        )
    if settings.realtime and data["achieved_rate_hz"] < 0.95 * settings.rate:
        # In real time the simulation waits for the controller, so the loop's factor stays
        # near 1 whatever the latency: the achieved rate is what shows a slow controller.
        console.print(
            f"[yellow]note:[/yellow] the controller kept up with {data['achieved_rate_hz']:.1f} "
            f"of the {settings.rate:g} Hz asked (--realtime: the plant ran on older plans "
            "while updates were late; the loop real-time factor is ~1 by construction)"
        )
    from hydroilqr.metrics.common import SATURATION_WARNING

    if data.get("saturated_fraction", 0.0) > SATURATION_WARNING:
        warn(
            f"{100 * data['saturated_fraction']:.0f}% of the commands hit the effort limits "
            "(clipped): the plant could not apply what the controller asked"
        )
    units = metrics.final_error_units(task, data["metrics"])
    for line in metrics.summary_lines(data["metrics"], units):
        console.print(line, soft_wrap=True)  # one line each: a terminal wraps, a log keeps it
    for line in metrics.report_lines(data.get("reports") or {}, "closed loop"):
        console.print(line, soft_wrap=True)
