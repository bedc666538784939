"""The plots (and the reference table) of each result set: convergence.png of a solve, mpc.png,
playback.png, reference.csv and playback.html. Figures are saved with ``io.figures.savefig``;
plots of metrics live with their metric (``hydroilqr.metrics``)."""

from __future__ import annotations

import csv
import warnings
from pathlib import Path

import numpy as np
from pydrake.multibody.tree import JointIndex

from hydroilqr.control.mpc import MPCResult
from hydroilqr.control.playback import PlaybackResult
from hydroilqr.io.figures import pyplot, savefig
from hydroilqr.model.plant import position_unit
from hydroilqr.output.replay import write_replay
from hydroilqr.problem.errors import ConfigError

plt = pyplot()


def plot_convergence(sol, path: Path, title: str) -> None:
    fig, ax = plt.subplots(figsize=(5, 3.2))
    c = np.asarray(sol.costs, float)
    ax.semilogy(np.arange(len(c)), np.maximum(c, 1e-300), "o-", ms=3)
    windows = "resolves" in sol.extra  # receding horizon: one window's costs after another
    stages = sol.extra.get("continuation") or []
    if stages:  # continuation: each stage on its own model; mark where the next one starts
        start = 0
        for i, st in enumerate(stages[:-1]):
            start += st["iterations"]
            ax.axvline(start, color="0.5", ls=":", lw=1)
            nxt = stages[i + 1]["start_cost"]
            ax.plot([start], [max(nxt, 1e-300)], "o", mfc="none", mec="C0", ms=6)
    label = "iteration"
    if windows:
        label = "iteration (all windows, each with its own cost)"
    elif stages:
        label = "iteration (continuation stages, each on its own model)"
    ax.set_xlabel(label)
    ax.set_ylabel("cost")
    searched = sol.reason in ("search", "interrupted") and np.size(sol.K) == 0
    ax.set_title(f"{title}: {'best sample cost' if searched else 'iLQR cost'} per iteration")
    ax.grid(True, which="both", alpha=0.3)
    savefig(fig, path)


def plot_search(costs: np.ndarray, path: Path, title: str) -> None:
    """search.png: every sample's cost per search iteration (dots; failed rollouts left out),
    the iteration's median and the best cost so far. costs: [iterations, samples]."""
    costs = np.asarray(costs, float)
    fig, ax = plt.subplots(figsize=(5.5, 3.4))
    its = np.arange(costs.shape[0])
    finite = np.where(np.isfinite(costs), costs, np.nan)
    for i in its:
        ax.semilogy(
            np.full(costs.shape[1], i), np.maximum(finite[i], 1e-300), ".", color="0.7", ms=2
        )
    if costs.size:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # (a row of failed rollouts)
            ax.semilogy(its, np.nanmedian(finite, axis=1), "-", color="C1", label="median sample")
            ax.semilogy(its, np.fmin.accumulate(np.nanmin(finite, axis=1)), "o-", ms=3,
                        color="C0", label="best so far")  # fmt: skip
        ax.legend(fontsize=8)
    ax.set_xlabel("search iteration")
    ax.set_ylabel("cost")
    ax.set_title(f"{title}: sampling search")
    ax.grid(True, which="both", alpha=0.3)
    savefig(fig, path)


def plotted_blocks(task) -> list[tuple[str, str]]:
    """(name, unit) of the (at most 4) position blocks mpc.png plots: the object the metrics
    follow (``metric_params.object``/``ball``) first, then the blocks weighted in the running
    or terminal cost (a pushed cube weighted only in Qf included), euclidean with every
    coordinate in q (a velocity group such as the Kinova's ``arm_v`` is left out whatever its
    name), each set of coordinates once. The unit: "m" or "rad" when every coordinate is a
    prismatic/revolute joint's or a floating body's position, else ""."""
    layout, plant = task.dynamics.layout, task.dynamics.plant
    joints = [plant.get_joint(JointIndex(i)) for i in range(plant.num_joints())]

    def unit(coords) -> str:
        units = {
            position_unit(j)
            for c in coords
            for j in joints
            if j.position_start() <= c < j.position_start() + j.num_positions()
        }
        return units.pop() if len(units) == 1 else ""

    cost = task.config.cost
    params = task.config.metric_params
    obj = params.get("object", params.get("ball"))
    names = [f"{obj}.position"] if isinstance(obj, str) else []
    names += [
        n for w in (cost.Q, cost.Qf) for n, v in w.items() if np.any(np.asarray(v, float) > 0)
    ]
    out, seen = [], set()
    for n in names:
        try:
            b = layout.block(n)
        except ConfigError:  # (an object that is not a floating body: not plotted)
            continue
        if b.kind == "euclidean" and all(c < layout.nq for c in b.coords) and b.coords not in seen:
            seen.add(b.coords)
            out.append((n, unit(b.coords)))
    return out[:4]


def plot_mpc(task, res: MPCResult, path: Path) -> None:
    layout = task.dynamics.layout
    blocks = plotted_blocks(task)
    n = len(blocks) + 2  # the blocks, the commands, the solve times
    fig, axes = plt.subplots(n, 1, figsize=(7, 2.0 * n), sharex=True)
    axes = np.atleast_1d(axes)
    xn = task.cost.nominal(res.t)
    params = task.config.metric_params
    obj = f"{params.get('object', params.get('ball'))}.position"
    for ax, (name, unit) in zip(axes, blocks):
        b = layout.block(name)
        # the object from where it starts: centimetres of travel, not its height in the room
        x0 = res.X[0] if name == obj else np.zeros(res.X.shape[1])
        for j, c in enumerate(b.coords):
            lab = f"{name}[{j}]" if len(b.coords) > 1 else name
            (line,) = ax.plot(res.t, res.X[:, c] - x0[c], label=lab)
            # the nominal in its coordinate's colour: several share a panel (a ball's x, y, z)
            ax.plot(
                res.t,
                xn[:, c] - x0[c],
                "--",
                color=line.get_color(),
                lw=0.8,
                label=f"{lab} nominal",
            )
        what = f"{name} − start" if name == obj else name
        ax.set_ylabel(f"{what} [{unit}]" if unit else f"{what}\n(model units)")
    for i, p in enumerate(res.settings.pushes):
        for ax in axes:
            ax.axvspan(
                p.time,
                p.time + p.duration,
                color="red",
                alpha=0.15,
                label="push" if i == 0 else None,
            )
    _plot_commands(axes[-2], task, res)
    for ax in axes[:-1]:  # beside the panel: a legend inside hid a target line
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1))
    ax = axes[-1]
    solve_ms = 1e3 * np.array(res.solve_seconds)
    period = 1e3 / res.settings.rate
    ax.plot(res.update_times, solve_ms, ".", ms=3, label="solve time")
    ax.axhline(period, color="k", ls="--", lw=0.8, label="control period")
    span = solve_ms[solve_ms > 0]
    if span.size and max(span.max(), period) / min(span.min(), period) > 30:
        ax.set_yscale("log")  # solve times far above (or below) the period: all visible
    ax.set_ylabel("solve time [ms]")
    ax.set_xlabel("time [s]")
    ax.set_xlim(res.t[0], res.t[-1])  # a push lasting past the run's end widened the axis
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1))
    axes[0].set_title(f"{task.name}: closed-loop MPC at {res.settings.rate:g} Hz")
    savefig(fig, path)


def _plot_commands(ax, task, res: MPCResult) -> None:
    """The controller's commands per actuator (before the effort limits clip them), stepped."""
    U = res.U_commanded if res.U_commanded is not None and len(res.U_commanded) else res.U
    names = task.dynamics.layout.actuators
    for i in range(U.shape[1] if U.ndim == 2 else 0):
        label = names[i] if i < len(names) and U.shape[1] <= 8 else None
        ax.step(res.t[: len(U)], U[:, i], where="post", lw=0.9, label=label)
    ax.set_ylabel("commands\n[N·m or N]")


def write_reference_csv(r: PlaybackResult, path: Path) -> None:
    """time, q̄_J, v̄_J, ū at the update rate; units in the column names (docs/playback.md)."""

    def vunit(u):
        return "m_per_s" if u == "m" else "rad_per_s"

    header = ["time_s"]
    header += [f"q_{j}_{u}" for j, u in zip(r.joints, r.joint_units)]
    header += [f"v_{j}_{vunit(u)}" for j, u in zip(r.joints, r.joint_units)]
    header += [f"u_{a}_{'N' if u == 'm' else 'Nm'}" for a, u in zip(r.actuators, r.joint_units)]
    ref = r.reference
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        for i in range(len(ref.t)):
            w.writerow(
                [f"{ref.t[i]:.6f}"] + [f"{v:.9g}" for v in np.r_[ref.q[i], ref.v[i], ref.u[i]]]
            )


def plot_playback(r: PlaybackResult, path: Path, title: str) -> None:
    c = list(r.obj.coords)
    t, X, X_plan = r.t, r.X, r.X_plan
    if r.hold is not None and len(r.hold.t):  # the hold after the plan, on the same axes
        t = np.concatenate([t, r.hold.t])
        X = np.concatenate([X, r.hold.X])
        X_plan = np.concatenate([X_plan, r.hold.X_plan])
    labels = ["x", "y", "z"] if r.obj.kind == "floating" else [r.obj.name]
    if len(c) != len(labels):
        labels = [f"{r.obj.name}[{i}]" for i in range(len(c))]
    rows = len(c) + 1
    fig, axes = plt.subplots(rows, 1, figsize=(6.4, 1.9 * rows + 0.6), sharex=True)
    for i, ax in enumerate(axes[:-1]):
        stretched = abs(r.settings.speed - 1.0) > 1e-12
        plan_label = "planned (time-stretched)" if stretched else "planned"
        ax.plot(t, X_plan[:, c[i]], "--", color="0.4", label=plan_label)
        ax.plot(t, X[:, c[i]], color="C0", label="actual")
        ax.set_ylabel(f"{labels[i]} [{r.obj.unit}]" if r.obj.unit else labels[i])
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, loc="best")
    ax = axes[-1]
    m = r.metrics
    qi = r.q_indices
    for i, name in enumerate(r.joints):
        ax.plot(t, X[:, qi[i]] - X_plan[:, qi[i]], lw=1, label=name)
    units = set(r.joint_units)
    unit = f" [{units.pop()}]" if len(units) == 1 else " [m or rad]"
    ax.set_ylabel(f"joint error{unit}\n(actual − plan)")
    ax.set_xlabel("playback time [s]")
    ax.grid(alpha=0.3)
    if len(r.joints) <= 12:  # one joint too: which one it is (the cart-pole's cart)
        ax.legend(fontsize=6, ncol=4, loc="best")
    ob = m["object"]
    gaps = f"final gap {ob['final_gap']:.3g} {r.obj.unit}"
    if ob.get("resting_gap") is not None:
        gaps = f"resting gap {ob['resting_gap']:.3g} {r.obj.unit} (at the plan's end {gaps[6:]})"
    fig.suptitle(
        f"{title}: {m['policy']} playback at speed {r.settings.speed:g}, truth plant "
        f"{r.truth_contact} contact, dt={r.settings.truth_time_step:g} s\n{gaps}, max deviation "
        f"{ob['max_deviation']:.3g} {r.obj.unit}",
        fontsize=9,
    )
    if len(t) > len(r.t):
        for ax in axes:  # the plan's end; after it the robot holds its last reference
            ax.axvline(r.t[-1], color="0.6", lw=0.8, ls=":")
    savefig(fig, path)


def write_playback_replay(task, r: PlaybackResult, path: Path) -> None:
    """Meshcat HTML: the actual motion first, then (after a short pause) the plan at the same
    playback speed."""
    write_replay(task, [r.X, r.X_plan], r.t, path, inputs=[r.U, r.U_plan])
