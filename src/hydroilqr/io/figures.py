"""Figures: the one place a figure is saved (``savefig``) and the pyplot every plot draws
with (the non-interactive backend: figures are only written to files)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

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
