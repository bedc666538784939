"""Where the unactuated bodies go along a guess's rollout (``hydroilqr check``): each free or
planar base's (a floating body's, a planar joint's child's, a chain of unactuated sliders'
last body's) end, lowest point and top speed,
and warnings when one falls below every world-fixed contact geometry, leaves the scene, or
moves far faster than the task's scale allows.

The scene's extent is what is fixed to the world and collides (a ground half space with its
normal up bounds it from below only), together with where every body starts."""

from __future__ import annotations

import math

import numpy as np
from pydrake.geometry import Box, Capsule, Cylinder, Ellipsoid, HalfSpace, Sphere
from pydrake.multibody.tree import BodyIndex

G = 9.81  # m/s², for the speed of a fall across the scene
BELOW_FLOOR_M = 0.1  # deeper than this below every contact geometry: fell through
SPEED_FACTOR = 5.0  # a speed this many times the task's scale is far beyond it
BASE_JOINTS = ("quaternion_floating", "rpy_floating", "planar")


def base_bodies(plant) -> list:
    """Bodies that move freely in translation: the child of a free or planar joint, or the
    last body of a chain of unactuated sliders (a hopper's base_x, base_z)."""
    actuated = {
        plant.get_joint_actuator(a).joint().index() for a in plant.GetJointActuatorIndices()
    }
    joints = [plant.get_joint(j) for j in plant.GetJointIndices()]
    free = [
        j
        for j in joints
        if j.type_name() in BASE_JOINTS
        or (j.type_name() == "prismatic" and j.index() not in actuated)
    ]
    parents = {j.parent_body().index() for j in free}
    return [j.child_body() for j in free if j.child_body().index() not in parents]


def _box(shape, X, inspector, gid) -> tuple[np.ndarray, np.ndarray] | None:
    """(lo, hi): a world box that holds the geometry at pose X (None: unknown shape)."""
    p = X.translation()
    if isinstance(shape, Box):
        half = 0.5 * np.array([shape.width(), shape.depth(), shape.height()])
        reach = np.abs(X.rotation().matrix()) @ half  # (the corners' extent, exactly)
        return p - reach, p + reach
    r = _radius(shape, inspector, gid)
    return None if r is None else (p - r, p + r)


def extent_below(shape, inspector, gid) -> float | None:
    """How far the geometry reaches below its own origin along its -z axis (m; None:
    unknown)."""
    if isinstance(shape, Sphere):
        return shape.radius()
    if isinstance(shape, Box):
        return 0.5 * shape.height()
    if isinstance(shape, Cylinder):
        return 0.5 * shape.length()
    if isinstance(shape, Capsule):
        return shape.radius() + 0.5 * shape.length()
    if isinstance(shape, Ellipsoid):
        return shape.c()
    try:  # meshes and convex hulls: their bounding box's lowest corner
        obb = inspector.GetObbInGeometryFrame(gid)
    except Exception:  # noqa: BLE001 - a shape without one
        return None
    if obb is None:
        return None
    reach = np.abs(obb.pose().rotation().matrix()) @ obb.half_width()
    return float(reach[2] - obb.pose().translation()[2])


def _radius(shape, inspector, gid) -> float | None:
    """Radius of a sphere around the geometry's origin that holds it (None: unknown)."""
    if isinstance(shape, Sphere):
        return shape.radius()
    if isinstance(shape, Cylinder):
        return math.hypot(shape.radius(), 0.5 * shape.length())
    if isinstance(shape, Capsule):
        return shape.radius() + 0.5 * shape.length()
    if isinstance(shape, Ellipsoid):
        return max(shape.a(), shape.b(), shape.c())
    try:  # meshes and convex hulls
        obb = inspector.GetObbInGeometryFrame(gid)
    except Exception:  # noqa: BLE001 - a shape without one
        return None
    if obb is None:
        return None
    return float(np.linalg.norm(obb.half_width())) + float(np.linalg.norm(obb.center()))


def scene_extent(dyn) -> dict:
    """{"lo", "hi": [3] box of the world-fixed collision geometry, "floor": the lowest
    surface of it (m), "ground": a half space with its normal up bounds it from below}."""
    inspector = dyn.scene_graph.model_inspector()
    world = dyn.plant.world_body().name()
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    floor, ground = math.inf, False
    for gid, (_name, body) in dyn.geometry_names().items():
        if body != world:
            continue
        shape = inspector.GetShape(gid)
        X = inspector.GetPoseInFrame(gid)  # (in the world's frame: it is fixed to it)
        p = X.translation()
        if isinstance(shape, HalfSpace):
            if X.rotation().matrix()[2, 2] > 0.99:  # normal up: a ground
                floor, ground = min(floor, float(p[2])), True
            continue
        box = _box(shape, X, inspector, gid)
        if box is None:
            continue
        lo, hi = np.minimum(lo, box[0]), np.maximum(hi, box[1])
        floor = min(floor, float(box[0][2]))
    return {"lo": lo, "hi": hi, "floor": floor, "ground": ground}


def _body_positions(dyn, X: np.ndarray, bodies: list) -> np.ndarray:
    """[len(X), len(bodies), 3] world positions of the bodies' origins along X."""
    plant, ctx = dyn.plant, dyn.plant_context
    P = np.empty((len(X), len(bodies), 3))
    for k, x in enumerate(X):
        plant.SetPositionsAndVelocities(ctx, x)
        for i, b in enumerate(bodies):
            P[k, i] = plant.EvalBodyPoseInWorld(ctx, b).translation()
    return P


def base_report(task, X: np.ndarray) -> dict:
    """{"bodies": [{name, start, end, lowest_z, top_speed}], "scale_m", "speed_scale",
    "floor", "warnings": [...]} for the rollout X: [K+1, nx] of the initial guess."""
    dyn = task.dynamics
    bodies = base_bodies(dyn.plant)
    if not bodies or len(X) < 2:
        return {"bodies": [], "warnings": []}
    P = _body_positions(dyn, X, bodies)
    ext = scene_extent(dyn)
    starts = _starts(dyn, X[0])
    lo = np.minimum(ext["lo"], starts.min(axis=0))
    hi = np.maximum(ext["hi"], starts.max(axis=0))
    scale = max(0.1, float(np.linalg.norm(hi - lo)))
    horizon = (len(X) - 1) * dyn.dt
    speed_scale = max(scale / horizon, math.sqrt(2 * G * scale))
    V = np.linalg.norm(np.diff(P, axis=0), axis=2) / dyn.dt  # [K, bodies] m/s
    rows, warnings = [], []
    for i, b in enumerate(bodies):
        row = {
            "name": b.name(),
            "start": P[0, i].tolist(),
            "end": P[-1, i].tolist(),
            "lowest_z": float(P[:, i, 2].min()),
            "top_speed": float(V[:, i].max()),
        }
        rows.append(row)
        warnings += _warnings(row, P[:, i], ext, lo, hi, scale, speed_scale)
    return {
        "bodies": rows,
        "scale_m": scale,
        "speed_scale": speed_scale,
        "floor": ext["floor"] if math.isfinite(ext["floor"]) else None,
        "steps": len(X) - 1,
        "warnings": warnings,
    }


def _starts(dyn, x0: np.ndarray) -> np.ndarray:
    """[bodies, 3] where every body (besides the world) starts."""
    plant, ctx = dyn.plant, dyn.plant_context
    plant.SetPositionsAndVelocities(ctx, x0)
    pts = [
        plant.EvalBodyPoseInWorld(ctx, plant.get_body(BodyIndex(b))).translation()
        for b in range(1, plant.num_bodies())
    ]
    return np.array(pts) if pts else np.zeros((1, 3))


def _warnings(row, P, ext, lo, hi, scale, speed_scale) -> list[str]:
    name, out = row["name"], []
    if math.isfinite(ext["floor"]) and row["lowest_z"] < ext["floor"] - BELOW_FLOOR_M:
        k = int(np.argmin(P[:, 2]))
        out.append(
            f"{name} falls below every contact geometry along the guess: {row['lowest_z']:.2f} m "
            f"at step {k}, the lowest surface is at {ext['floor']:.2f} m (through the ground? "
            "a guess that holds it, a weld, or a thicker ground)"
        )
    margin = max(1.0, scale)
    axes = [0, 1] if ext["ground"] else [0, 1, 2]
    outside = [
        k
        for k in range(len(P))
        if any(not lo[a] - margin <= P[k, a] <= hi[a] + margin for a in axes)
    ]
    if outside:
        out.append(
            f"{name} leaves the scene along the guess (at step {outside[0]}; it ends at "
            f"{_xyz(row['end'])} m, the scene spans {_xyz(lo)} to {_xyz(hi)} m)"
        )
    if row["top_speed"] > SPEED_FACTOR * speed_scale:
        out.append(
            f"{name} reaches {row['top_speed']:.3g} m/s along the guess, far beyond the task's "
            f"scale ({speed_scale:.2g} m/s: a fall across the scene or its size over the horizon)"
        )
    return out


def _xyz(p) -> str:
    return "(" + ", ".join(f"{v:.2f}" for v in p) + ")"
