"""Transmission error (beyond the paper): the PPANN's state is the motor encoder's angle, the
slider is driven by the crank, and between the two a backlash (or any compliance) lets the crank
sit at theta + delta. Open loop the slider's spread is millimetres and delta hardly shows; in
closed loop, where feedback holds the motor angle to a few mrad, it dominates: on line-15 under
the LQR tube the slider's spread at sample 50 computed from the motor angle was 0.28 mm (what
the closed-loop Monte-Carlo predicted), the measured slider's 0.53 mm, the difference the crank
rattling in the backlash gap (its angle to the motor 7.9 mrad rms).

delta is not measured, but the slider position is (the dataset contract's measurement channel):
delta_k solves x(theta_k + delta_k) = x_measured_k, by Newton steps from 0, on samples away from
the dead centres (|dx/dtheta| at least half its largest value), where the slider tells the
crank angle well. The checkpoint keeps the empirical quantiles of delta at LEVELS; the
Monte-Carlo draws delta independently for each trajectory and sample by inverse CDF and puts
the slider at x(theta + delta) (control/robust.py, replay/heldout.py). Zero quantiles (nothing
fitted) draw delta = 0, which leaves every slider as it was, bit for bit.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from twin.geometry import Geometry

LEVELS = np.linspace(0.0, 1.0, 101)
"""Probability levels of the stored quantiles of delta."""
NEWTON_STEPS = 4
SLOPE_SHARE = 0.5
"""Samples used: |dx/dtheta| >= this share of its largest value (~ the crank length)."""


def transmission_angles(
    theta: npt.ArrayLike, slider: npt.ArrayLike, *, geometry: Geometry
) -> np.ndarray:
    """delta (rad) of the samples away from the dead centres, from motor angle and measured
    slider position (module docstring)."""
    theta, slider = np.asarray(theta, dtype=float), np.asarray(slider, dtype=float)
    usable = np.abs(geometry.slider_slope(theta)) >= SLOPE_SHARE * geometry.crank_length
    theta, slider = theta[usable], slider[usable]
    delta = np.zeros_like(theta)
    for _ in range(NEWTON_STEPS):
        crank = theta + delta
        delta = delta + (slider - geometry.slider_position(crank)) / geometry.slider_slope(crank)
    return delta


def fit_quantiles(theta: npt.ArrayLike, slider: npt.ArrayLike, *, geometry: Geometry) -> np.ndarray:
    """Quantiles of delta at LEVELS, (len(LEVELS),); zeros if no sample is usable."""
    delta = transmission_angles(theta, slider, geometry=geometry)
    if delta.size == 0:
        return np.zeros(len(LEVELS))
    return np.quantile(delta, LEVELS)


def draw(quantiles: np.ndarray, shape: tuple[int, ...], rng: np.random.Generator) -> np.ndarray:
    """delta of the given shape by inverse CDF (linear between the stored quantiles)."""
    if not np.any(quantiles):
        return np.zeros(shape)
    return at_levels(quantiles, rng.uniform(size=shape))


def at_levels(quantiles: np.ndarray, levels: npt.ArrayLike) -> np.ndarray:
    """delta at probability levels `levels` (the inverse CDF, linear between the stored
    quantiles; zeros where nothing was fitted): `draw`'s, and control/tail_lines.py's at the
    normal score's level."""
    levels = np.asarray(levels, dtype=float)
    if not np.any(quantiles):
        return np.zeros(levels.shape)
    return np.interp(levels, LEVELS, quantiles)
