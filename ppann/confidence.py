"""How the robust tightening's confidence is split (control/robust.py), in a module of its own so
that the OCP's configuration and the PPANN's report (which states the bounds the OCP will use)
share one rule without importing torch.

The training machines are a few draws of the line, and the Monte-Carlo estimates the tightening
from finitely many trajectories. Three one-sided bounds allow for that: on the line's mean, on
the line's spread, and on the Monte-Carlo's estimate. A confidence c is split evenly between
them (Bonferroni), each bound at 1 - (1 - c) / 3, so that all three hold together with
probability >= c.

The two bounds on the line are exact for M machines, not asymptotic (since session 79; before,
both took the normal z whatever M): the line's mean and spread are estimated from M machines'
offsets, and a normal quantile about a plug-in estimate holds only for many. For M machines
observed directly (normal offsets, the spread's estimate s the maximum-likelihood one, divisor
M, as phase 2's is):
- the line's mean sits within t_{M-1}(p) sqrt(M / (M - 1)) s / sqrt(M) of theirs with
  probability p (Student), so the mean's ellipsoid takes `mean_quantile`, not z: at 0.95, 2.82
  for 8 machines (z 2.13 missed 4.3 % of the time, not 1.7 %), 2.31 for 24, 2.14 for 310; one
  machine bounds nothing;
- the spread is below the value where the profile likelihood has risen by `spread_level`,
  the rise at which the exact chi-square bound sits, M s^2 / sigma^2 ~ chi2_{M-1}: 2.33 s for 8
  machines where the asymptotic z^2 / 2 gave 1.91 s (a 5.2 % miss, not 1.7 %).
With white noise in the runs the machines are seen less directly: the covariance of the mean
then holds a white share known to far more degrees of freedom than M - 1, and the Student factor
on it errs on the safe side; the spread's level is the directly observed case's, not derived for
the noisy one (`tests/test_small_sample.py` checks the exact case). Where the count is unknown
(`machines` 0: a checkpoint from before it was recorded) both take the normal z, as before.
Through phase 2's fit the levels hold where the machines ran alike and not for a few seen
unequally (bench/bound_coverage.md); ppann/inversion.py calibrates both by simulation instead for
a line of 2-32 machines (`TrainConfig.bound_lines`), and falls back to these outside its tails."""

from __future__ import annotations

import math
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


def bound_level(confidence: float) -> float:
    """The one-sided level of each bound: 1 - (1 - c) / 3."""
    return 1 - (1 - confidence) / CONFIDENCE_BOUNDS


def mean_quantile(confidence: float, machines: int) -> float:
    """The radius, in standard errors of the line's mean, of its bound from `machines` machines
    (module docstring): t_{M-1} sqrt(M / (M - 1)); the normal z for `machines` 0 (unknown); 0 at
    confidence 0.

    Raises:
      ValueError: one machine, at a confidence above 0 (it tells nothing of the line's mean).
    """
    if confidence == 0:
        return 0.0
    if machines == 0:
        return confidence_quantile(confidence)
    if machines < 2:
        raise ValueError(one_machine(confidence))
    from scipy.stats import t

    return float(t.ppf(bound_level(confidence), machines - 1)) * (machines / (machines - 1)) ** 0.5


def spread_level(confidence: float, machines: int) -> float:
    """The rise of the profile negative log-likelihood at which the spread's upper bound from
    `machines` machines sits (module docstring): (M / 2) (u - 1 - log u), u = chi2_{M-1}(1 - p) / M,
    the rise where sigma = s / sqrt(u); z^2 / 2 for `machines` 0 (unknown); 0 at confidence 0.

    Raises:
      ValueError: one machine, at a confidence above 0.
    """
    if confidence == 0:
        return 0.0
    if machines == 0:
        return 0.5 * confidence_quantile(confidence) ** 2
    if machines < 2:
        raise ValueError(one_machine(confidence))
    from scipy.stats import chi2

    u = float(chi2.ppf(1 - bound_level(confidence), machines - 1)) / machines
    return 0.5 * machines * (u - 1 - math.log(u))


def one_machine(confidence: float) -> str:
    """Why a model learnt from one machine has no bound on the line at `confidence`."""
    return (
        f"the model's spread was learnt from one machine: it bounds nothing about the line at "
        f"confidence {confidence:g} (train on runs of two or more machines, or --confidence 0 "
        "for eq. 16 on the model's own spread)"
    )
