"""Saving figures: PNG, atomically, with the project's resolution."""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure

from common.atomic import atomic_path


def save_figure(fig: Figure, path: str | Path) -> None:
    """Write `fig` as a PNG at `path`, atomically."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
