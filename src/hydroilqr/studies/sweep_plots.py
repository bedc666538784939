"""A sweep's plots: metric(s) against the parameter, with the goal's bounds
(``studies/sweep.py`` draws them; re-exported there)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hydroilqr.io.figures import pyplot, savefig

plt = pyplot()

# ------------------------------------------------------------------------------------------
# Plots
# ------------------------------------------------------------------------------------------


def _log_axis(vals: list) -> bool:
    v = [float(x) for x in vals if x is not None]
    return bool(v) and min(v) > 0 and max(v) / min(v) >= 100


def goal_panels(goal: dict) -> list[tuple[str, str]]:
    """(metric, axis label) of each goal check with a fixed bound, its bounds in the label."""
    return [
        (name, f"{name}\n(goal: {check.describe()})")
        for name, check in goal.items()
        if check.min is not None or check.max is not None
    ]


def _bounds(goal: dict, metric: str) -> list[float]:
    check = goal.get(metric)
    return [] if check is None else [b for b in (check.min, check.max) if b is not None]


def plot_sweep(
    path: Path,
    task_name: str,
    param_keys: list[str],
    rows: list[dict],
    grid_values: list[list],
    metric_panels: list[tuple[str, str]] = (),
    goal: dict | None = None,
) -> None:
    """sweep.png: each of ``metric_panels`` ((key, axis label), from the task's metrics) that
    some point reports, and the final cost, against the first parameter (a series per value
    of the second)."""
    key = param_keys[0]
    other = param_keys[1] if len(param_keys) > 1 else None
    shown = [(k, lab) for k, lab in metric_panels if any(r.get(k) is not None for r in rows)]
    panels = [k for k, _ in shown] + ["final_cost"]
    labels = {**dict(shown), "final_cost": "final cost"}  # circles: "not converged" in legend
    fig, axes = plt.subplots(
        len(panels), 1, figsize=(6.2, 2.7 * len(panels) + 0.4), sharex=True, squeeze=False
    )
    series = (
        [(None, rows)]
        if other is None
        else [(v, [r for r in rows if r.get(f"param:{other}") == v]) for v in grid_values[1]]
    )
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, metric in zip(axes[:, 0], panels):
        labelled: set[str] = set()  # each marker kind in the legend once, whichever series

        def once(kind: str, labelled=labelled) -> str | None:
            if kind in labelled:
                return None
            labelled.add(kind)
            return kind

        for j, (ov, rs) in enumerate(series):
            ok = sorted((r for r in rs if r.get("status") == "ok"), key=lambda r: r[f"param:{key}"])
            xs = [r[f"param:{key}"] for r in ok]
            ys = [r.get(metric) for r in ok]
            c = colors[j % len(colors)]
            lab = None if ov is None else f"{other} = {ov:.4g}"
            ax.plot(xs, [np.nan if y is None else y for y in ys], "o-", color=c, ms=5, label=lab)
            tun = [(x, y) for x, y, r in zip(xs, ys, ok) if r.get("tunnelled") and y is not None]
            if tun:
                ax.plot(
                    *zip(*tun),
                    "x",
                    color="red",
                    ms=11,
                    mew=2.5,
                    label=once("tunnelled"),
                )
            nconv = [
                (x, y) for x, y, r in zip(xs, ys, ok) if not r.get("converged") and y is not None
            ]
            if nconv:
                ax.plot(
                    *zip(*nconv),
                    "o",
                    mfc="none",
                    mec="k",
                    ms=10,
                    label=once("not converged"),
                )
            bad = [r[f"param:{key}"] for r in rs if r.get("status") != "ok"]
            for x in bad:
                ax.axvline(x, color="gray", ls=":", lw=1.2, label=once("failed"))
        for b in _bounds(goal or {}, metric):  # the goal's bound on this metric
            ax.axhline(b, color="C3", ls="--", lw=1, label=once("goal bound"))
        ax.set_ylabel(labels.get(metric, metric))
        # log when the values span decades (overlap: 0.2 mm stiff, 100 mm tunnelled); not
        # when one is 0 (no contact), which a log axis would drop
        vals = [r.get(metric) for r in rows if r.get("status") == "ok"]
        vals = [v for v in vals if v is not None]
        if vals and min(vals) > 0 and max(vals) / min(vals) > 20:
            ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    ax = axes[-1, 0]
    if _log_axis(grid_values[0]):
        ax.set_xscale("log")
    ax.set_xlabel(key + (" [Pa]" if key.endswith("hydroelastic_modulus") else ""))
    axes[0, 0].set_title(f"{task_name}: sweep of {key}")
    savefig(fig, path)
