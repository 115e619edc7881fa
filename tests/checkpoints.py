"""The constant-network PPANN the tests save where a command or a file needs a checkpoint
(`crank solve --model`, `heldout_file`, the MPC's model): no training, known z."""

from __future__ import annotations

from pathlib import Path

from ppann.checkpoint import save
from ppann.model import PPANN, constant_ppann


def constant_checkpoint(
    path: Path, *, z_sigma: tuple[float, float, float] = (0.03, 0.05, 0.05)
) -> PPANN:
    """A PPANN with constant networks (z_mean 0, 0, -0.9) saved at `path`; returned."""
    model = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=z_sigma)
    save(path, model, kind="ppann", extra={"history": {}})
    return model
