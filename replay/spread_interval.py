"""How well a set of held-out machines measures a spread: the observed σ's bootstrap interval.

The calibration ratio (predicted / observed σ of the slider, replay/heldout.py) is read against
0.8–1.25, but its denominator is itself an estimate from the machines drawn. Near top dead centre
the slider's spread is left-skewed and heavy-tailed (skew −0.7 to −1.05 at sample 100 of the
paper task), so 1000 machines measure its σ to several per cent, not the 2.2 % of a Gaussian:
the same five torques read 0.06–0.09 apart at sample 100 on two sets of 1000 (docs/history.md, *The
plan round as a stage of the chain*). And a sweep checks every seed on the same machines, so that
error is common to all of its ratios. The interval here is a percentile bootstrap over the
machines (resampled with replacement, BOOTSTRAP_DRAWS times), which follows the tails as they
are.

The numerator is an estimate too: the model's σ from a finite Monte-Carlo. With the OCP's 1000
trajectories it moved single ratios by up to 0.06 (seed 1 of session 23's plan-round sweep, sample
50: 1.30 from the shared stream's 1000 trajectories, 1.24 and 1.25 from two sets of 10 000), and
a sweep's models share that stream, so the error is common to its seeds as well. The held-out
check therefore predicts from CALIBRATION_TRAJECTORIES, and `ratio_interval` widens the
machines' interval by the Monte-Carlo's standard error (control/tightening.py
`sigma_relative_se`, the tightening's own), the two independent, in log space.
"""

from __future__ import annotations

import math
import statistics

import numpy as np

BOOTSTRAP_DRAWS = 2000
"""Resamples of the machines per interval (the 2.5 % and 97.5 % points to ~0.5 % of σ)."""
LEVEL = 0.95
Z_LEVEL = statistics.NormalDist().inv_cdf(0.5 + LEVEL / 2)
"""The standard normal's two-sided LEVEL point (1.96)."""
CALIBRATION_TRAJECTORIES = 10_000
"""Monte-Carlo trajectories of each predicted σ in the held-out check: σ to ~0.7 % (Gaussian),
~0.2 s per mode with the compiled rollout."""


def sigma_interval(
    x: np.ndarray, *, rng: np.random.Generator, draws: int = BOOTSTRAP_DRAWS, level: float = LEVEL
) -> tuple[float, float]:
    """The two-sided `level` percentile-bootstrap interval of the standard deviation (ddof 1)
    of the values `x` (one per machine)."""
    x = np.asarray(x, dtype=float)
    if x.ndim != 1 or len(x) < 2:
        raise ValueError("a spread's interval needs a 1-d sample of two or more values")
    n = len(x)
    sigmas = np.empty(draws)
    for start in range(0, draws, 250):  # 250 resamples at a time: 2 MB at n = 1000
        rows = rng.integers(0, n, (min(250, draws - start), n))
        sigmas[start : start + len(rows)] = x[rows].std(axis=1, ddof=1)
    tail = (1 - level) / 2
    low, high = np.quantile(sigmas, [tail, 1 - tail])
    return float(low), float(high)


def ratio_interval(
    predicted: float,
    observed: float,
    interval: tuple[float, float],
    *,
    predicted_relative_se: float = 0.0,
) -> list[float] | None:
    """The `LEVEL` interval of predicted / observed σ (low ratio first): the observed σ's
    `interval` around `observed`, each side widened in log space by the predicted σ's own
    standard error (`predicted_relative_se`, relative; the two independent). With none it is
    predicted over the interval's ends. None where the observed spread can be zero or the
    prediction is not finite."""
    low, high = interval
    if low <= 0 or observed <= 0 or not math.isfinite(predicted * predicted_relative_se):
        return None
    ratio = predicted / observed
    own = Z_LEVEL * predicted_relative_se
    down = math.hypot(math.log(high / observed), own)
    up = math.hypot(math.log(observed / low), own)
    return [ratio * math.exp(-down), ratio * math.exp(up)]
