"""The slider force's channel (beyond the paper; `PPANNConfig.sigma_lever`).

The twin's unmeasured white force F on the slider reaches the motor as a torque x'(theta) F,
x' = dx/dtheta of the mechanism's kinematics: it has no lever at the dead centres (theta = 0 and
pi). Eq. 9's white noise enters eq. 14 as factors on the inertia, damping and stiffness terms,

    r = J_m (1 + z_J) alpha + B_m (1 + z_B) omega + K_m (1 + z_K) theta_mod - tau,

and none of them vanishes there: starting from rest at bottom dead centre J_m alpha is large,
crawling over top dead centre K_m theta_mod is. Measured along seed 0's robust torque
(docs/history.md, session 19), the networks put 1.8x the twin's force variance on the start from
rest and 6.3x on the crawl over top dead centre, and the predicted slider spread was 1.1-1.5x the
machines'.

This channel adds to the torque balance

    r = ... - x'(theta) F,   F ~ N(0, lever_sigma^2),

one scalar fitted in phase 2 beside the networks (the likelihood's white variance gains
lever_sigma^2 x'(theta)^2 per sample), and the Monte-Carlo draws F with its own normals, white
in time like eq. 11's z. It is a disturbance on the load, not part of the motor's torque: in a
closed loop it is added after the law's saturation.
"""

from __future__ import annotations

import numpy as np
import torch

from twin.geometry import Geometry

LEVER_START = 5.0
"""lever_sigma at the start of phase 2, N (the twin's force is U[-30, 30] N: 17.3 N)."""


def lever_arm(geometry: Geometry, theta: np.ndarray) -> np.ndarray:
    """x'(theta) = dx/dtheta of `geometry`'s kinematics, m/rad, (n,)."""
    return geometry.slider_slope(np.asarray(theta, dtype=float))


def lever_squared(geometry: Geometry, theta: torch.Tensor) -> torch.Tensor:
    """x'(theta)^2 per sample, (n,), for the phase-2 likelihood (theta is data, not trained)."""
    return torch.from_numpy(lever_arm(geometry, theta.detach().numpy()) ** 2)


def lever_torque_sigma(table: np.ndarray, cell: float, theta: np.ndarray) -> np.ndarray:
    """lever_sigma x'(theta) at `theta` (n,) from FusedHeads' `lever_table` over one turn
    (`cell` rows per radian), interpolated linearly as the angle networks' table and the C
    kernel do; 0 where theta is not finite."""
    at = np.remainder(theta, 2 * np.pi) * cell
    at = np.where(np.isfinite(at), at, 0.0)
    row = np.minimum(at.astype(np.intp), len(table) - 2)
    frac = at - row
    return table[row] * (1 - frac) + table[row + 1] * frac
