"""The cart-pole against a wall (paper Fig. 7): metric ``cartpole_wall``.

Values: ``final_angle_error_rad`` (|final pole angle − its nominal|), ``max_overlap_m`` (tip vs
wall), ``min_signed_distance_m``, ``wall_contact_steps``, ``tunnelled`` (the tip's centre ended
up beyond the wall's far face at some step).

``metric_params`` (optional): ``angle_block`` (state block of the pole angle, default
``pole_angle``), ``contact_pair`` ([tip, wall] collision or body names, default
``[tip, wall]``).

Sweeps: the columns ``max_overlap_m`` and ``tunnelled`` (always), the other values where
points have them, and per point the tip/pin/cart paths and the pair's signed distance
(``snapshots.png``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.patches import Circle, Rectangle

from hydroilqr.io.figures import pyplot, savefig
from hydroilqr.metrics.common import contact_pairs, geometry_ids, involves, signed_distance
from hydroilqr.metrics.registry import Metric, register
from hydroilqr.problem.errors import ConfigError

plt = pyplot()


def _pair(task) -> tuple[str, str]:
    pair = task.config.metric_params.get("contact_pair", ["tip", "wall"])
    if (
        not isinstance(pair, (list, tuple))
        or len(pair) != 2
        or not all(isinstance(n, str) for n in pair)
    ):
        raise ConfigError(
            f"metric_params.contact_pair: expected two collision or body names, got {pair!r}"
        )
    return pair[0], pair[1]


def validate(task) -> None:
    dyn = task.dynamics
    name = task.config.metric_params.get("angle_block", "pole_angle")
    if not isinstance(name, str):
        raise ConfigError(f"metric_params.angle_block: expected a state block name, got {name!r}")
    dyn.layout.block(name, "metric_params.angle_block")
    for n in _pair(task):
        geometry_ids(dyn, n, "contact_pair")


def cartpole_wall(task, sol) -> dict:
    """final_angle_error_rad, max_overlap_m (tip vs wall), wall_contact_steps, tunnelled."""
    p = task.config.metric_params
    dyn = task.dynamics
    angle = dyn.layout.block(p.get("angle_block", "pole_angle"))
    a_name, b_name = _pair(task)
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


def cartpole_geometry(task, X: np.ndarray) -> dict[str, np.ndarray]:
    """Per-step world positions of the tip, its pin and the cart, the tip radius, and the
    per-step signed distance of the contact pair (what the sweep's plot_snapshots draws)."""
    dyn = task.dynamics
    plant = dyn.plant
    a_name, b_name = _pair(task)
    gid = geometry_ids(dyn, a_name)[0]
    body = plant.GetBodyByName(dyn.geometry_names()[gid][1])
    joint = next(
        (
            plant.get_joint(j)
            for j in plant.GetJointIndices()
            if plant.get_joint(j).child_body().index() == body.index()
        ),
        None,
    )
    inspector = dyn.plant.get_geometry_query_input_port().Eval(dyn.plant_context).inspector()
    shape = inspector.GetShape(gid)
    radius = float(shape.radius()) if hasattr(shape, "radius") else 0.05
    tip, pin, cart = [], [], []
    return_pin = joint is not None
    for x in X:
        plant.SetPositionsAndVelocities(dyn.plant_context, x)
        tip.append(body.EvalPoseInWorld(dyn.plant_context).translation())
        if return_pin:
            pin.append(joint.frame_on_child().CalcPoseInWorld(dyn.plant_context).translation())
            cart.append(joint.parent_body().EvalPoseInWorld(dyn.plant_context).translation())
    out = {"tip_xyz": np.array(tip), "tip_radius": np.array(radius)}
    if return_pin:
        out["pin_xyz"] = np.array(pin)
        out["cart_xyz"] = np.array(cart)
    ia, ib = geometry_ids(dyn, a_name), geometry_ids(dyn, b_name)
    out["signed_distance"] = np.array([signed_distance(dyn, x, ia, ib) for x in X])
    return out


def _representative(rows: list[dict], key: str, n: int = 4) -> list[dict]:
    ok = sorted((r for r in rows if r.get("status") == "ok"), key=lambda r: r[f"param:{key}"])
    if len(ok) <= n:
        return ok
    idx = sorted({int(round(i)) for i in np.linspace(0, len(ok) - 1, n)})
    return [ok[i] for i in idx]


def plot_snapshots(
    path: Path, points_dir: Path, task_cfg, param_keys: list[str], rows: list[dict]
) -> bool:
    """Pole + wall in the x-z plane at the step of maximum overlap, a few points side by side."""

    key = param_keys[0]
    chosen = []
    for r in _representative(rows, key):
        try:
            with np.load(points_dir / f"{r['id']}.npz") as d:
                if "tip_xyz" not in d or "pin_xyz" not in d:
                    continue
                chosen.append((r, {k: d[k] for k in d.files}))
        except (OSError, ValueError):
            continue
    if not chosen:
        return False
    walls = [o for o in task_cfg.scene if o.shape == "box"]
    # Common limits: every tip path and cart, plus a margin.
    xs = np.concatenate([np.r_[d["tip_xyz"][:, 0], d["cart_xyz"][:, 0]] for _, d in chosen])
    zs = np.concatenate([np.r_[d["tip_xyz"][:, 2], d["cart_xyz"][:, 2]] for _, d in chosen])
    xlim = (float(xs.min()) - 0.2, float(xs.max()) + 0.2)
    ylim = (float(zs.min()) - 0.15, float(zs.max()) + 0.15)
    # equal-aspect panels ~2.6 in wide; the height follows (plus titles), no empty band
    aspect = (ylim[1] - ylim[0]) / (xlim[1] - xlim[0])
    fig, axes = plt.subplots(
        1, len(chosen), figsize=(3.1 * len(chosen), 2.6 * aspect + 1.4), squeeze=False
    )
    unit = " Pa" if key.endswith("hydroelastic_modulus") else ""
    for ax, (r, d) in zip(axes[0], chosen):
        k = int(np.argmin(d["signed_distance"])) if "signed_distance" in d else 0
        tip, pin, cart = d["tip_xyz"], d["pin_xyz"], d["cart_xyz"]
        rad = float(d["tip_radius"])
        for o in walls:
            color = o.color[:3] if len(o.color) >= 3 else (0.5, 0.5, 0.5)
            ax.add_patch(
                Rectangle(
                    (o.xyz[0] - o.size[0] / 2, o.xyz[2] - o.size[2] / 2),
                    o.size[0],
                    o.size[2],
                    color=color,
                    alpha=0.7,
                    lw=0,
                )
            )
        ax.plot(tip[:, 0], tip[:, 2], "-", color="0.6", lw=0.8, label="tip path")
        ax.add_patch(
            Rectangle((cart[k, 0] - 0.12, cart[k, 2] - 0.06), 0.24, 0.12, color=(0.2, 0.3, 0.8))
        )
        ax.plot([pin[k, 0], tip[k, 0]], [pin[k, 2], tip[k, 2]], "-", color="0.3", lw=3)
        ax.add_patch(Circle((tip[k, 0], tip[k, 2]), rad, color=(0.9, 0.4, 0.1), alpha=0.9))
        ax.set_aspect("equal")
        ax.set_xlim(*xlim)
        ax.set_ylim(*ylim)
        ov = r.get("max_overlap_m") or 0.0
        tun = " TUNNELLED" if r.get("tunnelled") else ""
        ax.set_title(
            f"{key.split('.')[-1]} = {r[f'param:{key}']:.3g}{unit}\n"
            f"overlap {ov * 1000:.1f} mm at t = {d['t'][k]:.2f} s{tun}",
            fontsize=8,
        )
        ax.tick_params(labelsize=7)
        ax.set_xlabel("x [m]", fontsize=8)
    axes[0, 0].set_ylabel("z [m]", fontsize=8)
    axes[0, 0].legend(fontsize=7, loc="upper right")
    fig.suptitle(
        f"{task_cfg.name}: configuration of maximum overlap (grey: tip path over the horizon)",
        fontsize=9,
    )
    savefig(fig, path)
    return True


register(
    Metric(
        "cartpole_wall",
        compute=cartpole_wall,
        headline=(
            ("angle err rad", "final_angle_error_rad", ".3f", 1.0),
            ("wall steps", "wall_contact_steps", "d", 1.0),
        ),
        sweep_panels=(("max_overlap_m", "max overlap [m]"),),
        sweep_plot=plot_snapshots,
        sweep_plot_file="snapshots.png",
        sweep_columns=("max_overlap_m", "tunnelled"),
        sweep_extra_columns=(
            "final_angle_error_rad",
            "min_signed_distance_m",
            "wall_contact_steps",
        ),
        sweep_arrays=cartpole_geometry,
        validate=validate,
    )
)
