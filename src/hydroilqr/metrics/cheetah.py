"""Metrics and plots of the Mini Cheetah gait-discovery tasks (paper §IV-A).

``metrics: [default, cheetah]`` in a task file adds (``t`` is time from the start):

* ``target_velocity_mps``: the nominal forward base velocity (from ``cost.nominal``);
* ``mean_forward_velocity_mps``: mean forward (world x) base velocity over the last second
  (the whole run if it is shorter); ``velocity_error_fraction``: |mean − target| / target;
* ``min_body_height_m``: lowest base (body frame origin) height for t ≥ 0.2 s;
* ``body_ground_contact_steps``: states with t ≥ 0.2 s where the body's collision box touches
  the ground (a geometry query of the touching pairs at each state);
* ``duty_factor``: per foot, the fraction of states with t ≥ 0.2 s in which the foot touches the
  ground;
* ``diagonal_pair_overlap`` / ``lateral_pair_overlap``: fraction of those states in which both
  feet of a diagonal pair (FL+HR, FR+HL) / of a same-side pair (FL+HL, FR+HR) touch together,
  averaged over the two pairs (a trot has diagonal > lateral);
* ``pair_sync``: for the diagonal, lateral, front (FL+FR) and hind (HL+HR) pairs, the fraction
  of those states in which both feet are in the same phase (both down or both up), averaged over
  the pairs of a kind. It names the gait: a trot has diagonal near 1 and lateral low, a pace the
  reverse, a bound front and hind near 1. (The overlaps above reward long stance: a gait whose
  feet are mostly down overlaps in every pair.)
* ``foot_touchdowns``: per foot, how many times it goes from air to ground (t ≥ 0.2 s);
* ``foot_slip_mps``: per foot, the median horizontal speed of the foot's lowest material point
  while it touches the ground (t ≥ 0.2 s): ~0 for a planted (rolling, pivoting) foot, large
  for one that slides;
* ``foot_load``: per foot, its mean vertical ground force while it touches the ground (t ≥ 0.2
  s), as a fraction of the robot's weight m·g, from the contact solve of each step (x_k, u_k):
  a standing robot has ~0.25 on each foot; a foot that touches but carries ~0 only grazes
  (or is dragged lightly, with ``foot_slip_mps``);
* ``max_foot_faces`` / ``mean_foot_faces``: contact polygons of one foot on the ground (most,
  and mean over the states where it touches);
* ``iterations_per_resolve`` (mean) and ``resolve_seconds`` (mean) for receding-horizon runs.

``metric_params`` (all optional): ``body`` (floating body, default ``body``), ``body_collision``
(default ``body_collision``), ``ground`` (a collision name or a list of them, for a ground made
of several geometries; default ``ground``), ``feet`` (collision names, default
``{FL,FR,HL,HR}_foot_collision``), ``settle_time`` (default 0.2 s), ``window`` (default 1.0 s).

Plots: ``velocity.png`` (forward base velocity against the target, paper Fig. 4) and
``gait.png`` (foot contact diagram: a bar wherever a foot touches the ground).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hydroilqr.io.figures import pyplot, savefig
from hydroilqr.metrics.common import contact_pairs
from hydroilqr.metrics.registry import Metric, register
from hydroilqr.model.contacts import runs
from hydroilqr.problem.config import ConfigError

FEET = ("FL_foot_collision", "FR_foot_collision", "HL_foot_collision", "HR_foot_collision")
DIAGONAL = ((0, 3), (1, 2))  # FL+HR, FR+HL
LATERAL = ((0, 2), (1, 3))  # FL+HL, FR+HR
PAIRS = {"diagonal": DIAGONAL, "lateral": LATERAL, "front": ((0, 1),), "hind": ((2, 3),)}

_cache: dict = {}


def _params(task) -> dict:
    p = task.config.metric_params
    feet = list(p.get("feet", FEET))
    if len(feet) != 4:
        raise ConfigError("metric_params.feet: expected four collision names (FL, FR, HL, HR)")
    ground = p.get("ground", "ground")
    ground = [ground] if isinstance(ground, str) else list(ground)
    return {
        "body": p.get("body", "body"),
        "body_collision": p.get("body_collision", "body_collision"),
        "ground": ground,
        "feet": feet,
        "settle_time": float(p.get("settle_time", 0.2)),
        "window": float(p.get("window", 1.0)),
    }


def _blocks(task, body: str):
    layout = task.dynamics.layout
    try:
        return layout.primitives[f"{body}.position"], layout.primitives[f"{body}.velocity"]
    except KeyError:
        raise ConfigError(f"metric_params.body: no floating body named {body!r}") from None


def forward_velocity(task, sol) -> tuple[np.ndarray, np.ndarray]:
    """(actual, target) forward base velocity at every state: two arrays [T]."""
    _, vel = _blocks(task, _params(task)["body"])
    i = vel.coords[0]
    X = np.asarray(sol.X)
    target = task.cost.nominal(np.asarray(sol.t))[:, i]
    return X[:, i], target


def contacts(task, sol) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Contact state of every replayed state.

    Returns feet: [T, 4] bool (FL, FR, HL, HR on the ground), faces: [T, 4] int (contact
    polygons per foot), body: [T] bool (body box on the ground).
    """
    key = (id(task), id(sol.X), np.asarray(sol.X).shape)
    if _cache.get("key") == key:
        return _cache["value"]
    p = _params(task)
    _check_names(task, p)
    X = np.asarray(sol.X)
    T = X.shape[0]
    feet = np.zeros((T, 4), bool)
    faces = np.zeros((T, 4), int)
    body = np.zeros(T, bool)
    for k, x in enumerate(X):
        for ga, _ba, gb, _bb, n in contact_pairs(task.dynamics, x):
            if ga in p["ground"]:
                other = gb
            elif gb in p["ground"]:
                other = ga
            else:
                continue
            if other in p["feet"]:
                j = p["feet"].index(other)
                feet[k, j] = True
                faces[k, j] += n
            elif other == p["body_collision"]:
                body[k] = True
    _cache["key"], _cache["value"] = key, (feet, faces, body)
    return feet, faces, body


def foot_slip_speeds(task, sol) -> np.ndarray:
    """Horizontal speed of the lowest point of each foot sphere, as a point of the leg it is
    welded to (the material point that touches the ground), at every state: [T, 4]. A foot
    that rolls or pivots without slipping has ~0 there while it touches; a sliding foot does
    not. Feet that are not spheres use their geometry origin."""
    dyn = task.dynamics
    plant = dyn.plant
    inspector = dyn.scene_graph.model_inspector()
    ids = {name: gid for gid, (name, _) in dyn.geometry_names().items()}
    feet = []
    for name in _params(task)["feet"]:
        gid = ids[name]
        shape = inspector.GetShape(gid)
        radius = shape.radius() if hasattr(shape, "radius") else 0.0
        body = plant.GetBodyFromFrameId(inspector.GetFrameId(gid))
        feet.append((gid, body, radius))
    S = np.zeros((len(sol.X), 4))
    for k, x in enumerate(np.asarray(sol.X)):
        plant.SetPositionsAndVelocities(dyn.plant_context, x)
        query = plant.get_geometry_query_input_port().Eval(dyn.plant_context)
        for j, (gid, body, radius) in enumerate(feet):
            p = query.GetPoseInWorld(gid).translation() - np.array([0.0, 0.0, radius])
            X_WB = plant.EvalBodyPoseInWorld(dyn.plant_context, body)
            V_WB = plant.EvalBodySpatialVelocityInWorld(dyn.plant_context, body)
            v = V_WB.translational() + np.cross(V_WB.rotational(), p - X_WB.translation())
            S[k, j] = np.hypot(v[0], v[1])
    return S


def foot_vertical_forces(task, sol) -> np.ndarray:
    """Vertical ground force on each foot (N, from the contact results of the step from
    (X[k], U[k])): [N, 4] for X: [N+1, nx], U: [N, nu] (the last state has no step); [0, 4]
    for a run without controls."""
    dyn = task.dynamics
    plant = dyn.plant
    p = _params(task)
    ids = {gid: name for gid, (name, _) in dyn.geometry_names().items()}
    X = np.asarray(sol.X)
    U = getattr(sol, "U", None)
    U = np.zeros((0, dyn.nu)) if U is None else np.asarray(U)
    if U.ndim != 2 or U.shape[1] != dyn.nu or len(U) >= len(X):
        U = np.zeros((0, dyn.nu))  # no controls for these states: no forces
    F = np.zeros((len(U), 4))
    port = plant.get_contact_results_output_port()
    for k in range(len(U)):
        plant.SetPositionsAndVelocities(dyn.plant_context, X[k])
        dyn._input.FixValue(dyn.context, U[k])
        results = port.Eval(dyn.plant_context)
        for i in range(results.num_hydroelastic_contacts()):
            info = results.hydroelastic_contact_info(i)
            s = info.contact_surface()
            names = (ids.get(s.id_M()), ids.get(s.id_N()))
            if not any(n in p["ground"] for n in names):
                continue
            for n in names:
                if n in p["feet"]:
                    F[k, p["feet"].index(n)] += abs(info.F_Ac_W().translational()[2])
        for i in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(i)
            names = (ids.get(info.point_pair().id_A), ids.get(info.point_pair().id_B))
            if not any(n in p["ground"] for n in names):
                continue
            for n in names:
                if n in p["feet"]:
                    F[k, p["feet"].index(n)] += abs(info.contact_force()[2])
    return F


def pair_sync(f: np.ndarray) -> dict[str, float]:
    """f: [T, 4] foot contact flags (FL, FR, HL, HR) -> for each pair kind, the fraction of
    steps in which both feet of a pair are in the same phase, averaged over its pairs."""
    n = max(1, f.shape[0])
    return {
        kind: float(np.mean([np.sum(f[:, a] == f[:, b]) / n for a, b in pairs]))
        for kind, pairs in PAIRS.items()
    }


def cheetah_metrics(task, sol) -> dict:
    p = _params(task)
    pos, _ = _blocks(task, p["body"])
    t = np.asarray(sol.t) - float(np.asarray(sol.t)[0])
    X = np.asarray(sol.X)
    vx, target = forward_velocity(task, sol)
    last = t >= t[-1] - p["window"] - 1e-9
    settled = t >= p["settle_time"] - 1e-9
    if not settled.any():
        settled = np.ones_like(settled)
    feet, faces, body = contacts(task, sol)
    f = feet[settled]
    n = max(1, f.shape[0])
    v_target = float(target[-1])
    v_mean = float(np.mean(vx[last]))
    touchdowns = np.sum(f[1:] & ~f[:-1], axis=0) if f.shape[0] > 1 else np.zeros(4, int)
    in_contact = faces[feet]
    labels = [name.split("_")[0] for name in p["feet"]]
    out = {
        "target_velocity_mps": v_target,
        "mean_forward_velocity_mps": v_mean,
        "velocity_error_fraction": (
            abs(v_mean - v_target) / abs(v_target) if v_target else abs(v_mean)
        ),
        "min_body_height_m": float(np.min(X[settled, pos.coords[2]])),
        "body_ground_contact_steps": int(np.sum(body[settled])),
        "duty_factor": {lab: float(np.sum(f[:, j]) / n) for j, lab in enumerate(labels)},
        "diagonal_pair_overlap": float(
            np.mean([np.sum(f[:, a] & f[:, b]) / n for a, b in DIAGONAL])
        ),
        "lateral_pair_overlap": float(np.mean([np.sum(f[:, a] & f[:, b]) / n for a, b in LATERAL])),
        "pair_sync": pair_sync(f),
        "foot_touchdowns": {lab: int(touchdowns[j]) for j, lab in enumerate(labels)},
        "foot_slip_mps": _stance_slip(task, sol, feet, settled, labels),
        "foot_load": _foot_load(task, sol, feet, settled, labels),
        "max_foot_faces": int(np.max(faces)) if faces.size else 0,
        "mean_foot_faces": float(np.mean(in_contact)) if in_contact.size else 0.0,
    }
    resolves = (sol.extra or {}).get("resolves") or []
    if resolves:
        out["iterations_per_resolve"] = float(np.mean([r["iterations"] for r in resolves]))
        out["resolve_seconds"] = float(np.mean([r["seconds"] for r in resolves]))
    return out


def _stance_slip(task, sol, feet, settled, labels) -> dict[str, float]:
    """Per foot, the median slip speed (``foot_slip_speeds``) over states where it touches the
    ground (t ≥ settle). The median: a foot lands still moving and sticks within a few steps,
    so a mean is dominated by touchdowns and grazes."""
    S = foot_slip_speeds(task, sol)
    on = feet & settled[:, None]
    return {
        lab: float(np.median(S[on[:, j], j])) if on[:, j].any() else 0.0
        for j, lab in enumerate(labels)
    }


def _foot_load(task, sol, feet, settled, labels) -> dict[str, float]:
    """Per foot, mean vertical force over the stepped states where it touches the ground
    (t ≥ settle), divided by m·g."""
    dyn = task.dynamics
    weight = dyn.plant.CalcTotalMass(dyn.plant_context) * float(
        np.linalg.norm(dyn.plant.gravity_field().gravity_vector())
    )
    F = foot_vertical_forces(task, sol)
    if not len(F):
        return {}  # a run without controls
    on = (feet & settled[:, None])[: len(F)]
    return {
        lab: float(np.mean(F[on[:, j], j]) / weight) if on[:, j].any() and weight > 0 else 0.0
        for j, lab in enumerate(labels)
    }


def plot_cheetah(task, sol, out: Path) -> None:
    plt = pyplot()

    t = np.asarray(sol.t)
    vx, target = forward_velocity(task, sol)
    fig, ax = plt.subplots(figsize=(5.5, 3.2))
    ax.plot(t, vx, color="C0", label="actual")
    ax.plot(t, target, "--", color="C0", lw=1, label="desired")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("forward base velocity [m/s]")
    ax.set_title(f"{task.name}: forward base velocity")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    savefig(fig, Path(out) / "velocity.png")

    feet, _, body = contacts(task, sol)
    labels = [name.split("_")[0] for name in _params(task)["feet"]]
    dt = float(t[1] - t[0]) if len(t) > 1 else task.config.plant.time_step
    fig, ax = plt.subplots(figsize=(6.5, 2.4))
    colors = ("C0", "C1", "C1", "C0")  # diagonal pairs share a colour
    for j in range(4):
        ax.broken_barh(_runs(t, feet[:, j], dt), (3 - j - 0.35, 0.7), color=colors[j])
    if body.any():
        ax.broken_barh(_runs(t, body, dt), (-1.35, 0.7), color="C3")
        labels = labels + ["body"]
    ax.set_yticks([3 - j for j in range(len(labels))], labels)
    ax.set_ylim(-1.6 if body.any() else -0.6, 3.6)
    ax.set_xlim(t[0], t[-1])
    ax.set_xlabel("time [s]")
    ax.set_title(f"{task.name}: ground contact (diagonal pairs same colour)")
    ax.grid(True, axis="x", alpha=0.3)
    savefig(fig, Path(out) / "gait.png")


def _runs(t: np.ndarray, on: np.ndarray, dt: float) -> list[tuple[float, float]]:
    """(start, width) of every run of True in ``on``."""

    return [(float(t[a]), float(t[b] - t[a] + dt)) for a, b in runs(on)]


def _check_names(task, p: dict) -> None:
    names = {n for n, _ in task.dynamics.geometry_names().values()}
    for n in p["feet"] + [p["body_collision"], *p["ground"]]:
        if n not in names:
            raise ConfigError(f"metric_params: no collision geometry named {n!r}")


def validate(task) -> None:
    """The cheetah's ``metric_params`` name a floating body and existing collision geometries,
    and its times are numbers."""
    try:
        p = _params(task)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"metric_params (cheetah): {e}") from None
    _blocks(task, p["body"])
    _check_names(task, p)


def _overlaps(m: dict) -> list[str]:
    diag, lat = m.get("diagonal_pair_overlap"), m.get("lateral_pair_overlap")
    if isinstance(diag, (int, float)) and isinstance(lat, (int, float)):
        return [f"diag/lat overlap {diag:.3f}/{lat:.3f}"]
    return []


register(
    Metric(
        "cheetah",
        compute=cheetah_metrics,
        plot=plot_cheetah,
        files=("velocity.png", "gait.png"),
        validate=validate,
        headline=(
            ("v m/s", "mean_forward_velocity_mps", ".2f", 1.0),
            ("body contact steps", "body_ground_contact_steps", "d", 1.0),
        ),
        headline_more=_overlaps,
    )
)
