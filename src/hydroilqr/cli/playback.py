"""``hydroilqr playback``: execute a solved trajectory on a finer 'real' simulation."""

from __future__ import annotations

from pathlib import Path

from hydroilqr.cli.common import command_line, console, print_goal, warn
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.plant import APPROXIMATIONS
from hydroilqr.problem.playback import PLAYBACK_FEEDFORWARDS, PLAYBACK_POLICIES
from hydroilqr.problem.variants import mismatch_overrides

HELP = (
    "execute a solved trajectory open loop (PD+, paper §V) on a finer "
    "'real' simulation and compare planned vs actual"
)


def setup(p) -> None:
    p.add_argument("dir", help="output directory of `hydroilqr solve` (summary.json, solution.npz)")
    p.add_argument(
        "--speed",
        type=float,
        default=None,
        help="playback speed (plan time per playback second); default 0.5 for pd, 1 for ilqr",
    )
    p.add_argument("--kp", type=float, help="PD+ stiffness (default 500)")
    p.add_argument("--kd", type=float, help="PD+ damping (default 5)")
    p.add_argument("--rate", type=float, help="PD+ control rate, Hz (default 1000)")
    p.add_argument(
        "--feedforward",
        choices=PLAYBACK_FEEDFORWARDS,
        help="PD+ feed-forward ū: scaled (default): g(q̄) + s²·(ū_plan − g(q̄)) at speed s, "
        "gravity kept and the rest slowed with the motion (Hollerbach 1984); plan: the "
        "plan's ū unchanged (the paper's)",
    )
    p.add_argument(
        "--update-period",
        type=float,
        default=0.02,
        help="seconds between reference updates (default 0.02)",
    )
    p.add_argument(
        "--policy",
        choices=PLAYBACK_POLICIES,
        default="pd",
        help="pd: PD+ on the joints (eq. 11); ilqr: u = ū − K(x − x̄) (eq. 8)",
    )
    p.add_argument(
        "--truth-time-step",
        type=float,
        default=0.001,
        help="time step of the 'real' simulation (default 0.001)",
    )
    p.add_argument(
        "--truth-contact",
        choices=APPROXIMATIONS,
        default=None,
        help="contact approximation of the 'real' simulation (default: one "
        "different from the planner's: sap->similar, others->sap)",
    )
    p.add_argument(
        "--truth-set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a task key of the 'real' system only, e.g. ball.friction=0.3 (repeatable)",
    )
    p.add_argument(
        "--mismatch",
        action="append",
        default=[],
        metavar="NAME",
        help="play against one of the task's named model errors (its mismatch: section, e.g. "
        "friction-30 on the Kinova tasks): its overrides go before any --truth-set (repeatable)",
    )
    p.add_argument(
        "--object",
        help="state block compared planned vs actual (default: the "
        "floating body, else the unactuated joint the plan moves most, else the first joint)",
    )
    p.add_argument(
        "--rest-max",
        type=float,
        help="seconds the robot holds its last reference after the plan while waiting for the "
        "object to come to rest (default 3; 0: no resting measurement)",
    )
    p.add_argument("--no-clip", action="store_true", help="do not clip torques to effort limits")
    p.add_argument(
        "--no-velocity-scaling",
        action="store_true",
        help="use the plan's v̄_J unscaled (default scales it by the speed)",
    )
    p.add_argument("--no-replay", action="store_true", help="skip playback.html")
    p.add_argument(
        "--out",
        help="output directory (default DIR/playback-POLICY, with -NAME appended per --mismatch)",
    )


def run(args) -> int:
    from hydroilqr.control.playback import advisories
    from hydroilqr.output.report import read_lock
    from hydroilqr.output.results import write_playback

    read_lock(Path(args.dir))  # no solve replaces the plan while it plays
    prepared = _settings(args)
    task, sol, settings = prepared.task, prepared.sol, prepared.settings
    out = _output_dir(task, args)
    _print_header(task, sol, settings, out, args.mismatch)
    early = advisories(task.dynamics.plant, settings)
    for w in early:
        warn(w)
    r = prepared.run()
    data = write_playback(  # Ctrl+C while it writes: after the set is complete
        task,
        r,
        out,
        replay=not args.no_replay,
        run_dir=args.dir,
        command=command_line(args),
        plan=sol,
    )
    _print_result(data, r.wall_seconds)
    for w in data.get("warnings", []):
        if w not in early:
            warn(w)
    console.print(
        f"wrote {out}/playback.json, playback.png, reference.csv, playback.npz"
        + ("" if args.no_replay else ", playback.html")
    )
    # a smoke-sized plan (its summary.json says so): its goal is the full task's
    return print_goal(data.get("goal"), task.config.smoke_run, "on the executed motion, at rest")


def _settings(args):
    """The solved run's task and solution, and the PlaybackSettings the options ask for,
    checked (``prepare``: the playback ready to run)."""
    from hydroilqr.control.playback import PlaybackSettings, load_run, prepare

    pd_loop = {
        k: getattr(args, k)
        for k in ("kp", "kd", "rate", "feedforward")
        if getattr(args, k) is not None
    }
    if args.policy == "ilqr" and pd_loop:
        raise ConfigError(
            f"{', '.join('--' + k for k in pd_loop)}: options of the PD+ loop; --policy ilqr "
            "applies the plan's own gains K once per plan step"
        )
    task, sol, _ = load_run(args.dir)
    repeated = sorted({n for n in args.mismatch if args.mismatch.count(n) > 1})
    if repeated:
        raise ConfigError(f"--mismatch {repeated[0]}: given more than once")
    mismatch = [o for name in args.mismatch for o in mismatch_overrides(task.config, name)]
    settings = PlaybackSettings(
        speed=args.speed,
        **pd_loop,  # the rest: PlaybackSettings' defaults
        update_period=args.update_period,
        policy=args.policy,
        truth_time_step=args.truth_time_step,
        truth_contact=args.truth_contact,
        truth_overrides=[*mismatch, *(args.truth_set or [])],
        clip_torques=not args.no_clip,
        scale_velocity_reference=not args.no_velocity_scaling,
        object=args.object,
        **({} if args.rest_max is None else {"rest_max": args.rest_max}),
    )
    return prepare(task, sol, settings)


def _output_dir(task, args) -> Path:
    from hydroilqr.output.report import output_dir

    # a mismatch playback gets its own directory: it does not replace the nominal one's files
    cases = "".join(f"-{name}" for name in args.mismatch)
    return output_dir(
        args.out or Path(args.dir) / f"playback-{args.policy}{cases}", task.name, playback=True
    )


def _repeats(settings) -> bool:
    keys = [t.split("=", 1)[0] for t in settings.truth_overrides]
    return len(set(keys)) < len(keys)


def _print_header(task, sol, settings, out: Path, mismatch: list[str]) -> None:
    truth_contact = settings.truth_contact_for(task)
    console.print(
        f"[bold]{task.name}[/bold]: {settings.policy} playback at speed {settings.speed:g}"
        + (f", feed-forward {settings.feedforward}" if settings.policy == "pd" else "")
        + f", truth dt={settings.truth_time_step:g} contact={truth_contact} "
        f"(plan dt={task.config.plant.time_step:g} "
        f"contact={task.config.plant.contact_approximation}) -> {out}"
    )
    if settings.truth_overrides:
        cases = f" (mismatch {', '.join(mismatch)})" if mismatch else ""
        console.print(
            f"real system differs{cases}: {', '.join(settings.truth_overrides)}"
            + (" (a later setting of the same key wins)" if _repeats(settings) else "")
        )
    from hydroilqr.control.playback import damping_note, plan_touches

    note = damping_note(task.config.plant.contact_approximation, truth_contact)
    if note and plan_touches(task, sol.X):  # (no contact: nothing is damped)
        console.print(f"note: {note}")


def _print_result(data: dict, wall_seconds: float) -> None:
    ob = data["object"]
    unit = f" {ob['unit']}" if ob["unit"] else ""
    final = f"final gap {ob['final_gap']:.4g}{unit} (plan's end)"
    rest = ""
    if ob.get("resting_gap") is not None:
        rested = "at rest" if ob["rest"]["actual"]["rested"] else "still moving"
        rest = (
            f"resting gap {ob['resting_gap']:.4g}{unit} ({rested} after "
            f"{ob['rest']['actual']['hold_s']:.2f} s of hold)"
        )
    if ob.get("no_resting_gap"):  # the warning says why; the plan's end is the headline
        head, rest = final, "; no resting gap (see the warning)"
    elif ob.get("resting_gap_caveat"):  # against an extension still moving: secondary
        unheld = "after the plan, unheld (no motor): " if ob.get("kind") == "joint" else ""
        head = final
        rest = f"; {unheld}{rest}, against the plan's extension still moving (see the warning)"
    elif ob.get("kind") == "joint" and rest:
        # a joint of the robot without a motor: the hold (PD+ on the actuated joints) cannot
        # hold it, so where it ends after the plan is no measure of the plan
        head, rest = final, f"; after the plan, unheld (no motor): {rest}"
    else:
        head, rest = (f"{rest}, {final}" if rest else final), ""
    console.print(
        f"{data['truth_steps']} truth steps in {wall_seconds:.2f} s; object {ob['name']}: "
        f"{head}, max deviation {ob['max_deviation']:.4g}{unit}, progress ratio "
        f"{_fmt(ob['progress_ratio'])}{rest}",
        soft_wrap=True,
    )
    joints = data.get("joint_tracking") or {}
    worst = max(joints, key=lambda k: joints[k]["rms_error"], default=None)
    which = f" {joints[worst]['unit']} ({worst})".replace("  ", " ") if worst else ""
    console.print(
        f"joint RMS tracking error (max over joints) {data['joint_rms_error_max']:.3g}{which}; "
        f"saturated commands {100 * data['saturated_fraction']:.1f}%"
    )
    from hydroilqr.metrics import report_lines  # (loaded with the playback already)

    for line in report_lines(data.get("reports") or {}, "executed"):
        console.print(line, soft_wrap=True)


def _fmt(v) -> str:
    return "n/a" if v is None else f"{v:.3g}"
