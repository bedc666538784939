"""``hydroilqr check TASK``: what a task file builds into, before anything is solved.

``check_task(task, console)`` prints

* the model: positions, velocities, actuators, time step, horizon, contact settings;
* the state layout: every named block (task groups first) with its size and kind, which are
  the names usable in ``blocks``, ``initial_state`` and ``cost``;
* actuators with their effort limits (the names usable in ``cost.R``);
* collision geometries with their hydroelastic kind (compliant / rigid / none) and modulus;
* candidate collision pairs with the contact model Drake will use for each, and the signed
  distance at the initial state where Drake can compute it;
* contact at the initial state: touching pairs and the number of contact-surface polygons
  (which dominates the cost of a time step and of its derivatives);
* a simulation sanity check: one time step from the initial state with the first input of the
  initial guess, then a short open-loop rollout of the initial guess, both timed.

It returns a dict of the same facts (for tests and scripts) and raises ``SimulationError`` if
the simulation check fails; warnings (no collision pairs, velocities blowing up, ...) are
printed and listed under ``"warnings"``.
"""

from __future__ import annotations

import time

import numpy as np

from hydroilqr.model.plant import SimulationError, hydroelastic_kind
from hydroilqr.problem.config import DerivativeMethod

# Largest rollout the sanity check runs (steps), and the speed treated as a blow-up (m/s, rad/s).
ROLLOUT_STEPS = 50
DEEP_OVERLAP = 0.005  # m: an initial overlap this deep is reported with a failed rollout,
LAUNCH_SPEED = 5.0  # or with a rollout that flings something faster than this
VERY_DEEP_OVERLAP = 0.02  # m: reported in any case (a resting foot or ball sinks a few mm)
BLOWUP_SPEED = 100.0


def _fmt_limit(e: float) -> str:
    return f"{e:g}" if np.isfinite(e) else "none (unbounded)"


def _pair_model(ka: str, kb: str, contact_model: str) -> str:
    if contact_model == "point":
        return "point"
    if "none" in (ka, kb) or ka == kb == "rigid":
        return "point (fallback)"
    return "hydroelastic"


def geometry_table(dyn) -> list[dict]:
    """One row per collision geometry: name, body, shape, kind, modulus, resolution hint."""
    inspector = dyn.scene_graph.model_inspector()
    rows = []
    for gid, (name, body) in dyn.geometry_names().items():
        props = inspector.GetProximityProperties(gid)
        kind = hydroelastic_kind(props)

        def prop(group, key, props=props):
            if props is not None and props.HasProperty(group, key):
                return props.GetProperty(group, key)
            return None

        friction = prop("material", "coulomb_friction")
        rows.append(
            {
                "id": gid,
                "name": name,
                "body": body,
                "shape": type(inspector.GetShape(gid)).__name__,
                "kind": kind,
                "modulus": prop("hydroelastic", "hydroelastic_modulus"),
                "resolution_hint": prop("hydroelastic", "resolution_hint"),
                "friction": friction.static_friction() if friction is not None else None,
                "relaxation_time": prop("material", "relaxation_time"),
                "dissipation": prop("material", "hunt_crossley_dissipation"),
            }
        )
    return rows


def candidate_pairs(dyn, x: np.ndarray, geoms: list[dict]) -> list[dict]:
    """Collision candidates with their contact model and signed distance at x (None if Drake
    cannot compute it for that shape pair)."""
    inspector = dyn.scene_graph.model_inspector()
    by_id = {g["id"]: g for g in geoms}
    dyn.plant.SetPositionsAndVelocities(dyn.plant_context, x)
    query = dyn.plant.get_geometry_query_input_port().Eval(dyn.plant_context)
    rows = []
    for a, b in inspector.GetCollisionCandidates():
        ga, gb = by_id.get(a), by_id.get(b)
        if ga is None or gb is None:
            continue
        try:
            dist = float(query.ComputeSignedDistancePairClosestPoints(a, b).distance)
        except RuntimeError:
            dist = None
        rows.append(
            {
                "a": f"{ga['name']} ({ga['body']})",
                "b": f"{gb['name']} ({gb['body']})",
                "kinds": f"{ga['kind']}/{gb['kind']}",
                "model": _pair_model(ga["kind"], gb["kind"], dyn.task.plant.contact_model),
                "distance": dist,
            }
        )
    rows.sort(key=lambda r: (r["distance"] is None, r["distance"] or 0.0, r["a"], r["b"]))
    return rows


def _deepest_overlap(pairs: list[dict]) -> str:
    """A sentence about the deepest overlap at x0 beyond DEEP_OVERLAP ("" if none)."""
    deep = sorted(
        (p for p in pairs if p["distance"] is not None and p["distance"] < -DEEP_OVERLAP),
        key=lambda p: p["distance"],
    )
    if not deep:
        return ""
    return (
        f"at x0 {deep[0]['a']} and {deep[0]['b']} overlap by {-1e3 * deep[0]['distance']:.3g} "
        "mm: check initial_state; a free body not named there starts at the world origin"
    )


def _start_warning(pairs: list[dict], speed: float) -> str:
    """The warning about the start ("" if none): a deep overlap at x0 that launches a body or
    is very deep, or a rollout of the initial guess that blows up. ``speed``: its max |v|."""
    overlap = _deepest_overlap(pairs)
    depth = max((-p["distance"] for p in pairs if p["distance"] is not None), default=0.0)
    if overlap and speed > LAUNCH_SPEED:  # a body pushed out of a deep overlap
        return f"the initial-guess rollout reaches |v| = {speed:.3g}; {overlap}"
    if overlap and depth > VERY_DEEP_OVERLAP:
        return overlap
    if speed > BLOWUP_SPEED:
        return (
            f"the initial-guess rollout reaches |v| = {speed:.3g} (> {BLOWUP_SPEED:g}): "
            "check masses, the time step and initial penetrations"
        )
    return ""


def start_warning(task, rollout_steps: int = ROLLOUT_STEPS) -> str:
    """``check``'s warning about the start, for commands that solve without ``check`` ("" if
    none, or if the rollout fails: the solve reports that itself)."""
    dyn = task.dynamics
    pairs = candidate_pairs(dyn, task.x0, geometry_table(dyn))
    U = task.initial_guess(task.steps)[: min(task.steps, rollout_steps)]
    try:
        X = dyn.rollout(task.x0, U)
    except SimulationError:
        return ""
    speed = float(np.max(np.abs(X[:, dyn.nq :]))) if dyn.nv else 0.0
    return _start_warning(pairs, speed)


def check_task(task, console, rollout_steps: int = ROLLOUT_STEPS) -> dict:
    """Prints the report described in the module docstring; returns its facts as a dict."""
    from rich.table import Table

    cfg = task.config
    dyn = task.dynamics
    layout = dyn.layout
    x0 = task.x0
    _ = task.cost  # validates the cost's names and sizes
    out: dict = {"warnings": []}
    warn = out["warnings"].append

    console.print(
        f"[bold]{task.name}[/bold]: {', '.join(m.file for m in cfg.models)}\n"
        f"  nq={dyn.nq} nv={dyn.nv} nx={dyn.nx} nu={dyn.nu}  dt={dyn.dt} s  "
        f"steps={task.steps}  contact={cfg.plant.contact_approximation} "
        f"({cfg.plant.contact_model}, {cfg.plant.contact_surface_representation})  "
        f"derivatives={cfg.solver.derivatives}"
    )

    if cfg.solver.derivatives in ("forward", "central"):
        plain, forces = dyn.nx + dyn.nu, dyn.nq + dyn.nv
        qualifies = dyn.force_path() is not None
        out["fd_steps_per_time_step"] = forces if cfg.solver.fd_forces and qualifies else plain
        if cfg.solver.fd_forces and qualifies:
            console.print(
                f"  differences over generalized forces (solver.fd_forces): {forces} perturbed "
                f"steps per time step instead of {plain}"
            )
        elif cfg.solver.fd_forces:
            console.print(
                "  solver.fd_forces: this model does not qualify (it needs SAP, or TAMSI without "
                "joint damping, and no PD actuators): plain differences, "
                f"{plain} steps per time step"
            )
        elif qualifies and forces < plain - 1:
            console.print(
                f"  (solver.fd_forces: true would take {forces} perturbed steps per time step "
                f"instead of {plain}; docs/performance.md)"
            )

    if cfg.continuation:
        task.validate()  # builds every stage: bad keys or sizes are named here
        for i, stage in enumerate(cfg.continuation):
            keys = ", ".join(f"{k}={v}" for k, v in stage.items())
            console.print(f"  continuation[{i}] (solved first): {keys}")
        out["continuation"] = [dict(s) for s in cfg.continuation]

    plant = dyn.plant
    free = [plant.get_body(i).name() for i in plant.GetFloatingBaseBodies()]
    out["floating_bodies"] = sorted(free)
    if free:
        console.print(
            f"  floating bodies (6-DoF; a robot base meant to be fixed needs `weld:`): "
            f"{', '.join(sorted(free))}"
        )

    # ---------------------------------------------------------------- state layout
    t = Table(title="state blocks (names for blocks / initial_state / cost)", title_justify="left")
    for col in ("block", "kind", "coords", "tangent", "x indices", "x0"):
        t.add_column(col)
    blocks = []
    for name, nc, nt, kind in layout.describe():
        b = layout.block(name)
        group = name in layout.groups
        idx = list(b.coords)
        span = (
            f"{idx[0]}..{idx[-1]}"
            if idx == list(range(idx[0], idx[-1] + 1)) and len(idx) > 1
            else ",".join(map(str, idx))
        )
        blocks.append({"name": name, "size": nc, "tangent": nt, "kind": kind, "group": group})
        vals = np.round(x0[idx], 4).tolist()
        t.add_row(
            name,
            ("group, " if group else "") + kind,
            str(nc),
            str(nt),
            span,
            str(vals if len(vals) > 1 else vals[0]),
        )
    console.print(t)
    out["blocks"] = blocks

    # ---------------------------------------------------------------- actuators
    t = Table(title="actuators (names for cost.R)", title_justify="left")
    for col in (
        "#",
        "actuator",
        "joint",
        "effort limit",
        "rotor inertia",
        "gear ratio",
        "reflected",
    ):
        t.add_column(col)
    actuators = []
    for k, i in enumerate(dyn.plant.GetJointActuatorIndices()):
        a = dyn.plant.get_joint_actuator(i)
        lim = float(dyn.effort_limits[k])
        rho, gear = float(a.default_rotor_inertia()), float(a.default_gear_ratio())
        reflected = float(a.default_reflected_inertia())
        actuators.append(
            {
                "name": a.name(),
                "joint": a.joint().name(),
                "effort_limit": lim,
                "rotor_inertia": rho,
                "gear_ratio": gear,
                "reflected_inertia": reflected,
            }
        )
        t.add_row(
            str(k),
            a.name(),
            a.joint().name(),
            _fmt_limit(lim),
            f"{rho:.3g}",
            f"{gear:.3g}",
            f"{reflected:.3g}",
        )
    console.print(t)
    out["actuators"] = actuators

    # ---------------------------------------------------------------- geometry
    geoms = geometry_table(dyn)
    t = Table(title="collision geometries (names for geometry overrides)", title_justify="left")
    for col in (
        "geometry",
        "body",
        "shape",
        "hydroelastic",
        "modulus [Pa]",
        "hint [m]",
        "friction",
        "damping",
    ):
        t.add_column(col)
    sap = cfg.plant.contact_approximation == "sap"
    for g in geoms:
        # The damping the contact solver uses: SAP a relaxation time (default 0.1 s per
        # geometry), the others Hunt-Crossley dissipation.
        if sap:
            rt = g["relaxation_time"]
            damping = f"τ {0.1 if rt is None else rt:g} s" + (" (default)" if rt is None else "")
        else:
            d = g["dissipation"]
            damping = "" if d is None else f"{d:g} s/m"
        t.add_row(
            g["name"],
            g["body"],
            g["shape"],
            g["kind"],
            "" if g["modulus"] is None else f"{g['modulus']:.3g}",
            "" if g["resolution_hint"] is None else f"{g['resolution_hint']:g}",
            "" if g["friction"] is None else f"{g['friction']:g}",
            damping,
        )
    console.print(t)
    if sap:
        console.print(
            "damping: sap uses relaxation times (a pair's τ is the sum of its two geometries'); "
            "Hunt-Crossley dissipation applies under tamsi, similar or lagged only"
        )
    out["geometries"] = [{k: v for k, v in g.items() if k != "id"} for g in geoms]
    from hydroilqr.model.plant import geometry_hits

    names = dyn.geometry_names()
    out["geometry_overrides"] = {}
    for key in task.config.geometry:
        hits = [f"{names[g][1]}/{names[g][0]}" for g in geometry_hits(key, names)]
        out["geometry_overrides"][key] = hits
        several = len({h.split("/")[0] for h in hits}) > 1
        console.print(
            f"geometry.{key} applies to: {', '.join(hits)}"
            + (f" (BODY/{key} picks one)" if several else "")
        )
    if not geoms:
        warn("no collision geometry: the task has no contact at all")
    props = [(f"geometry.{k}", p) for k, p in cfg.geometry.items()]
    props += [(f"scene {o.name}", o) for o in cfg.scene]
    for key, p in props:
        if p.compliance == "rigid" and p.hydroelastic_modulus is not None:
            warn(f"{key}: compliance rigid, so its hydroelastic_modulus is not used")

    pairs = candidate_pairs(dyn, x0, geoms)
    t = Table(
        title=f"candidate collision pairs ({len(pairs)}), closest first", title_justify="left"
    )
    for col in ("A", "B", "kinds", "contact model", "distance at x0 [m]"):
        t.add_column(col)
    shown = 40
    for p in pairs[:shown]:
        d = "n/a" if p["distance"] is None else f"{p['distance']:.4g}"
        t.add_row(p["a"], p["b"], p["kinds"], p["model"], d)
    console.print(t)
    if len(pairs) > shown:
        console.print(f"  ... and {len(pairs) - shown} more pairs")
    for i, o in enumerate(cfg.scene):
        if o.no_contact_with:
            console.print(
                f"  scene[{i}] ({o.name or f'scene_{i}'}) never touches: "
                f"{', '.join(o.no_contact_with)} (no_contact_with; not listed above)"
            )
    out["pairs"] = pairs
    if geoms and not pairs:
        warn("no candidate collision pairs (all filtered, e.g. geometry on adjacent bodies)")
    if any(p["model"] != "hydroelastic" for p in pairs) and (
        DerivativeMethod(cfg.solver.derivatives) is DerivativeMethod.AUTODIFF
    ):
        warn(
            "point-contact pairs under autodiff: Drake differentiates point contact only "
            "when one shape is a sphere; prefer central differences or set compliance"
        )

    # ---------------------------------------------------------------- contact at x0
    try:
        contacts = dyn.contact_surfaces(x0)
    except RuntimeError as e:
        raise SimulationError(
            f"contact query at the initial state: {str(e).strip().splitlines()[0]}"
        ) from None
    out["contacts"] = [{"a": a, "b": b, "faces": n} for a, b, n in contacts]
    out["contact_faces"] = int(sum(n for _, _, n in contacts))
    if contacts:
        console.print(
            f"[bold]contact at the initial state[/bold]: {len(contacts)} pair(s), "
            f"{out['contact_faces']} hydroelastic polygons"
        )
        for a, b, n in contacts:
            console.print(f"  {a} / {b}: " + (f"{n} polygons" if n else "point contact"))
    else:
        console.print("[bold]contact at the initial state[/bold]: none")
    n_touch = len(contacts)
    overlapping = [p for p in pairs if p["distance"] is not None and p["distance"] < 0]
    if len(overlapping) > n_touch:
        console.print(
            f"  ({len(overlapping)} pair(s) overlap in the exact shapes, {n_touch} touch: a "
            "hydroelastic mesh of a curved shape lies inside the exact surface, by up to a "
            "fraction of its resolution_hint, so a shallow overlap can have no contact)"
        )

    # ---------------------------------------------------------------- simulation
    N = min(task.steps, rollout_steps)
    U = task.initial_guess(task.steps)[:N]
    tic = time.perf_counter()
    x1 = dyn.step(x0, U[0])  # raises SimulationError with Drake's reason
    step_ms = 1e3 * (time.perf_counter() - tic)
    tic = time.perf_counter()
    overlap = _deepest_overlap(pairs)
    try:
        X = dyn.rollout(x0, U)
    except SimulationError as e:
        hint = f" ({overlap})" if overlap else ""
        raise SimulationError(
            f"rollout of the initial guess ({cfg.initial_guess}): {e}{hint}"
        ) from None
    rollout_ms = 1e3 * (time.perf_counter() - tic) / max(N, 1)
    speed = float(np.max(np.abs(X[:, dyn.nq :]))) if dyn.nv else 0.0
    out.update(
        {
            "one_step_ok": bool(np.all(np.isfinite(x1))),
            "rollout_steps": N,
            "max_speed": speed,
            "step_ms": step_ms,
            "rollout_ms_per_step": rollout_ms,
        }
    )
    console.print(
        f"[bold]simulation[/bold]: one step ok ({step_ms:.2f} ms); {N}-step rollout of the "
        f"initial guess ({cfg.initial_guess}) ok, {rollout_ms:.2f} ms/step, "
        f"max |v| = {speed:.3g}"
    )
    w = _start_warning(pairs, speed)
    if w:
        warn(w)
    if out["contact_faces"] > 500:
        warn(
            f"{out['contact_faces']} contact polygons at x0: consider a coarser "
            "resolution_hint (the polygon count dominates the cost of derivatives)"
        )

    for w in out["warnings"]:
        console.print(f"[yellow]warning:[/yellow] {w}")
    console.print(
        "[green]check passed[/green]"
        + (f" with {len(out['warnings'])} warning(s)" if out["warnings"] else "")
    )
    return out
