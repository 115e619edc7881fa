"""Monte-Carlo simulation of a PPANN (paper eq. 11), vectorised over samples and seeded.

Two ways to draw z = z_mu + z_sigma * eps, eps ~ N(0, I):
- "step": a fresh eps at every step (the paper's eq. 11), white in time;
- "trajectory": one eps per trajectory, held for its whole length (fully correlated in time), as
  a machine whose friction differs systematically from the mean would behave.

The loop runs in NumPy on the fused weights (`FusedHeads`): a few dozen array operations per step
on (n_samples,) arrays, where torch's per-operation overhead would dominate.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from ppann.model import PPANN, FusedHeads

Mode = Literal["step", "trajectory"]
MODES: tuple[Mode, ...] = ("step", "trajectory")


@dataclass(frozen=True)
class Bands:
    """Trajectories (n_samples, T + 1, 2) and their mean and standard deviation (T + 1, 2)."""

    samples: np.ndarray
    mean: np.ndarray
    std: np.ndarray


def monte_carlo(
    model: PPANN | FusedHeads,
    x0: npt.ArrayLike,
    tau: npt.ArrayLike,
    *,
    n_samples: int = 100,
    mode: Mode = "step",
    seed: int = 0,
) -> Bands:
    """Simulate n_samples trajectories of the PPANN from x0 (2,) under tau (T,).

    A draw that diverges (possible with trajectory draws of a model whose σ allows a negative
    effective damping) becomes inf/NaN in its samples, silently: callers report such numbers as
    null rather than let NumPy print overflow warnings at the user.
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if n_samples < 2:
        raise ValueError(f"n_samples must be >= 2 for a standard deviation, got {n_samples}")
    heads = model if isinstance(model, FusedHeads) else FusedHeads(model)
    tau = np.asarray(tau, dtype=float)
    rng = np.random.default_rng(seed)
    steps = tau.shape[0]
    eps = rng.standard_normal((1 if mode == "trajectory" else steps, n_samples, 3))
    samples = np.empty((n_samples, steps + 1, 2))
    theta = np.full(n_samples, float(np.asarray(x0)[0]))
    omega = np.full(n_samples, float(np.asarray(x0)[1]))
    samples[:, 0, 0], samples[:, 0, 1] = theta, omega
    dt = heads.dt
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(steps):
            mean, sigma = heads(theta, omega)
            z = mean + sigma * eps[0 if mode == "trajectory" else k]
            alpha = heads.acceleration(theta, omega, tau[k], z)
            theta, omega = theta + dt * omega, omega + dt * alpha
            samples[:, k + 1, 0], samples[:, k + 1, 1] = theta, omega
        return Bands(samples, samples.mean(axis=0), samples.std(axis=0, ddof=1))
