"""Metrics and plot of the Kinova Gen3 whole-arm manipulation tasks (paper §IV-B).

``metrics: [default, kinova]`` in a task file adds:

* ``ball_displacement_m``: [dx, dy, dz] of the ball centre, end minus start;
* ``target_error_m``: distance of the final ball centre from its nominal, over the axes that the
  terminal cost weights (``Qf.ball_position`` > 0; only z for the lifting task);
* ``target_error_xyz_m``: the signed per-axis errors (final − nominal, 0 on unweighted axes);
* ``max_ball_height_gain_m``: highest ball centre over the trajectory minus its start height;
* ``contact_links``: bodies (other than the world/ground) that touched the ball at any step,
  from a geometry query of the touching pairs at every state; ``contact_steps`` per link;
  ``max_arm_ball_faces``: most contact polygons between the arm and the ball at one step.

``metric_params.ball`` names the ball's body (default ``ball``). The plot ``ball.png`` shows the
ball centre's x, y, z against time with the targets dashed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hydroilqr.metrics import contact_pairs, metric
from hydroilqr.output import report
from hydroilqr.problem.config import ConfigError


def _ball_block(task):
    name = task.config.metric_params.get("ball", "ball")
    layout = task.dynamics.layout
    key = f"{name}.position"
    if key not in layout.primitives:
        raise ConfigError(f"metric_params.ball: no floating body named {name!r}")
    return name, layout.primitives[key]


def _ball_track(task, sol):
    """(ball body name, P: [T, 3] ball centre, targets: [T, 3], axis weights: [3])."""
    name, block = _ball_block(task)
    idx = list(block.coords)
    P = np.asarray(sol.X)[:, idx]
    targets = task.cost.nominal(np.asarray(sol.t))[:, idx]
    w = task.cost.qf[list(block.tangent)]
    return name, P, targets, w


def ball_contacts(task, sol, ball: str) -> tuple[dict[str, int], int]:
    """Steps in contact per body touching ``ball`` (world excluded) and most faces at a step."""
    dyn = task.dynamics
    steps: dict[str, int] = {}
    max_faces = 0
    for x in np.asarray(sol.X)[1:]:
        faces = 0
        touching = set()
        for _ga, ba, _gb, bb, n in contact_pairs(dyn, x):
            if ball not in (ba, bb):
                continue
            other = bb if ba == ball else ba
            if other == "world":
                continue
            touching.add(other)
            faces += n
        for body in touching:
            steps[body] = steps.get(body, 0) + 1
        max_faces = max(max_faces, faces)
    return steps, max_faces


@metric("kinova")
def kinova_metrics(task, sol) -> dict:
    name, P, targets, w = _ball_track(task, sol)
    err = np.where(w > 0, P[-1] - targets[-1], 0.0)
    steps, max_faces = ball_contacts(task, sol, name)
    order = [b for b in _body_order(task) if b in steps] + sorted(
        b for b in steps if b not in _body_order(task)
    )
    return {
        "ball_start_m": P[0],
        "ball_final_m": P[-1],
        "ball_target_m": targets[-1],
        "ball_displacement_m": P[-1] - P[0],
        "target_error_m": float(np.linalg.norm(err)),
        "target_error_xyz_m": err,
        "max_ball_height_gain_m": float(np.max(P[:, 2]) - P[0, 2]),
        "contact_links": order,
        "contact_steps": {b: steps[b] for b in order},
        "max_arm_ball_faces": int(max_faces),
    }


def _body_order(task) -> list[str]:
    plant = task.dynamics.plant
    from pydrake.multibody.tree import BodyIndex

    return [plant.get_body(BodyIndex(i)).name() for i in range(plant.num_bodies())]


@report.plot("kinova", files=("ball.png",))
def plot_ball(task, sol, out: Path) -> None:
    import matplotlib.pyplot as plt

    _, P, targets, w = _ball_track(task, sol)
    t = np.asarray(sol.t)
    fig, ax = plt.subplots(figsize=(6.2, 3.4))
    for i, (axis, color) in enumerate(zip("xyz", ("C0", "C1", "C2"))):
        ax.plot(t, P[:, i], color=color, label=f"ball {axis}")
        if w[i] > 0:
            ax.plot(t, targets[:, i], "--", color=color, lw=1, label=f"target {axis}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("ball centre [m]")
    ax.set_title(f"{task.name}: ball position")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1))  # inside, it hid a target
    fig.tight_layout()
    fig.savefig(Path(out) / "ball.png", dpi=120)
    plt.close(fig)
