"""What contact costs along a guess (``hydroilqr check``): the contact-surface faces of each
pair at every step of the guess's rollout, the time of each step with and without contact,
the geometry whose mesh decides the count (the finest ``resolution_hint`` of the busiest
pair), and the same rollout measured again with that hint doubled, side by side.

Each step's time is measured on this machine as it runs (contended if others run beside it);
the two rollouts compared run step by step in turn, so load from elsewhere falls on both alike
and their ratio is the comparison."""

from __future__ import annotations

import time

import numpy as np

from hydroilqr.model.plant import SimulationError
from hydroilqr.problem.errors import ConfigError

MIN_FACES = 50  # fewer faces at the busiest step: contact is cheap, no comparison is made


def _faces(dyn, x: np.ndarray, names: dict) -> dict[tuple[str, str], int]:
    """Faces of each touching pair's contact surface at state x, by (geometry, geometry)."""
    surfaces, _ = dyn.contact_query(x)
    out: dict[tuple[str, str], int] = {}
    for s in surfaces:
        a, b = sorted((names[s.id_M()], names[s.id_N()]))
        out[(a, b)] = out.get((a, b), 0) + s.num_faces()
    return out


def _timed_rollouts(dyns: list, x0: np.ndarray, U: np.ndarray) -> list:
    """[(X [K+1, nx], seconds of each step [K])] of the controls U from x0 on each of
    ``dyns``, their steps interleaved (step k of each, then step k + 1 of each), so that
    load from elsewhere falls on all of them alike."""
    X = [np.empty((len(U) + 1, len(x0))) for _ in dyns]
    seconds = [np.empty(len(U)) for _ in dyns]
    for Xi in X:
        Xi[0] = x0
    for k, u in enumerate(U):
        for dyn, Xi, si in zip(dyns, X, seconds, strict=True):
            tic = time.perf_counter()
            Xi[k + 1] = dyn.step(Xi[k], u)
            si[k] = time.perf_counter() - tic
    return list(zip(X, seconds, strict=True))


def _measure(dyn, X: np.ndarray, seconds: np.ndarray) -> dict:
    """Faces per pair at every step of the rollout X and each step's time."""
    names = {gid: f"{n} ({b})" for gid, (n, b) in dyn.geometry_names().items()}
    per_step = [_faces(dyn, x, names) for x in X[:-1]]
    total = np.array([sum(f.values()) for f in per_step])
    pairs: dict[tuple[str, str], list[int]] = {}
    for k, f in enumerate(per_step):
        for p, n in f.items():
            pairs.setdefault(p, [0] * len(per_step))[k] = n
    touching = total > 0
    return {
        "pairs": [
            {
                "pair": list(p),
                "max_faces": int(max(n)),
                "mean_faces": float(np.mean([v for v in n if v])),
                "steps": int(sum(v > 0 for v in n)),
            }
            for p, n in sorted(pairs.items(), key=lambda kv: -max(kv[1]))
        ],
        "max_faces": int(total.max()) if len(total) else 0,
        "ms_per_step": 1e3 * float(seconds.mean()) if len(seconds) else 0.0,
        "ms_in_contact": 1e3 * float(seconds[touching].mean()) if touching.any() else None,
        "ms_without_contact": 1e3 * float(seconds[~touching].mean()) if (~touching).any() else None,
    }


def _finest(task, pair: list[str]) -> tuple[str, float] | None:
    """(geometry key BODY/NAME, its resolution_hint) of the pair's geometry with the finest
    hydroelastic mesh (None: neither has one)."""
    inspector = task.dynamics.scene_graph.model_inspector()
    best = None
    for gid, (name, body) in task.dynamics.geometry_names().items():
        if f"{name} ({body})" not in pair:
            continue
        props = inspector.GetProximityProperties(gid)
        if props is None or not props.HasProperty("hydroelastic", "resolution_hint"):
            continue
        h = float(props.GetProperty("hydroelastic", "resolution_hint"))
        if body == task.dynamics.plant.world_body().name():
            continue  # (a scene object's hint: set on the scene entry, not under geometry:)
        if best is None or h < best[1]:
            best = (f"{body}/{name}", h)
    return best


def step_cost_report(task, steps: int) -> dict:
    """The report described in the module docstring over the guess's first ``steps`` steps:
    {"now": _measure, "geometry", "resolution_hint", "coarser": _measure with the hint
    doubled, or None}."""
    dyn = task.dynamics
    U = task.initial_guess(task.steps)[:steps]
    try:
        now = _measure(dyn, *_timed_rollouts([dyn], task.x0, U)[0])
    except SimulationError:
        return {}
    out = {"now": now, "steps": len(U), "coarser": None}
    if not now["pairs"] or now["max_faces"] < MIN_FACES:
        return out
    finest = _finest(task, now["pairs"][0]["pair"])
    if finest is None:
        return out
    key, h = finest
    out["geometry"], out["resolution_hint"] = key, h
    try:  # both measured again, side by side
        coarse = task.with_overrides([f"geometry.{key}.resolution_hint={2 * h:g}"]).dynamics
        runs = _timed_rollouts([dyn, coarse], task.x0, U)
    except (ConfigError, SimulationError) as e:
        out["coarser_error"] = str(e)
        return out
    out["now"] = _measure(dyn, *runs[0])
    out["coarser"] = _measure(coarse, *runs[1])
    return out
