"""Metric ``object``: a pushed, lifted or carried body (e.g. the Kinova tasks' ball).

``metric_params``:

* ``object``: the floating body's name (required; a task file with only ``ball``, the older
  Kinova parameter, names it there);
* ``object_target`` (optional): a fixed target position [x, y, z] of the body's origin. Without
  it the target is the cost's nominal position of the body, and the target error counts only
  the axes the terminal cost weights (``Qf.<body>_position`` > 0; e.g. only z for lifting).

Values (``<b>`` is the body's name):

* ``<b>_start_m``, ``<b>_final_m``, ``<b>_target_m``: positions [x, y, z] at the start, at the
  end, and the final target;
* ``<b>_displacement_m``: final minus start position;
* ``target_error_m``: distance of the final position from the target over the counted axes;
  ``target_error_xyz_m``: the signed per-axis errors (final − target, 0 on uncounted axes);
* ``max_<b>_height_gain_m``: highest z over the trajectory minus the start height;
* ``contact_links``: bodies (other than the world/ground) that touched the body at any step,
  in the plant's order, from a geometry query of the touching pairs at every state after x0;
  ``contact_steps``: the number of such states per body; ``max_robot_<b>_faces``: most
  contact polygons between those bodies and the body at one state.

Plot: ``<b>.png`` (``<b>`` as ``metric_params`` names it): the body's x, y and z against time,
one panel each at its own scale, with the target dashed on the counted axes, and the distance
to the target (counted axes) in cm.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hydroilqr.io.figures import pyplot, savefig
from hydroilqr.io.files import file_name
from hydroilqr.metrics.common import body_order, contact_pairs, floating_block, floating_name
from hydroilqr.metrics.registry import Metric, register
from hydroilqr.problem.errors import ConfigError

_cache: dict = {}


def object_name(params) -> str:
    """The body the object metrics follow: ``object``, else ``ball`` (older Kinova task files),
    else ``ball``."""
    name = params.get("object", params.get("ball", "ball"))
    return name


def _target(params):
    tgt = params.get("object_target")
    if tgt is None:
        return None
    try:
        tgt = np.asarray(tgt, float)
    except (TypeError, ValueError):
        tgt = None
    if tgt is None or tgt.shape != (3,) or not np.all(np.isfinite(tgt)):
        raise ConfigError(
            "metric_params.object_target: expected a position [x, y, z] (numbers), got "
            f"{params.get('object_target')!r}"
        )
    return tgt


def validate(task) -> None:
    p = task.config.metric_params
    if "object" not in p and "ball" not in p:
        raise ConfigError("metric_params.object: name the pushed or carried floating body")
    floating_block(task, object_name(p), "object" if "object" in p else "ball")
    _target(p)


def validate_kinova(task) -> None:
    p = task.config.metric_params
    floating_block(task, object_name(p), "object" if "object" in p else "ball")
    _target(p)


def track(task, sol):
    """(body name, P: [T, 3] its position, targets: [T, 3], axis weights: [3] (>0: counted))."""
    p = task.config.metric_params
    block = floating_block(task, object_name(p), "object" if "object" in p else "ball")
    name = floating_name(block)
    idx = list(block.coords)
    P = np.asarray(sol.X)[:, idx]
    tgt = _target(p)
    if tgt is None:
        targets = task.cost.nominal(np.asarray(sol.t))[:, idx]
        w = task.cost.qf[list(block.tangent)]
    else:
        targets = np.tile(tgt, (len(P), 1))
        w = np.ones(3)
    return name, P, targets, w


def object_contacts(task, sol, body: str) -> tuple[dict[str, int], int]:
    """States (after x0) in contact per body touching ``body`` (world excluded), and the most
    contact polygons between them and ``body`` at one state."""
    dyn = task.dynamics
    steps: dict[str, int] = {}
    max_faces = 0
    for x in np.asarray(sol.X)[1:]:
        faces = 0
        touching = set()
        for _ga, ba, _gb, bb, n in contact_pairs(dyn, x):
            if body not in (ba, bb):
                continue
            other = bb if ba == body else ba
            if other == "world":
                continue
            touching.add(other)
            faces += n
        for b in touching:
            steps[b] = steps.get(b, 0) + 1
        max_faces = max(max_faces, faces)
    return steps, max_faces


def object_values(task, sol) -> tuple[str, dict, int]:
    """(body name, the metric's values, most polygons at a state); computed once per solution."""
    key = (task, sol.X)  # held, so neither id is reused while cached
    if _cache.get("key", (None, None))[0] is task and _cache["key"][1] is sol.X:
        return _cache["value"]
    name, P, targets, w = track(task, sol)
    err = np.where(w > 0, P[-1] - targets[-1], 0.0)
    steps, max_faces = object_contacts(task, sol, name)
    bodies = body_order(task)
    order = [b for b in bodies if b in steps] + sorted(b for b in steps if b not in bodies)
    values = {
        f"{name}_start_m": P[0],
        f"{name}_final_m": P[-1],
        f"{name}_target_m": targets[-1],
        f"{name}_displacement_m": P[-1] - P[0],
        "target_error_m": float(np.linalg.norm(err)),
        "target_error_xyz_m": err,
        f"max_{name}_height_gain_m": float(np.max(P[:, 2]) - P[0, 2]),
        "contact_links": order,
        "contact_steps": {b: steps[b] for b in order},
    }
    _cache["key"], _cache["value"] = key, (name, values, int(max_faces))
    return name, values, int(max_faces)


def object_metrics(task, sol) -> dict:
    name, values, faces = object_values(task, sol)
    return {**values, f"max_robot_{name}_faces": faces}


def _span(ax, values, least: float) -> None:
    """Y limits around ``values`` at least ``least`` wide, without an offset: millimetres of
    numerical drift do not fill a panel, and the ticks read as positions."""
    lo = min(float(np.min(v)) for v in values)
    hi = max(float(np.max(v)) for v in values)
    mid, half = (lo + hi) / 2, max(hi - lo, least) / 2 * 1.1
    ax.set_ylim(mid - half, mid + half)
    ax.ticklabel_format(axis="y", useOffset=False)


def plot_object(task, sol, out: Path) -> None:
    """One panel per axis (each at its own scale: a 0.2 m push shows beside a body 3 m below
    the origin), the target dashed on the axes counted, and the distance to the target."""
    plt = pyplot()
    name, P, targets, w = track(task, sol)
    t = np.asarray(sol.t)
    fig, axes = plt.subplots(4, 1, figsize=(6.2, 6.4), sharex=True)
    for i, (axis, ax) in enumerate(zip("xyz", axes)):
        ax.plot(t, P[:, i], color=f"C{i}", label=axis)
        if w[i] > 0:
            ax.plot(t, targets[:, i], "--", color="k", lw=1, label="target")
        ax.set_ylabel(f"{axis} [m]")
        _span(ax, [P[:, i], targets[:, i] if w[i] > 0 else P[:1, i]], 0.01)
        ax.legend(fontsize=7, loc="best")
    err = np.linalg.norm(np.where(w > 0, P - targets, 0.0), axis=1)
    axes[3].plot(t, err * 100.0, color="C3")
    axes[3].set_ylabel("to target [cm]")
    _span(axes[3], [err * 100.0, [0.0]], 1.0)
    axes[3].set_xlabel("time [s]")
    for ax in axes:
        ax.grid(True, alpha=0.3)
    axes[0].set_title(f"{task.name}: {name} position (origin of the body)")
    savefig(fig, Path(out) / plot_files(task.config.metric_params)[0])


def plot_files(params: dict) -> tuple[str, ...]:
    return (file_name(object_name(params)),)


#: The object's numbers on the results page (the Kinova ball: target error, lift).
HEADLINE = (
    ("ball err cm", "target_error_m", ".1f", 100.0),
    ("lift cm", "max_ball_height_gain_m", ".1f", 100.0),
)

register(
    Metric(
        "object",
        compute=object_metrics,
        plot=plot_object,
        files=plot_files,
        validate=validate,
        headline=HEADLINE,
        moves_object=True,
    )
)
