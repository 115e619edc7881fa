"""How well a set of held-out machines measures a spread: the observed σ's bootstrap interval.

The calibration ratio (predicted / observed σ of the slider, replay/heldout.py) is read against
0.8–1.25, but its denominator is itself an estimate from the machines drawn. Near top dead centre
the slider's spread is left-skewed and heavy-tailed (skew −0.7 to −1.05 at sample 100 of the
paper task), so 1000 machines measure its σ to several per cent, not the 2.2 % of a Gaussian:
the same five torques read 0.06–0.09 apart at sample 100 on two sets of 1000 (README, *The plan
round as a stage of the chain*). And a sweep checks every seed on the same machines, so that
error is common to all of its ratios. The interval here is a percentile bootstrap over the
machines (resampled with replacement, BOOTSTRAP_DRAWS times), which follows the tails as they
are.
"""

from __future__ import annotations

import numpy as np

BOOTSTRAP_DRAWS = 2000
"""Resamples of the machines per interval (the 2.5 % and 97.5 % points to ~0.5 % of σ)."""
LEVEL = 0.95


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


def ratio_interval(predicted: float, observed: tuple[float, float]) -> list[float] | None:
    """predicted / observed σ over the observed σ's interval (low ratio first); None where the
    observed spread can be zero."""
    low, high = observed
    if low <= 0:
        return None
    return [predicted / high, predicted / low]
