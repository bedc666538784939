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
* ``stance_slip_mps``: per foot, the mean of that speed over the same states, and
  ``mean_stance_slip_mps`` its mean over the feet (the gait report's stance slip: a walkable
  gait keeps it to a few cm/s);
* ``stride_frequency_hz``: per foot, one over the mean time between its touchdowns (t ≥ 0.2 s;
  0 with fewer than two), and ``mean_stride_frequency_hz``;
* ``pair_phase``: for the diagonal and lateral pairs, the phase of the second foot's
  touchdowns after the first's, as a fraction of the first foot's stride (0 = together,
  0.5 = alternating), folded to [0, 0.5] and averaged over the pairs of a kind (a trot:
  diagonal near 0, lateral near 0.5); None where a foot has fewer than two touchdowns;
* ``cost_of_transport``: the actuators' absolute mechanical work Σ|u·v| dt over t ≥ 0.2 s
  (u the commanded efforts, v the actuated joints' velocities), divided by m·g times the base's
  forward distance over that time (None without forward progress);
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
from hydroilqr.metrics.common import contact_pairs, floating_block, floating_name
from hydroilqr.metrics.contacts import state_step
from hydroilqr.metrics.registry import Metric, Report, register
from hydroilqr.model.contacts import runs
from hydroilqr.problem.errors import ConfigError

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
    pos = floating_block(task, body, "body")
    return pos, layout.primitives[f"{floating_name(pos)}.velocity"]


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
        **_slip(task, sol, feet, settled, labels),
        **_strides(t, f, t[settled], labels),
        "cost_of_transport": cost_of_transport(task, sol, settled),
        "foot_load": _foot_load(task, sol, feet, settled, labels),
        "max_foot_faces": int(np.max(faces)) if faces.size else 0,
        "mean_foot_faces": float(np.mean(in_contact)) if in_contact.size else 0.0,
    }
    resolves = (getattr(sol, "extra", None) or {}).get("resolves") or []
    if resolves:
        out["iterations_per_resolve"] = float(np.mean([r["iterations"] for r in resolves]))
        out["resolve_seconds"] = float(np.mean([r["seconds"] for r in resolves]))
    return out


def _slip(task, sol, feet, settled, labels) -> dict:
    """Per foot, the median (``foot_slip_mps``) and the mean (``stance_slip_mps``) slip speed
    (``foot_slip_speeds``) over states where it touches the ground (t ≥ settle), and the mean
    over the feet. The median shows a planted foot (a foot lands still moving and sticks
    within a few steps); the mean counts the sliding at touchdowns and grazes too."""
    S = foot_slip_speeds(task, sol)
    on = feet & settled[:, None]

    def per_foot(stat) -> dict[str, float]:
        return {
            lab: float(stat(S[on[:, j], j])) if on[:, j].any() else 0.0
            for j, lab in enumerate(labels)
        }

    mean = per_foot(np.mean)
    return {
        "foot_slip_mps": per_foot(np.median),
        "stance_slip_mps": mean,
        "mean_stance_slip_mps": float(np.mean(list(mean.values()))),
    }


def _touchdown_times(t: np.ndarray, on: np.ndarray) -> np.ndarray:
    """Times of the states at which ``on`` goes from False to True."""
    return t[1:][on[1:] & ~on[:-1]] if len(on) > 1 else t[:0]


def _strides(t: np.ndarray, f: np.ndarray, t_settled: np.ndarray, labels) -> dict:
    """Stride frequency per foot and the phase relation of the diagonal and lateral pairs,
    from the touchdowns in ``f``: [T, 4] (the settled states, at times ``t_settled``)."""
    down = [_touchdown_times(t_settled, f[:, j]) for j in range(4)]
    freq = {lab: _frequency(down[j]) for j, lab in enumerate(labels)}
    phase = {}
    for kind in ("diagonal", "lateral"):
        values = [_phase(down[a], down[b]) for a, b in PAIRS[kind]]
        values = [v for v in values if v is not None]
        phase[kind] = float(np.mean(values)) if values else None
    return {
        "stride_frequency_hz": freq,
        "mean_stride_frequency_hz": float(np.mean(list(freq.values()))),
        "pair_phase": phase,
    }


def _frequency(touchdowns: np.ndarray) -> float:
    """Strides per second: one over the mean time between successive touchdowns (0 with
    fewer than two)."""
    if len(touchdowns) < 2:
        return 0.0
    return float((len(touchdowns) - 1) / (touchdowns[-1] - touchdowns[0]))


def _phase(ta: np.ndarray, tb: np.ndarray) -> float | None:
    """The phase of foot b's touchdowns after foot a's, as a fraction of a's stride, folded
    to [0, 0.5] (0: together, 0.5: alternating); the circular mean over a's strides that
    contain a touchdown of b. None with fewer than two touchdowns of a or none of b."""
    if len(ta) < 2 or len(tb) == 0:
        return None
    angles = []
    for t0, t1 in zip(ta[:-1], ta[1:]):
        inside = tb[(tb >= t0) & (tb < t1)]
        if len(inside):
            angles.append(2 * np.pi * (inside[0] - t0) / (t1 - t0))
    if not angles:
        return None
    mean = np.angle(np.mean(np.exp(1j * np.array(angles)))) / (2 * np.pi) % 1.0
    return float(min(mean, 1.0 - mean))


def cost_of_transport(task, sol, settled: np.ndarray) -> float | None:
    """Σ|u_k · v_k| dt over the settled steps (absolute mechanical power of the actuators:
    efforts u against the actuated joints' velocities, ``B^T v`` with Drake's actuation matrix
    B), divided by m·g times the base's forward travel over them; None for a run without
    controls or without forward progress."""
    dyn = task.dynamics
    U = getattr(sol, "U", None)
    X = np.asarray(sol.X)
    if U is None or len(U) == 0 or len(U) >= len(X):
        return None
    U = np.asarray(U)
    B = dyn.plant.MakeActuationMatrix()  # [nv, nu]
    V = X[: len(U), dyn.nq :]
    power = np.abs(np.einsum("ki,ki->k", U, V @ B))
    steps = settled[: len(U)]
    work = float(np.sum(power[steps]) * dyn.dt)
    pos, _ = _blocks(task, _params(task)["body"])
    idx = np.flatnonzero(steps)
    if not len(idx):
        return None
    x = X[:, pos.coords[0]]
    distance = float(x[idx[-1] + 1] - x[idx[0]])
    weight = dyn.plant.CalcTotalMass(dyn.plant_context) * float(
        np.linalg.norm(dyn.plant.gravity_field().gravity_vector())
    )
    if distance <= 1e-6 or weight <= 0:
        return None
    return work / (weight * distance)


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
    dt = state_step(task, sol)
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
            raise ConfigError(
                f"metric_params: no collision geometry named {n!r} "
                f"(known: {', '.join(sorted(names))})"
            )


def validate(task) -> None:
    """The cheetah's ``metric_params`` name a floating body and existing collision geometries,
    and its times are numbers."""
    try:
        p = _params(task)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"metric_params (cheetah): {e}") from None
    _blocks(task, p["body"])
    _check_names(task, p)


def _num(v, fmt: str) -> str:
    return format(v, fmt) if isinstance(v, (int, float)) and not isinstance(v, bool) else "-"


def _per_foot(m: dict, key: str, fmt: str) -> str:
    d = m.get(key) or {}
    return "/".join(_num(d.get(f), fmt) for f in ("FL", "FR", "HL", "HR")) if d else "-"


GAIT_REPORT = Report(
    title="Gaits",
    intro=(
        "The cheetah tasks' gaits, from the solved plan (t ≥ 0.2 s). `duty` is the fraction "
        "of time each foot (FL/FR/HL/HR) is down; `stance slip` the mean horizontal speed of "
        "the feet's contact points while down; `overlap` the fraction of time both feet of "
        "the diagonal / lateral pairs are down together; `phase` the lag of a pair's second "
        "touchdown after its first as a fraction of the stride (0 together, 0.5 alternating: "
        "a trot has diagonal near 0 and lateral near 0.5); `CoT` the cost of transport "
        "(absolute actuator work over m·g·distance)."
    ),
    columns=(
        ("v m/s", lambda m: _num(m.get("mean_forward_velocity_mps"), ".2f")),
        ("duty FL/FR/HL/HR", lambda m: _per_foot(m, "duty_factor", ".2f")),
        ("stance slip m/s", lambda m: _num(m.get("mean_stance_slip_mps"), ".3f")),
        (
            "overlap diag/lat",
            lambda m: (
                f"{_num(m.get('diagonal_pair_overlap'), '.2f')}/"
                f"{_num(m.get('lateral_pair_overlap'), '.2f')}"
            ),
        ),
        (
            "phase diag/lat",
            lambda m: (
                f"{_num((m.get('pair_phase') or {}).get('diagonal'), '.2f')}/"
                f"{_num((m.get('pair_phase') or {}).get('lateral'), '.2f')}"
            ),
        ),
        ("stride Hz", lambda m: _num(m.get("mean_stride_frequency_hz"), ".2f")),
        ("CoT", lambda m: _num(m.get("cost_of_transport"), ".2f")),
        ("body contact steps", lambda m: _num(m.get("body_ground_contact_steps"), "d")),
    ),
    figures=("gait.png", "velocity.png"),
)


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
        report=GAIT_REPORT,
    )
)
