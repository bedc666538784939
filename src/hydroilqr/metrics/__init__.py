"""Task metrics, by name (``metrics: [default, cartpole_wall]`` in a task file).

Each metric function takes (task, solution) and returns a dict of JSON-able numbers. Contact
metrics query the geometry of every stored state (touching pairs and their contact polygons,
``Dynamics.contact_query``; signed distances): no contact solve, the states themselves.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from hydroilqr.problem.config import ConfigError

METRICS: dict[str, Callable] = {}


def metric(name: str):
    def deco(fn):
        METRICS[name] = fn
        return fn

    return deco


# Modules that register task-specific metrics and plots (``metrics_<name>.py``).
PLUGINS = ("metrics.kinova", "metrics.cheetah")


def load_plugins() -> None:
    import importlib

    for mod in PLUGINS:
        try:
            importlib.import_module(f"hydroilqr.{mod}")
        except ModuleNotFoundError as e:
            if e.name != f"hydroilqr.{mod}":
                raise


def compute(task, sol) -> dict:
    load_plugins()
    out: dict = {}
    for name in task.config.metrics:
        if name not in METRICS:
            raise ConfigError(f"metrics: unknown metric {name!r} (known: {', '.join(METRICS)})")
        out.update(METRICS[name](task, sol))
    return out


# ------------------------------------------------------------------------------------------
# Helpers over a trajectory
# ------------------------------------------------------------------------------------------


def geometry_ids(dyn, name: str) -> list:
    """Collision geometry ids whose collision name or body name is ``name``."""
    ids = [g for g, (n, b) in dyn.geometry_names().items() if name in (n, b)]
    if not ids:
        raise ConfigError(f"metric_params: no collision geometry or body named {name!r}")
    return ids


def signed_distance(dyn, x: np.ndarray, ids_a: list, ids_b: list) -> float:
    """Smallest signed distance between two sets of geometries at state x: [nx] (negative =
    overlap)."""
    dyn.plant.SetPositionsAndVelocities(dyn.plant_context, x)
    query = dyn.plant.get_geometry_query_input_port().Eval(dyn.plant_context)
    best = np.inf
    for a in ids_a:
        for b in ids_b:
            try:
                d = query.ComputeSignedDistancePairClosestPoints(a, b).distance
            except RuntimeError:
                continue
            best = min(best, d)
    return float(best)


def contact_pairs(dyn, x: np.ndarray) -> list[tuple[str, str, str, str, int]]:
    """Touching pairs at x: (geom A, body A, geom B, body B, polygons); see plant.Dynamics."""
    return dyn.contact_pairs(x)


def involves(pair, name: str) -> bool:
    return name in (pair[0], pair[1], pair[2], pair[3])


def max_contact_faces(task, sol) -> int:
    dyn = task.dynamics
    return int(max((sum(p[4] for p in contact_pairs(dyn, x)) for x in sol.X), default=0))


# ------------------------------------------------------------------------------------------
# Metrics
# ------------------------------------------------------------------------------------------


@metric("default")
def default_metrics(task, sol) -> dict:
    """Final cost terms, the final tangent error of every Qf block, and contact polygons."""
    cost = task.cost
    N = sol.U.shape[0]
    t0 = float(sol.t[0])
    terms = cost.breakdown(sol.X, sol.U, t0)
    xn = cost.nominal(np.array([sol.t[-1]]))[0]
    err = cost.layout.diff(sol.X[-1], xn)
    final_err = {}
    for name in task.config.cost.Qf:
        b = cost.layout.block(name)
        final_err[name] = float(np.linalg.norm(err[list(b.tangent)]))
    return {
        "cost_terms": terms,
        "final_error": final_err,
        "steps": int(N),
        "max_contact_faces": max_contact_faces(task, sol),
        **beyond_limits(task.dynamics, sol.U),
    }


def beyond_limits(dyn, U: np.ndarray) -> dict:
    """Commands beyond the actuators' effort limits in U: [N, nu]. Drake's plant applies the
    limit instead (the trajectory is the same as with the clipped command), so a plan may
    list larger commands than act; the cost prices the commands. Returns
    ``commands_beyond_limits`` (entries of U) and, if any, ``max_command_over_limit``
    (max |u| / limit) with its actuator."""
    lim = np.asarray(getattr(dyn, "effort_limits", np.full(U.shape[1], np.inf)), float)
    ratio = np.abs(U) / lim  # 0 where there is no limit (inf)
    n = int(np.sum(ratio > 1.0))
    out: dict = {"commands_beyond_limits": n}
    if n:
        k, j = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
        out["max_command_over_limit"] = float(ratio[k, j])
        out["max_command_over_limit_actuator"] = dyn.plant.get_joint_actuator(
            dyn.plant.GetJointActuatorIndices()[j]
        ).name()
    return out


@metric("cartpole_wall")
def cartpole_wall(task, sol) -> dict:
    """final_angle_error_rad, max_overlap_m (tip vs wall), wall_contact_steps, tunnelled."""
    p = task.config.metric_params
    dyn = task.dynamics
    angle = dyn.layout.block(p.get("angle_block", "pole_angle"))
    a_name, b_name = p.get("contact_pair", ["tip", "wall"])
    ids_a, ids_b = geometry_ids(dyn, a_name), geometry_ids(dyn, b_name)
    target = task.cost.nominal(np.array([sol.t[-1]]))[0][angle.coords[0]]
    dist = np.array([signed_distance(dyn, x, ids_a, ids_b) for x in sol.X])
    steps = sum(
        any(involves(pr, a_name) and involves(pr, b_name) for pr in contact_pairs(dyn, x))
        for x in sol.X[1:]
    )
    # Tunnelling: the tip's centre ended up beyond the wall's far face at some step. The far
    # face is the one away from the side of the wall the tip starts on (axis-aligned wall).
    tunnelled = False
    wall = next((o for o in task.config.scene if o.name == b_name and o.shape == "box"), None)
    if wall is not None:
        body = dyn.plant.GetBodyByName(dyn.geometry_names()[ids_a[0]][1])
        xs = []
        for x in sol.X:
            dyn.plant.SetPositionsAndVelocities(dyn.plant_context, x)
            xs.append(body.EvalPoseInWorld(dyn.plant_context).translation()[0])
        side = 1.0 if xs[0] >= wall.xyz[0] else -1.0
        far_face = wall.xyz[0] - side * 0.5 * wall.size[0]
        tunnelled = bool(np.min(side * (np.array(xs) - far_face)) < 0.0)
    return {
        "final_angle_error_rad": float(abs(sol.X[-1, angle.coords[0]] - target)),
        "max_overlap_m": float(max(0.0, -np.min(dist))),
        "min_signed_distance_m": float(np.min(dist)),
        "wall_contact_steps": int(steps),
        "tunnelled": tunnelled,
    }


def summary_lines(m: dict) -> list[str]:
    """Console lines for a metrics dict: its scalars, then the final error per Qf block."""
    fmt = lambda v: f"{v:.4g}" if isinstance(v, float) else str(v)  # noqa: E731
    shown = {k: v for k, v in m.items() if not isinstance(v, (dict, list))}
    lines = ["metrics: " + ", ".join(f"{k}={fmt(v)}" for k, v in shown.items())]
    if m.get("commands_beyond_limits"):
        lines.append(
            f"note: {m['commands_beyond_limits']} planned commands exceed their actuator's "
            f"effort limit (up to {m['max_command_over_limit']:.3g}x, "
            f"{m['max_command_over_limit_actuator']}); the plant applies the limit there, so "
            "the trajectory is what the clipped command gives (the cost prices the command)"
        )
    if m.get("final_error"):
        lines.append(
            "final error |x_N - x_nom| per Qf block: "
            + ", ".join(f"{k}={fmt(v)}" for k, v in m["final_error"].items())
        )
    return lines
