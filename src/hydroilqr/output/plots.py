"""Figures: the one place a figure is saved (``savefig``), and the convergence plot every solve
writes. Plots of metrics live with their metric (``hydroilqr.metrics``); studies and control
loops draw their own figures and save them here."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

DPI = 120


def pyplot():
    """matplotlib.pyplot on the non-interactive backend (figures are only written to files)."""
    return plt


def savefig(fig, path: str | Path, dpi: int = DPI) -> Path:
    """Lays ``fig`` out (tight), writes it to ``path`` and closes it."""
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return Path(path)


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
    ax.set_title(f"{title}: iLQR cost per iteration")
    ax.grid(True, which="both", alpha=0.3)
    savefig(fig, path)
