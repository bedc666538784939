"""``hydroilqr check``: validate a task and report its layout and contacts."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from rich.markup import escape
from rich.measure import Measurement
from rich.table import Table

from hydroilqr.cli.common import add_task_args, console, load_task_from_args, task_name_from_args
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.mpc import MPCConfig

HELP = "validate a task and report its layout and contacts"

PAIRS_SHOWN = 40  # rows of the candidate-pair table


def setup(p) -> None:
    add_task_args(p)
    p.add_argument(
        "--replay",
        metavar="FILE.html",
        help="also write a 3-D replay of the initial guess rolled out over the task's horizon "
        "(what a solve starts from) to FILE.html",
    )


#: Columns that hold names a user copies into a task file: never cut short with "…" in a
#: narrow terminal (kept whole, or folded onto a second line when nothing else can give).
NAME_COLUMNS = {"block", "actuator", "joint", "geometry", "body", "A", "B"}


def _table(title: str, columns) -> Table:
    t = Table(title=title, title_justify="left")
    for col in columns:  # (escaped: "hint [m]" is no markup)
        if col in NAME_COLUMNS:
            t.add_column(escape(col), no_wrap=True, overflow="fold")
        else:
            t.add_column(escape(col), overflow="fold")
    return t


def _emit(t: Table) -> None:
    """The table, or where it does not fit the terminal (80 columns: rich would squeeze
    columns to nothing), one line per row: ``NAME: column value, ...``, nothing dropped."""
    width = Measurement.get(console, console.options.update(max_width=10_000), t).maximum
    if width <= console.width:
        console.print(t)
        return
    console.print(t.title)
    headers = [str(c.header).replace("\\[", "[") for c in t.columns]
    lead = 2 if headers[:2] == ["A", "B"] else 1  # a pair: "A / B: ..."
    for cells in zip(*(list(c.cells) for c in t.columns)):
        name = " / ".join(str(c) for c in cells[:lead])
        rest = ", ".join(f"{h} {v}" for h, v in zip(headers[lead:], cells[lead:]) if str(v))
        console.print(f"  {name}: {rest}", soft_wrap=True, markup=False)


def run(args) -> int:
    _replay_path(args.replay)
    task = load_task_from_args(args)  # (bad input is refused before Drake is loaded)
    from hydroilqr.studies.check import check_task

    if not args.smoke:  # the task's `smoke:` section must work too (tests rely on it)
        from hydroilqr.metrics import validate_task
        from hydroilqr.model.task import Task

        validate_task(Task.load(task_name_from_args(args), list(args.set or []), args.config, True))
    _check_mpc_section(task)
    check_task(task, on_section=print_section)
    if args.replay:
        _write_guess_replay(task, Path(args.replay))
    return 0


def _replay_path(value: str | None) -> None:
    """A --replay FILE.html whose directory exists (checked before any work)."""
    if value is None:
        return
    path = Path(value)
    if path.suffix != ".html" or not path.parent.is_dir():
        raise ConfigError(f"--replay {value}: expected FILE.html in an existing directory")


def _write_guess_replay(task, path: Path) -> None:
    from hydroilqr.output.replay import write_replay
    from hydroilqr.studies.check import guess_trajectory

    t, X, U = guess_trajectory(task)
    write_replay(task, X, t, path, inputs=U)
    console.print(f"wrote {path} (the initial guess's rollout, {len(U)} steps, {t[-1]:g} s)")


def _check_mpc_section(task) -> None:
    """A task file's ``mpc:`` section is checked as ``hydroilqr mpc`` would run it (rate and
    time steps, overrides, the controller's and the simulated robot's models built; no plan
    is solved): ConfigError, as there. Its warm-start plan is not read: it may be a run that
    does not exist yet (``mpc`` checks it)."""
    from hydroilqr.control.mpc import mpc_config, prepare

    if task.config.mpc == MPCConfig():
        return  # no mpc: section (`mpc` then runs on the defaults and its own options)
    prepare(task, dataclasses.replace(mpc_config(task), warm_start_plan=""))


def print_section(name: str, report: dict) -> None:
    """Prints one complete section of check_task's report."""
    PRINTERS[name](report)


def _model(r: dict) -> None:
    m = r["model"]
    console.print(
        f"[bold]{m['name']}[/bold]: {', '.join(m['files'])}\n"
        f"  nq={m['nq']} nv={m['nv']} nx={m['nx']} nu={m['nu']}  dt={m['dt']} s  "
        f"steps={m['steps']}  contact={m['contact_approximation']} "
        f"({m['contact_model']}, {m['contact_surface_representation']})  "
        f"derivatives={m['derivatives']}"
    )
    if m.get("gravity_off"):
        console.print(f"  gravity off (models.N.gravity: false) for {'; '.join(m['gravity_off'])}")
    fd = r.get("fd")
    if fd is None:
        return
    plain, forces = fd["plain"], fd["forces"]
    if fd["fd_forces"] and fd["qualifies"]:
        console.print(
            f"  differences over generalized forces (solver.fd_forces): {forces} perturbed "
            f"steps per time step instead of {plain}"
        )
    elif fd["fd_forces"]:
        console.print(
            "  solver.fd_forces: this model does not qualify (it needs SAP, or TAMSI without "
            "joint damping, and no PD actuators): plain differences, "
            f"{plain} steps per time step"
        )
    elif fd["qualifies"] and forces < plain - 1:
        console.print(
            f"  (solver.fd_forces: true would take {forces} perturbed steps per time step "
            f"instead of {plain}; docs/performance.md)"
        )


def _continuation(r: dict) -> None:
    for i, stage in enumerate(r.get("continuation", [])):
        keys = ", ".join(f"{k}={v}" for k, v in stage.items())
        console.print(f"  continuation[{i}] (solved first): {keys}")
    for i, member in enumerate(r.get("ensemble", [])):
        keys = ", ".join(f"{k}={v}" for k, v in member["overrides"].items())
        state = "guess rollout fails" if member.get("warning") else "guess rollout ok"
        console.print(f"  ensemble[{i}] (weight {member['weight']:g}, {state}): {keys}")
    for name, case in r.get("mismatch", {}).items():
        keys = ", ".join(f"{k}={v}" for k, v in case.items())
        console.print(f"  mismatch {name} (playback --mismatch {name}): {keys}")


def _floating_bodies(r: dict) -> None:
    if r["floating_bodies"]:
        console.print(
            f"  floating bodies (6-DoF; a robot base meant to be fixed needs `weld:`): "
            f"{', '.join(r['floating_bodies'])}"
        )


def _blocks(r: dict) -> None:
    t = _table(
        "state blocks (names for blocks / initial_state / cost)",
        ("block", "kind", "coords", "tangent", "x indices", "x0"),
    )
    for b in r["blocks"]:
        idx, vals = b["x_indices"], b["x0"]
        span = (
            f"{idx[0]}..{idx[-1]}"
            if idx == list(range(idx[0], idx[-1] + 1)) and len(idx) > 1
            else ",".join(map(str, idx))
        )
        t.add_row(
            b["name"],
            ("group, " if b["group"] else "") + b["kind"],
            str(b["size"]),
            str(b["tangent"]),
            span,
            str(vals if len(vals) > 1 else vals[0]),
        )
    _emit(t)


def _actuators(r: dict) -> None:
    cols = ("#", "actuator", "joint", "effort limit", "rotor inertia", "gear ratio", "reflected")
    t = _table("actuators (names for cost.R and actuators:)", cols)
    for k, a in enumerate(r["actuators"]):
        lim = a["effort_limit"]
        t.add_row(
            str(k),
            a["name"],
            a["joint"],
            f"{lim:g}" if math.isfinite(lim) else "none (unbounded)",
            f"{a['rotor_inertia']:.3g}",
            f"{a['gear_ratio']:.3g}",
            f"{a['reflected_inertia']:.3g}",
        )
    _emit(t)


def _geometries(r: dict) -> None:
    cols = ("geometry", "body", "shape", "hydroelastic", "modulus [Pa]", "hint [m]", "friction")
    t = _table("collision geometries (names for geometry overrides)", (*cols, "damping"))
    sap = r["model"]["contact_approximation"] == "sap"
    for g in r["geometries"]:
        t.add_row(
            g["name"],
            g["body"],
            g["shape"],
            g["kind"],
            "" if g["modulus"] is None else f"{g['modulus']:.3g}",
            "" if g["resolution_hint"] is None else f"{g['resolution_hint']:g}",
            "" if g["friction"] is None else f"{g['friction']:g}",
            _damping(g, sap),
        )
    _emit(t)
    if sap:
        console.print(
            "damping: sap uses relaxation times (a pair's τ is the sum of its two geometries'); "
            "Hunt-Crossley dissipation applies under tamsi, similar or lagged only"
        )
    for key, hits in r["geometry_overrides"].items():
        several = len({h.split("/")[0] for h in hits}) > 1
        console.print(
            f"geometry.{key} applies to: {', '.join(hits)}"
            + (f" (BODY/{key} picks one)" if several else "")
        )


def _damping(g: dict, sap: bool) -> str:
    """The damping the contact solver uses: SAP a relaxation time (default 0.1 s per
    geometry), the others Hunt-Crossley dissipation."""
    if sap:
        rt = g["relaxation_time"]
        return f"τ {0.1 if rt is None else rt:g} s" + (" (default)" if rt is None else "")
    d = g["dissipation"]
    return "" if d is None else f"{d:g} s/m"


def _pairs(r: dict) -> None:
    pairs = r["pairs"]
    t = _table(
        f"candidate collision pairs ({len(pairs)}), closest first",
        ("A", "B", "kinds", "contact model", "distance at x0 [m]"),
    )
    for p in pairs[:PAIRS_SHOWN]:
        d = "n/a" if p["distance"] is None else f"{p['distance']:.4g}"
        t.add_row(p["a"], p["b"], p["kinds"], p["model"], d)
    _emit(t)
    if len(pairs) > PAIRS_SHOWN:
        console.print(f"  ... and {len(pairs) - PAIRS_SHOWN} more pairs")
    for o in r["no_contact_with"]:
        console.print(
            f"  scene[{o['index']}] ({o['name']}) never touches: "
            f"{', '.join(o['geometries'])} (no_contact_with; not listed above)"
        )


def _stiffness(rows: list[dict]) -> None:
    """Each compliant geometry's force pressed into a rigid plane (studies/stiffness.py)."""
    if rows:
        console.print(
            "[bold]compliant geometries pressed into a rigid plane[/bold] (force at an "
            "overlap, and force/overlap: match a point contact's stiffness with "
            "hydroelastic_modulus; the force scales with it)"
        )
    for g in rows:
        forces = ", ".join(
            f"{f['force_n']:.3g} N at {1e3 * f['overlap_m']:g} mm "
            f"({f['stiffness_n_per_m']:.3g} N/m)"
            for f in g["forces"]
        )
        console.print(f"  {g['geometry']} (modulus {g['modulus']:.3g} Pa): {forces}")


def _contacts(r: dict) -> None:
    _stiffness(r.get("stiffness") or [])
    contacts = r["contacts"]
    if contacts:
        console.print(
            f"[bold]contact at the initial state[/bold]: {len(contacts)} pair(s), "
            f"{r['contact_faces']} hydroelastic polygons"
        )
        for c in contacts:
            n = c["faces"]
            console.print(f"  {c['a']} / {c['b']}: " + (f"{n} polygons" if n else "point contact"))
    else:
        console.print("[bold]contact at the initial state[/bold]: none")
    n_touch, overlapping = len(contacts), r["overlapping_pairs"]
    if overlapping > n_touch:
        console.print(
            f"  ({overlapping} pair(s) overlap in the exact shapes, {n_touch} touch: a "
            "hydroelastic mesh of a curved shape lies inside the exact surface, by up to a "
            "fraction of its resolution_hint, so a shallow overlap can have no contact)"
        )


def _position_guess(p: dict) -> None:
    """The tracking rollout of a position guess: how closely it follows the path, where the
    rest of the state went, how hard it pushes."""
    tracked = ", ".join(
        f"{k} {v['max_error']:.3g} (at {v['at_s']:g} s)" for k, v in p["tracked"].items()
    )
    console.print(f"  position guess: tracking rollout, largest |q - q_ref|: {tracked}")
    if p["others"]:
        console.print(
            "  the rest of the configuration (first -> last state): "
            + ", ".join(f"{k} {a:.3g} -> {b:.3g}" for k, (a, b) in p["others"].items())
        )
    effort = [f"{k} {v:.2f}" for k, v in p["effort_to_limit"].items() if v is not None]
    if effort:
        console.print(f"  largest control / effort limit: {', '.join(effort)}")
    if p.get("unactuated"):
        console.print(
            "  unactuated, asked -> reached by the tracking rollout at the end: "
            + ", ".join(
                f"{k} {v['asked']:.3g} -> {v['reached']:.3g}" for k, v in p["unactuated"].items()
            )
        )


def _realized_guess(r: dict) -> None:
    """Where the realization (initial_guess.realize) takes the unactuated coordinates: the
    tracking with virtual forces, and the realized guess on the task's own plant."""
    console.print(
        "  realized (initial_guess.realize), at the end: "
        + ", ".join(
            f"{k} {v['virtual_tracking']:.3g} with virtual forces, {v['realized']:.3g} realized"
            for k, v in r["ends"].items()
        )
    )
    stages = ", ".join(f"weight {s['weight']:g}: {s['max_virtual_force']:.3g}" for s in r["stages"])
    console.print(
        f"  largest virtual force per stage: {stages}; hand-off to the plant: {r['handoff']}"
    )


def _ms(m: dict) -> str:
    both = m["ms_in_contact"] is not None and m["ms_without_contact"] is not None
    split = (
        f" ({m['ms_in_contact']:.3g} in contact, {m['ms_without_contact']:.3g} without)"
        if both
        else ""
    )
    return f"{m['ms_per_step']:.3g} ms/step{split}"


def _step_cost(c: dict) -> None:
    """Contact faces per pair along the guess and what a coarser mesh gives
    (studies/step_cost.py)."""
    now = c.get("now")
    if not now or not now["pairs"]:
        return
    pairs = "; ".join(
        f"{p['pair'][0]}/{p['pair'][1]} up to {p['max_faces']} (mean {p['mean_faces']:.0f} "
        f"over {p['steps']} steps)"
        for p in now["pairs"]
    )
    console.print(f"  contact faces along {c['steps']} steps of the guess: {pairs}; {_ms(now)}")
    coarse = c.get("coarser")
    if coarse is not None:
        console.print(
            f"  most faces: {c['geometry']} (resolution_hint {c['resolution_hint']:g}); with "
            f"{2 * c['resolution_hint']:g}, measured: up to {coarse['max_faces']} faces at a step "
            f"(now {now['max_faces']}), {_ms(coarse)}"
        )


def _bases(b: dict) -> None:
    """Where each free or planar base ends along the guess (studies/bases.py)."""
    for row in b.get("bodies") or []:
        end = ", ".join(f"{v:.2f}" for v in row["end"])
        console.print(
            f"  {row['name']} (free base) after {b['steps']} steps of the guess: at ({end}) m, "
            f"lowest z {row['lowest_z']:.2f} m, top speed {row['top_speed']:.2g} m/s"
        )


def _simulation(r: dict) -> None:
    n, steps, guess = r["rollout_steps"], r["task_steps"], r["model"]["initial_guess"]
    rollout = (
        f"{n}-step rollout of the initial guess ({guess})"
        if n >= steps
        else f"rollout of the initial guess ({guess}) over the first {n} of the task's "
        f"{steps} steps"
    )
    console.print(
        f"[bold]simulation[/bold]: one step ok ({r['step_ms']:.2f} ms); {rollout} ok, "
        f"{r['rollout_ms_per_step']:.2f} ms/step, max |v| = {r['max_speed']:.3g}" + _speed_unit(r)
    )
    if r.get("position_guess"):
        _position_guess(r["position_guess"])
    if r.get("realized_guess"):
        _realized_guess(r["realized_guess"])
    touched = r.get("touched_pairs") or []
    along = f"along the rollout of the initial guess ({r['contact_rollout_steps']} steps)"
    if touched:
        console.print(
            f"  pairs touching {along}, states: "
            + ", ".join(f"{t['pair'][0]}/{t['pair'][1]} ({t['steps']})" for t in touched)
        )
    else:
        console.print(f"  no contact {along}")
    _bases(r.get("bases") or {})
    _step_cost(r.get("step_cost") or {})
    pull = r.get("cost_pull")
    if pull:
        names = ", ".join(r.get("tracked_objects") or [])
        console.print(
            f"  the cost brings the robot to {names}: with the guess's commands scaled by "
            f"{pull['scale']:g} (the control cost R pulls them towards 0, as the solver's "
            f"first steps do) the rollout touches {', '.join('/'.join(p) for p in pull['pairs'])}"
        )
    for t in r.get("terms") or []:  # cost.terms on the guess's rollout over the horizon
        err = "outside its window" if t["error"] is None else f"|r| = {t['error']:.4g}"
        err = "on the commands" if t.get("controls") else err
        stages = "".join(
            f"; continuation[{i}]: weight {_weight(w)}"
            for i, w in (t.get("stage_weights") or {}).items()
        )
        console.print(
            f"  cost term {t['name']} ({t['type']}): {err}, cost {t['cost']:.4g} "
            f"(weight {_weight(t.get('weight'))}{stages})"
        )


def _speed_unit(r: dict) -> str:
    """' rad/s (elbow.v)': the unit and the coordinate of check's largest velocity."""
    unit, name = r.get("max_speed_unit", ""), r.get("max_speed_coordinate", "")
    return (f" {unit}" if unit else "") + (f" ({name})" if name else "")


def _weight(w) -> str:
    """A term's weight: a number as %g, one per axis as a list."""
    return f"{w:g}" if isinstance(w, (int, float)) else str(w)


def _warnings(r: dict) -> None:
    for w in r["warnings"]:
        console.print(f"[yellow]warning:[/yellow] {w}")
    console.print(
        "[green]check passed[/green]"
        + (f" with {len(r['warnings'])} warning(s)" if r["warnings"] else "")
    )


PRINTERS = {
    "model": _model,
    "continuation": _continuation,
    "floating_bodies": _floating_bodies,
    "blocks": _blocks,
    "actuators": _actuators,
    "geometries": _geometries,
    "pairs": _pairs,
    "contacts": _contacts,
    "simulation": _simulation,
    "warnings": _warnings,
}
