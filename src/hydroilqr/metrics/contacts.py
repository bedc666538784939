"""The contact timeline (part of the ``default`` metric; also ``metrics: [contacts]``).

``contacts``: one entry per pair of collision geometries that touched along the solution,
in order of first contact::

    {pair: [geometry A, geometry B], bodies: [body A, body B],
     intervals: [[t_first, t_last], ...], steps: n, peak_normal_force_N: f}

``intervals`` are runs of consecutive states in contact (times of the first and last state of
each run); ``steps`` counts the states in contact; ``peak_normal_force_N`` is the largest
normal force of the pair over the steps, from the contact solve of each step (x_k, u_k) (the
final state has no step: it adds contact but no force). Plot: ``contacts.png``, pairs against
time, a bar wherever a pair touches.

``model.contacts.touched_pairs(task)`` gives the pairs a rollout of the initial guess touches
(``check``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hydroilqr.io.figures import pyplot, savefig
from hydroilqr.metrics.registry import Metric, register
from hydroilqr.model.contacts import runs, timeline
from hydroilqr.model.names import SCOPE

_cache: dict = {}


def _cached(task, sol):
    key = (task, sol.X)  # held, so neither id is reused while cached
    old = _cache.get("key", (None, None))
    if not (old[0] is task and old[1] is sol.X):
        _cache["key"] = key
        _cache["value"] = timeline(task, sol.X, getattr(sol, "U", None))
    return _cache["value"]


def contact_metrics(task, sol) -> dict:
    pairs, on, force = _cached(task, sol)
    t = np.asarray(sol.t)
    return {
        "contacts": [
            {
                "pair": list(key),
                "bodies": list(bodies),
                "intervals": [
                    [round(float(t[a]), 9), round(float(t[b]), 9)] for a, b in runs(on[:, j])
                ],
                "steps": int(np.sum(on[:, j])),
                "peak_normal_force_N": float(np.max(force[:, j])),
            }
            for j, (key, bodies) in enumerate(pairs)
        ]
    }


def state_step(task, sol) -> float:
    """The time between the states of ``sol`` (s): an MPC run's robot may step finer than the
    task's plan; a single state falls back on the task's time step."""
    t = np.asarray(sol.t)
    return float(t[1] - t[0]) if len(t) > 1 else task.config.plant.time_step


def pair_label(pair, bodies) -> str:
    """``A / B`` of a pair of geometries, each with its body where that body's name is scoped
    by its model (two models share the name: ``Box (cube::base_link)``)."""
    return " / ".join(
        f"{g} ({b})" if SCOPE in b and SCOPE not in g else g for g, b in zip(pair, bodies)
    )


def plot_contacts(task, sol, out) -> None:
    plt = pyplot()
    pairs, on, _ = _cached(task, sol)
    t = np.asarray(sol.t)
    dt = state_step(task, sol)
    P = len(pairs)
    fig, ax = plt.subplots(figsize=(6.5, 1.2 + 0.3 * max(P, 1)))
    for j in range(P):
        bars = [(float(t[a]), float(t[b] - t[a] + dt)) for a, b in runs(on[:, j])]
        ax.broken_barh(bars, (P - 1 - j - 0.35, 0.7), color=f"C{j % 10}")
    ax.set_yticks([P - 1 - j for j in range(P)], [pair_label(k, b) for k, b in pairs])
    ax.tick_params(axis="y", labelsize=7)
    ax.set_ylim(-0.6, max(P, 1) - 0.4)
    ax.set_xlim(t[0], t[-1] + dt)
    ax.set_xlabel("time [s]")
    title = "contact per geometry pair" if P else "no contact along the solution"
    ax.set_title(f"{task.name}: {title}")
    ax.grid(True, axis="x", alpha=0.3)
    savefig(fig, Path(out) / "contacts.png")


register(Metric("contacts", compute=contact_metrics, plot=plot_contacts, files=("contacts.png",)))
