"""Metrics and helpers for every task: geometry ids, signed distances, touching pairs, and the
``default`` metric (final cost terms, final errors, contact polygons, commands beyond limits,
the contact timeline)."""

from __future__ import annotations

import numpy as np
from pydrake.multibody.tree import JointIndex

from hydroilqr.metrics.contacts import contact_metrics, plot_contacts
from hydroilqr.metrics.registry import Metric, register
from hydroilqr.model.names import body_labels
from hydroilqr.model.plant import named_geometries
from hydroilqr.problem.errors import ConfigError

# ------------------------------------------------------------------------------------------
# Helpers over a trajectory
# ------------------------------------------------------------------------------------------


def geometry_ids(dyn, name: str, param: str = "") -> list:
    """Collision geometry ids a name gives: a collision name or a body (labelled, MODEL::NAME
    or bare, as ``geometry:`` keys), or ``BODY/GEOMETRY``."""
    where = f"metric_params.{param}" if param else "metric_params"
    return named_geometries(name, dyn.geometry_names(), where)


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


def floating_block(task, name: str, param: str):
    """The position block of floating body ``name`` (its label, ``MODEL::NAME`` or its bare
    name; ConfigError naming ``param`` and the floating bodies if none)."""
    layout = task.dynamics.layout
    key = f"{name}.position" if isinstance(name, str) else None
    key = layout.aliases.get(key, key)
    if key not in layout.primitives:
        known = [n[: -len(".position")] for n in layout.primitives if n.endswith(".position")]
        raise ConfigError(
            f"metric_params.{param}: no floating body named {name!r} "
            f"(floating bodies: {', '.join(known) or 'none'})"
        )
    return layout.primitives[key]


def floating_name(block) -> str:
    """The floating body's label of its position block (``floating_block``)."""
    return block.name[: -len(".position")]


#: Units of a joint's (position, velocity) coordinates by Drake joint type, one entry per
#: coordinate where they differ (a floating body: quaternion, then position).
_JOINT_UNITS = {
    "revolute": (["rad"], ["rad/s"]),
    "prismatic": (["m"], ["m/s"]),
    "quaternion_floating": (["", "", "", "", "m", "m", "m"], ["rad/s"] * 3 + ["m/s"] * 3),
    "planar": (["m", "m", "rad"], ["m/s", "m/s", "rad/s"]),
}


def coordinate_units(dyn) -> list[str]:
    """The unit of each coordinate of x: [nx] ('' where it has none: a quaternion, a joint
    type without a table entry)."""
    units = [""] * dyn.nx
    plant = dyn.plant
    for i in range(plant.num_joints()):
        j = plant.get_joint(JointIndex(i))
        q_units, v_units = _JOINT_UNITS.get(j.type_name(), ([], []))
        for k, u in enumerate(q_units[: j.num_positions()]):
            units[j.position_start() + k] = u
        for k, u in enumerate(v_units[: j.num_velocities()]):
            units[dyn.nq + j.velocity_start() + k] = u
    return units


def block_unit(dyn, name: str) -> str:
    """The unit of a state block's coordinates: ' m', ' rad/s', ... (with its space), ''
    for a quaternion's error (2 sin(θ/2), no unit) and ' (mixed units)' for a group that
    mixes them."""
    block = dyn.layout.block(name)
    if block.kind == "quaternion":
        return " (2 sin(θ/2))"
    units = {coordinate_units(dyn)[i] for i in block.coords}
    if len(units) == 1:
        u = units.pop()
        return f" {u}" if u else ""
    return " (mixed units)"


def coordinate_name(layout, i: int) -> str:
    """The name of coordinate i of x: a one-coordinate block or component, else the block
    that holds it with its index."""
    for b in list(layout.primitives.values()) + list(layout.components.values()):
        if b.coords == (i,):
            return b.name
    for b in layout.primitives.values():
        if i in b.coords:
            return f"{b.name}[{b.coords.index(i)}]"
    return f"x[{i}]"


def body_order(task) -> list[str]:
    """The plant's body names in index order."""

    labels = body_labels(task.dynamics.plant)
    return [labels[i] for i in range(task.dynamics.plant.num_bodies())]


# ------------------------------------------------------------------------------------------
# The default metric
# ------------------------------------------------------------------------------------------


def default_metrics(task, sol) -> dict:
    """Final cost terms, the final tangent error of every Qf block and its RMS over the
    trajectory (``tracking_error_rms``), and contact polygons."""
    cost = task.cost
    N = sol.U.shape[0]
    t0 = float(sol.t[0])
    terms = cost.breakdown(sol.X, sol.U, t0)
    xn = cost.nominal(np.array([sol.t[-1]]))[0]
    err = cost.layout.diff(sol.X[-1], xn)
    final_err, tracking = {}, {}
    # every state against the nominal at its own time (a closed loop's too, on its own grid)
    E = cost.layout.diff(sol.X, cost.nominal(np.asarray(sol.t, float)))
    for name in task.config.cost.Qf:
        b = cost.layout.block(name)
        final_err[name] = float(np.linalg.norm(err[list(b.tangent)]))
        tracking[name] = float(np.sqrt(np.mean(np.sum(E[:, list(b.tangent)] ** 2, axis=1))))
    return {
        "cost_terms": terms,
        "final_error": final_err,
        "tracking_error_rms": tracking,
        "steps": int(N),
        "max_contact_faces": max_contact_faces(task, sol),
        **beyond_limits(task.dynamics, sol.U),
    }


#: The fraction of clipped commands (``saturated_fraction`` of playback and MPC) that earns a
#: warning.
SATURATION_WARNING = 0.2


def beyond_limits(dyn, U: np.ndarray) -> dict:
    """Commands beyond the actuators' effort limits in U: [N, nu]. Drake's plant applies the
    limit instead (the trajectory is the same as with the clipped command), so a plan may
    list larger commands than act; the cost prices the commands. Returns
    ``commands_beyond_limits`` (entries of U) and, if any, ``max_command_to_limit_ratio``
    (max |u| / limit: 1.5 is a command half again as large as its limit) with its actuator,
    ``max_command_to_limit_actuator``. (Before 2026-11-26: ``max_command_over_limit`` and
    ``max_command_over_limit_actuator``; ``command_limit_ratio`` reads either.)"""
    lim = np.asarray(getattr(dyn, "effort_limits", np.full(U.shape[1], np.inf)), float)
    ratio = np.abs(U) / lim  # 0 where there is no limit (inf)
    n = int(np.sum(ratio > 1.0))
    out: dict = {"commands_beyond_limits": n}
    if n:
        k, j = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
        out["max_command_to_limit_ratio"] = float(ratio[k, j])
        out["max_command_to_limit_actuator"] = dyn.plant.get_joint_actuator(
            dyn.plant.GetJointActuatorIndices()[j]
        ).name()
    return out


def command_limit_ratio(m: dict) -> tuple[float, str] | None:
    """(max |u| / limit, its actuator) from a metrics dict, also one written under the
    earlier names (``max_command_over_limit``); None without commands beyond limits."""
    for key, actuator in (
        ("max_command_to_limit_ratio", "max_command_to_limit_actuator"),
        ("max_command_over_limit", "max_command_over_limit_actuator"),
    ):
        if key in m:
            return float(m[key]), str(m.get(actuator, "?"))
    return None


def _default(task, sol) -> dict:
    return {**default_metrics(task, sol), **contact_metrics(task, sol)}


def validate_camera(task) -> None:
    """``metric_params.camera`` (the replays' viewpoint, whatever the metrics) is
    {position: [x, y, z], target: [x, y, z]}."""
    cam = task.config.metric_params.get("camera")
    if cam is None:
        return
    ok = isinstance(cam, dict) and all(
        np.shape(np.asarray(cam.get(k), dtype=object)) == (3,) for k in ("position", "target")
    )
    if ok:
        try:
            ok = all(np.all(np.isfinite(np.asarray(cam[k], float))) for k in ("position", "target"))
        except (TypeError, ValueError):
            ok = False
    if not ok:
        raise ConfigError(
            "metric_params.camera: expected {position: [x, y, z], target: [x, y, z]} (numbers)"
        )


register(
    Metric(
        "default",
        compute=_default,
        plot=plot_contacts,
        files=("contacts.png",),
    )
)
