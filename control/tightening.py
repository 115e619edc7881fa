"""The tightening of the robust constraint (eq. 16 and beyond) at each constraint sample, from
the Monte-Carlo of one torque: gaussian k sigma or the empirical one-sided quantile, each with
its standard error, and the allowance for the line as known from a few machines (`confidence`,
control/robust.py's docstring): the machine spread the Monte-Carlo draws with, and how far the
line's mean slider can sit below the model's."""

from __future__ import annotations

import math

import numpy as np

from control.config import OCPConfig, confidence_quantile, lower_tail
from control.ocp import Solution, slider_position
from ppann.machine import sigma_upper
from ppann.model import FusedHeads
from ppann.montecarlo import MONTE_CARLO_MODES, line_sensitivity, rollout


def line_allowance(heads: FusedHeads, config: OCPConfig) -> tuple[np.ndarray | None, float]:
    """The machine spread the Monte-Carlo draws with (None: the model's own) and z, for the
    configured confidence (module docstring)."""
    z = confidence_quantile(config.confidence)
    if z == 0 or not MONTE_CARLO_MODES[config.mc_mode].machine:
        return None, z
    return sigma_upper(heads.machine_sigma, heads.machine_profile, z), z


def population_margin(
    heads: FusedHeads, solution: Solution, config: OCPConfig, z: float
) -> np.ndarray:
    """How far the line's mean slider can sit below the model's at each constraint sample, at
    one-sided normal quantile z (module docstring), m: the largest drop of the mean model's slider
    over line shifts delta on the ellipsoid delta^T C^-1 delta = z^2, evaluated by simulation, not
    linearised (near top dead centre the slider is concave in theta: the linear bound was 30 %
    short in tests/test_tightening.py). The shifts tried: the linear worst case
    -z C g / sqrt(g^T C g) of each sample (g = d slider / d delta) and ELLIPSOID_DIRECTIONS spread
    evenly over the ellipsoid."""
    count = len(config.constraint_samples)
    if z == 0 or not np.any(heads.common_covariance):
        return np.zeros(count)
    index = np.array(config.constraint_samples) - 1
    steps = int(index.max())
    x0, tau = solution.states[0], solution.tau[:steps]
    d_theta = line_sensitivity(heads, x0, tau)[index]
    theta = solution.states[index, 0]
    h = 1e-6
    d_slider = (slider_position(theta + h) - slider_position(theta - h)) / (2 * h)
    g = d_slider[:, None] * d_theta
    c = heads.common_covariance
    values, vectors = np.linalg.eigh(0.5 * (c + c.T))
    root = vectors * np.sqrt(np.clip(values, 0.0, None))  # root @ root.T == c
    shifts = [z * _sphere(ELLIPSOID_DIRECTIONS) @ root.T]
    spread = np.sqrt(np.einsum("ki,ij,kj->k", g, c, g))
    for gk, sk in zip(g, spread, strict=True):
        if sk > 0:
            shifts.append((-z * c @ gk / sk)[None])
    delta = np.concatenate([np.zeros((1, 3)), *shifts])
    paths = rollout(heads, x0, tau, n_samples=len(delta), factors=np.exp(delta))
    with np.errstate(invalid="ignore"):
        slider = slider_position(paths[:, index, 0])
    drop = slider[0] - slider[1:]
    return np.clip(np.where(np.isfinite(drop), drop, np.inf).max(axis=0), 0.0, None)


ELLIPSOID_DIRECTIONS = 64
"""Shifts of the line tried evenly over the confidence ellipsoid (beside the linear worst case)."""


def _sphere(n: int) -> np.ndarray:
    """n unit vectors spread evenly over the sphere (Fibonacci lattice), (n, 3)."""
    i = np.arange(n) + 0.5
    polar = np.arccos(1 - 2 * i / n)
    azimuth = np.pi * (1 + 5**0.5) * i
    return np.stack(
        [np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=-1
    )


def tightening(
    samples: np.ndarray, plan: float, *, k_sigma: float, method: str
) -> tuple[float, float]:
    """The margin one constraint sample asks for, and its standard error, from Monte-Carlo slider
    positions `samples` (n,) under a plan whose mean-model slider position is `plan`.

    gaussian  k·σ (paper eq. 16); standard error k·σ / sqrt(2 (n − 1)) (normal samples).
    quantile  plan − Q_p, Q_p the empirical lower quantile at p = Φ(−k), so that the slider is
              above the height with the probability k·σ stands for even when the spread is skewed
              or its mean is not the plan; standard error half the distance between the order
              statistics n p ∓ sqrt(n p (1 − p)) (distribution-free).
    """
    n = samples.shape[0]
    if method == "gaussian":
        sigma = float(np.std(samples, ddof=1))
        return k_sigma * sigma, k_sigma * sigma / math.sqrt(2 * (n - 1))
    p = lower_tail(k_sigma)
    ordered = np.sort(samples)
    spread = math.sqrt(n * p * (1 - p))
    lo = ordered[max(0, math.floor(n * p - spread))]
    hi = ordered[min(n - 1, math.ceil(n * p + spread))]
    return plan - float(np.quantile(samples, p)), float(hi - lo) / 2
