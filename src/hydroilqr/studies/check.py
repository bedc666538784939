"""``hydroilqr check TASK``: what a task file builds into, before anything is solved.

``check_task(task)`` reports (``hydroilqr check`` prints it)

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

It returns a dict of these facts and raises ``SimulationError`` if the simulation check fails;
warnings (no collision pairs, velocities blowing up, ...) are listed under ``"warnings"``.
"""

from __future__ import annotations

import time

import numpy as np

from hydroilqr import metrics
from hydroilqr.metrics import validate_task
from hydroilqr.metrics.common import coordinate_name, coordinate_units
from hydroilqr.metrics.terms import terms_on_guess
from hydroilqr.model.contacts import (
    NO_CONTACT_REMEDY,
    cost_pull_contact,
    fixed_bodies,
    no_contact_remedy,
    touched_pairs,
    touches_moving,
    tracked_bodies,
    tracked_objects,
)
from hydroilqr.model.guess import describe as describe_guess
from hydroilqr.model.guess import rollout_report
from hydroilqr.model.names import body_labels
from hydroilqr.model.pd import damping_bounds
from hydroilqr.model.plant import SimulationError, geometry_hits, hydroelastic_kind
from hydroilqr.problem.solver import DerivativeMethod
from hydroilqr.solver.realize import report as realize_report
from hydroilqr.studies.bases import base_report
from hydroilqr.studies.step_cost import step_cost_report
from hydroilqr.studies.stiffness import stiffness_report

# Largest rollout the sanity check runs (steps), and the speed treated as a blow-up (m/s, rad/s).
ROLLOUT_STEPS = 50
DEEP_OVERLAP = 0.005  # m: an initial overlap this deep is reported with a failed rollout,
LAUNCH_SPEED = 5.0  # or with a rollout that flings something faster than this
VERY_DEEP_OVERLAP = 0.02  # m: reported in any case (a resting foot or ball sinks a few mm)
BLOWUP_SPEED = 100.0


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
                "shapes": f"{ga['shape']}/{gb['shape']}",
                "model": _pair_model(ga["kind"], gb["kind"], dyn.spec.plant.contact_model),
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


def check_task(task, rollout_steps: int = ROLLOUT_STEPS, on_section=None) -> dict:
    """The report described in the module docstring, as a dict of facts. ``on_section(name,
    report)`` is called as each section is complete (``SECTIONS``, in that order; the report
    so far), so a caller can show it while the rest is computed, and before an error."""
    cfg = task.config
    dyn = task.dynamics
    x0 = task.x0
    _ = task.cost  # validates the cost's names and sizes

    metrics.validate(task)  # metric names and metric_params
    out: dict = {"warnings": []}
    warn = out["warnings"].append

    def done(section: str) -> None:
        if on_section is not None:
            on_section(section, out)

    out["model"] = _model(task)
    if cfg.solver.derivatives in ("forward", "central"):
        out["fd"] = _fd(dyn, cfg.solver.fd_forces)
        fd = out["fd"]
        out["fd_steps_per_time_step"] = (
            fd["forces"] if fd["fd_forces"] and fd["qualifies"] else fd["plain"]
        )
    done("model")

    if cfg.continuation or cfg.ensemble or cfg.mismatch:
        validate_task(task)  # builds every stage, member and mismatch case: bad keys named here
    if cfg.mismatch:
        out["mismatch"] = {name: dict(case) for name, case in cfg.mismatch.items()}
    if cfg.continuation:
        out["continuation"] = [dict(s) for s in cfg.continuation]
    if cfg.ensemble:
        out["ensemble"] = _ensemble(task, rollout_steps)
        out["warnings"] += [m["warning"] for m in out["ensemble"] if m.get("warning")]
    done("continuation")

    plant = dyn.plant
    labels = body_labels(plant)
    free = [labels[int(i)] for i in plant.GetFloatingBaseBodies()]
    out["floating_bodies"] = sorted(free)
    done("floating_bodies")

    out["blocks"] = _blocks(dyn.layout, x0)
    done("blocks")

    out["actuators"] = _actuators(dyn)
    done("actuators")

    geoms = geometry_table(dyn)
    out["geometries"] = [{k: v for k, v in g.items() if k != "id"} for g in geoms]
    out["geometry_overrides"] = _geometry_overrides(dyn, task.config.geometry)
    done("geometries")
    _settings_warnings(task, geoms, warn)

    pairs = candidate_pairs(dyn, x0, geoms)
    out["pairs"] = pairs
    out["no_contact_with"] = [
        {"index": i, "name": o.name or f"scene_{i}", "geometries": list(o.no_contact_with)}
        for i, o in enumerate(cfg.scene)
        if o.no_contact_with
    ]
    done("pairs")
    if geoms and not pairs:
        warn("no candidate collision pairs (all filtered, e.g. geometry on adjacent bodies)")
    w = _autodiff_point_warning(pairs, cfg.solver.derivatives)
    if w:
        warn(w)

    _contact_at_start(dyn, x0, pairs, out)
    out["stiffness"] = stiffness_report(dyn, geoms, pairs)  # (forces at a few overlaps)
    done("contacts")

    _simulation(task, pairs, rollout_steps, out)
    out["step_cost"] = step_cost_report(task, out["rollout_steps"])  # (faces, ms, coarser)
    if cfg.cost.terms:  # the task-space cost terms on the guess's rollout over the horizon
        out["terms"] = terms_on_guess(task)
    done("simulation")
    _rollout_warnings(pairs, out, warn)
    done("warnings")
    return out


def _autodiff_point_warning(pairs: list[dict], derivatives: str) -> str:
    """Under autodiff, the point-contact pairs Drake cannot differentiate: those where neither
    shape is a sphere ("" if none)."""
    if DerivativeMethod(derivatives) is not DerivativeMethod.AUTODIFF:
        return ""
    bad = [
        p for p in pairs if p["model"] != "hydroelastic" and "Sphere" not in p["shapes"].split("/")
    ]
    if not bad:
        return ""
    names = ", ".join(f"{p['a']}/{p['b']} ({p['shapes']})" for p in bad[:3])
    more = f" and {len(bad) - 3} more" if len(bad) > 3 else ""
    return (
        f"{len(bad)} point-contact pair(s) without a sphere under autodiff ({names}{more}): "
        "Drake differentiates point contact only when one shape is a sphere; prefer central "
        "differences or set compliance"
    )


def _settings_warnings(task, geoms: list, warn) -> None:
    """No collision geometry at all; rigid geometry given a hydroelastic modulus; a search's
    PD+ damping an explicit step cannot keep stable (``pd_damping_warning``)."""
    cfg = task.config
    w = pd_damping_warning(task.dynamics, task.x0, cfg.search)
    if w:
        warn(w)
    if not geoms:
        warn("no collision geometry: the task has no contact at all")
    props = [(f"geometry.{k}", p) for k, p in cfg.geometry.items()]
    props += [(f"scene {o.name}", o) for o in cfg.scene]
    for key, p in props:
        if p.compliance == "rigid" and p.hydroelastic_modulus is not None:
            warn(f"{key}: compliance rigid, so its hydroelastic_modulus is not used")


def _rollout_warnings(pairs: list, out: dict, warn) -> None:
    """What the start and the guess's rollout show: a deep overlap or a rollout that blows
    up, contact that misses the tracked objects, too many contact polygons."""
    w = _start_warning(pairs, out["max_speed"])
    if w:
        warn(w)
    for w in out["bases"]["warnings"]:  # (free and planar bases: fell, left, flew)
        warn(w)
    if out.get("cost_pull"):  # the cost itself brings the robot to the object
        return _rollout_more_warnings(out, warn)
    w = _untracked_contact_warning(
        out["touched_pairs"],
        set(out["tracked_objects"]),
        set(out["fixed_bodies"]),
        out.get("no_contact_remedy", ""),
    )
    if w:
        warn(w)
    _rollout_more_warnings(out, warn)


def _rollout_more_warnings(out: dict, warn) -> None:
    if out["contact_faces"] > 500:
        warn(
            f"{out['contact_faces']} contact polygons at x0: consider a coarser "
            "resolution_hint (the polygon count dominates the cost of derivatives)"
        )


def _untracked_contact_warning(
    touched: list[dict], tracked: set[str], fixed: set[str], remedy: str = ""
) -> str:
    """A warning when along the guess's rollout no moving body touches an object the cost
    tracks (``tracked_objects``; the same test as solve's ``no_progress`` sentence): gradients
    reach an object only through contact with what moves (resting on the ground gives none),
    so the solve could not start moving it. ``remedy``: what to do
    (``model.contacts.no_contact_remedy``, the words solve's no-progress sentence uses)."""

    if not tracked or touches_moving(touched, tracked, fixed):
        return ""
    names = ", ".join(sorted(tracked))
    if not touched:
        what = "the initial-guess rollout touches nothing"
    elif not any(set(p["bodies"]) & tracked for p in touched):
        what = f"no pair touched along the initial-guess rollout involves {names}"
    else:
        what = f"along the initial-guess rollout {names} touches only what is fixed to the world"
    return (
        f"{what}, and the cost tracks {names}: no gradient reaches it at the start "
        f"(a solve likely ends with status no_progress); {remedy or NO_CONTACT_REMEDY}"
    )


def _ensemble(task, rollout_steps: int) -> list[dict]:
    """Per ensemble member: its overrides and weight, and whether the initial guess's
    rollout (its first ``rollout_steps`` steps) runs on it (a warning if not)."""
    U = task.initial_guess(task.steps)[: min(task.steps, rollout_steps)]
    out = []
    for i, member in enumerate(task.members()):
        entry = {"overrides": dict(task.config.ensemble[i]), "weight": task.config.ensemble_weight}
        try:
            member.dynamics.rollout(task.x0, U)
        except SimulationError as e:
            entry["warning"] = f"ensemble[{i}]: the initial guess's rollout fails: {e}"
        out.append(entry)
    return out


#: The sections of ``check_task``'s report, in the order they are complete.
SECTIONS = (
    "model",
    "continuation",
    "floating_bodies",
    "blocks",
    "actuators",
    "geometries",
    "pairs",
    "contacts",
    "simulation",
    "warnings",
)


def _model(task) -> dict:
    cfg, dyn = task.config, task.dynamics
    return {
        "name": task.name,
        "files": [m.file for m in cfg.models],
        "nq": dyn.nq,
        "nv": dyn.nv,
        "nx": dyn.nx,
        "nu": dyn.nu,
        "dt": dyn.dt,
        "steps": task.steps,
        "contact_approximation": cfg.plant.contact_approximation,
        "contact_model": cfg.plant.contact_model,
        "contact_surface_representation": cfg.plant.contact_surface_representation,
        "derivatives": cfg.solver.derivatives,
        "initial_guess": describe_guess(cfg.initial_guess),
        "gravity_off": [
            f"models[{i}]: {m.file}" for i, m in enumerate(cfg.models) if not m.gravity
        ],
    }


def _fd(dyn, fd_forces: bool) -> dict:
    """Perturbed steps per time step of plain differences and of differences over
    generalized forces, and whether the model qualifies for the latter."""
    return {
        "plain": dyn.nx + dyn.nu,
        "forces": dyn.nq + dyn.nv,
        "fd_forces": bool(fd_forces),
        "qualifies": dyn.force_path() is not None,
    }


def pd_damping_warning(dyn, x0, search) -> str:
    """A search in position space whose PD+ damping ``search.kd`` is at or above the bound an
    explicit step keeps stable on a freely moving joint (``model.pd.damping_bounds`` at x0):
    the joints it names ring in the air ("" when none, or no such search)."""
    if search is None or search.space != "position":
        return ""
    bounds = damping_bounds(dyn.plant, x0, dyn.dt)
    over = [
        (dyn.plant.get_joint_actuator(i).joint().name(), b)
        for i, b in zip(dyn.plant.GetJointActuatorIndices(), bounds)
        if search.kd >= b
    ]
    if not over:
        return ""
    names = ", ".join(f"{n} ({b:.3g})" for n, b in over[:4])
    more = f" and {len(over) - 4} more" if len(over) > 4 else ""
    return (
        f"search.kd {search.kd:g} is at or above the damping a {dyn.dt:g} s step keeps stable "
        f"on a joint moving freely, 2·I/dt, for {names}{more}: out of contact such a joint rings "
        "towards its effort limit; lower search.kd below the smallest, or shorten the time step"
    )


def _actuators(dyn) -> list[dict]:
    actuators = []
    for k, i in enumerate(dyn.plant.GetJointActuatorIndices()):
        a = dyn.plant.get_joint_actuator(i)
        actuators.append(
            {
                "name": a.name(),
                "joint": a.joint().name(),
                "effort_limit": float(dyn.effort_limits[k]),
                "rotor_inertia": float(a.default_rotor_inertia()),
                "gear_ratio": float(a.default_gear_ratio()),
                "reflected_inertia": float(a.default_reflected_inertia()),
            }
        )
    return actuators


def _geometry_overrides(dyn, geometry: dict) -> dict[str, list[str]]:
    """Each ``geometry:`` key of the task -> the BODY/GEOMETRY names it applies to."""

    names = dyn.geometry_names()
    return {
        key: [f"{names[g][1]}/{names[g][0]}" for g in geometry_hits(key, names)] for key in geometry
    }


def _blocks(layout, x0: np.ndarray) -> list[dict]:
    """The state blocks (task groups first): name, size, tangent size, kind, whether a group,
    their indices in x and their values at x0."""
    blocks = []
    for name, nc, nt, kind in layout.describe():
        idx = list(layout.block(name).coords)
        blocks.append(
            {
                "name": name,
                "size": nc,
                "tangent": nt,
                "kind": kind,
                "group": name in layout.groups,
                "x_indices": idx,
                "x0": np.round(x0[idx], 4).tolist(),
            }
        )
    return blocks


def _contact_at_start(dyn, x0: np.ndarray, pairs: list[dict], out: dict) -> None:
    """The pairs touching at x0 with their polygon counts, and how many overlap exactly."""
    try:
        contacts = dyn.contact_surfaces(x0)
    except RuntimeError as e:
        raise SimulationError(
            f"contact query at the initial state: {str(e).strip().splitlines()[0]}"
        ) from None
    out["contacts"] = [{"a": a, "b": b, "faces": n} for a, b, n in contacts]
    out["contact_faces"] = int(sum(n for _, _, n in contacts))
    out["overlapping_pairs"] = sum(
        1 for p in pairs if p["distance"] is not None and p["distance"] < 0
    )


def _simulation(task, pairs: list[dict], rollout_steps: int, out: dict) -> None:
    """One timed step, then a timed rollout of the initial guess (SimulationError with the
    reason, and a deep initial overlap if there is one)."""
    dyn, x0 = task.dynamics, task.x0
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
            f"rollout of the initial guess ({describe_guess(task.config.initial_guess)}): {e}{hint}"
        ) from None
    rollout_ms = 1e3 * (time.perf_counter() - tic) / max(N, 1)
    out["position_guess"] = rollout_report(task)  # (None unless the guess is positions)
    if out["position_guess"] and task.config.initial_guess.realize is not None:
        out["realized_guess"] = realize_report(task, out["position_guess"]["unactuated"])
    speed = float(np.max(np.abs(X[:, dyn.nq :]))) if dyn.nv else 0.0
    fastest = dyn.nq + int(np.argmax(np.max(np.abs(X[:, dyn.nq :]), axis=0))) if dyn.nv else 0

    tracked = tracked_objects(task)
    Xc = _contact_rollout(task, X) if tracked else X
    out["bases"] = base_report(task, Xc if tracked else _contact_rollout(task, X))
    touched = touched_pairs(task, Xc)
    pull = None
    if tracked and not touches_moving(touched, tracked, fixed_bodies(task)):
        pull = cost_pull_contact(task, task.initial_guess(task.steps)[: len(Xc) - 1])
    out.update(
        {
            "cost_pull": pull,
            "no_contact_remedy": no_contact_remedy(task, None, ", ".join(sorted(tracked))),
            "touched_pairs": touched,
            "contact_rollout_steps": len(Xc) - 1,
            "tracked_bodies": sorted(tracked_bodies(task)),
            "tracked_objects": sorted(tracked),
            "fixed_bodies": sorted(fixed_bodies(task)),
            "one_step_ok": bool(np.all(np.isfinite(x1))),
            "rollout_steps": N,
            "task_steps": task.steps,
            "max_speed": speed,
            "max_speed_coordinate": coordinate_name(dyn.layout, fastest) if dyn.nv else "",
            "max_speed_unit": coordinate_units(dyn)[fastest] if dyn.nv else "",
            "step_ms": step_ms,
            "rollout_ms_per_step": rollout_ms,
        }
    )


def guess_trajectory(task) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t: [N+1] s, X: [N+1, nx], U: [N, nu]): the task's initial guess rolled out from x0
    over its whole horizon (a receding-horizon task: all its steps), as a solve starts."""
    U = task.initial_guess(task.steps)
    X = task.dynamics.rollout(task.x0, U)
    return task.config.plant.time_step * np.arange(len(X)), X, U


def _contact_rollout(task, X: np.ndarray) -> np.ndarray:
    """The states along which contact with the tracked objects is judged: the whole initial
    guess of a single solve, as the solve itself sees it (``X``, the timed rollout's first
    steps, extended); for a receding-horizon task its first window."""
    rh = task.config.receding_horizon
    steps = min(task.steps, rh.window_steps) if rh is not None else task.steps
    if len(X) - 1 >= steps:
        return X
    try:
        return task.dynamics.rollout(task.x0, task.initial_guess(task.steps)[:steps])
    except SimulationError:
        return X  # (the solve reports a rollout that fails)
