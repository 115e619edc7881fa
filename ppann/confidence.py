"""How the robust tightening's confidence is split (control/robust.py), in a module of its own so
that the OCP's configuration and the PPANN's report (which states the bounds the OCP will use)
share one rule without importing torch.

The training machines are a few draws of the line, and the Monte-Carlo estimates the tightening
from finitely many trajectories. Three one-sided bounds allow for that: on the line's mean, on
the line's spread, and on the Monte-Carlo's estimate. A confidence c is split evenly between
them (Bonferroni), each bound at 1 - (1 - c) / 3, so that all three hold together with
probability >= c."""

from __future__ import annotations

import statistics

DEFAULT_CONFIDENCE = 0.95
CONFIDENCE_BOUNDS = 3
"""The line's mean, the line's spread, and the Monte-Carlo's estimate of the tightening."""


def confidence_quantile(confidence: float) -> float:
    """z of each one-sided bound at `confidence` (module docstring): 2.13 at 0.95. 0 is the
    paper's eq. 16 and gives 0 (no allowance)."""
    if confidence == 0:
        return 0.0
    return statistics.NormalDist().inv_cdf(1 - (1 - confidence) / CONFIDENCE_BOUNDS)
