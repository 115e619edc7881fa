"""Tightening of the robust constraint: gaussian k·σ and the empirical quantile, their standard
errors against known distributions, and the sample counts the config chooses."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import stats

from control.ocp import NominalOCP, OCPConfig, OCPConfigError, lower_tail
from control.robust import slider_uncertainty, tightening
from ppann.model import FusedHeads, constant_ppann
from replay.heldout import rate_upper

PLAN = 0.095


def _skewed(rng: np.random.Generator, size) -> np.ndarray:
    """Slider positions plan − Gamma(shape 4, scale 2 mm): left-skewed like the twin's near TDC."""
    return PLAN - rng.gamma(4.0, 2e-3, size)


def test_quantile_tightening_gives_the_known_quantile_within_its_standard_error() -> None:
    p = lower_tail(3.0)
    exact = float(stats.gamma.ppf(1 - p, 4.0, scale=2e-3))  # plan − Q_p of the slider
    rng = np.random.default_rng(0)
    n = OCPConfig(tightening="quantile").mc_samples
    estimates, errors = [], []
    for _ in range(200):
        margin, se = tightening(_skewed(rng, n), PLAN, k_sigma=3.0, method="quantile")
        estimates.append(margin)
        errors.append(se)
    estimates = np.array(estimates)
    # One draw is within 2 standard errors of the known answer ...
    assert abs(estimates[0] - exact) < 2 * errors[0]
    # ... the estimator is unbiased to well inside its standard error, and the standard error
    # it reports is the spread the estimates really have (within 25 %).
    assert abs(estimates.mean() - exact) < 0.25 * np.mean(errors)
    assert np.mean(errors) == pytest.approx(estimates.std(ddof=1), rel=0.25)
    # Gaussian 3σ of this skewed law falls short of the quantile: the reason for the option.
    gaussian = tightening(_skewed(rng, n), PLAN, k_sigma=3.0, method="gaussian")[0]
    assert gaussian < exact - 2 * np.mean(errors)


def test_gaussian_tightening_and_its_standard_error() -> None:
    rng = np.random.default_rng(1)
    values = [
        tightening(rng.normal(PLAN, 4e-3, 1000), PLAN, k_sigma=3.0, method="gaussian")
        for _ in range(300)
    ]
    margins, errors = np.array([m for m, _ in values]), np.array([s for _, s in values])
    assert margins.mean() == pytest.approx(12e-3, rel=0.01)
    assert errors.mean() == pytest.approx(margins.std(ddof=1), rel=0.15)


def test_sample_counts_follow_the_tightening() -> None:
    assert OCPConfig().mc_samples == 1000
    assert OCPConfig().mc_mode == "mixed"
    q = OCPConfig(tightening="quantile")
    assert q.mc_samples == math.ceil(20 / lower_tail(3.0))
    assert OCPConfig(tightening="quantile", k_sigma=2.5758).mc_samples == math.ceil(
        20 / lower_tail(2.5758)
    )
    with pytest.raises(OCPConfigError, match="needs >= 14816 Monte-Carlo samples"):
        OCPConfig(tightening="quantile", mc_samples=1000)
    with pytest.raises(OCPConfigError, match="tightening must be one of"):
        OCPConfig(tightening="median")
    with pytest.raises(OCPConfigError, match="Monte-Carlo mode must be one of"):
        OCPConfig(mc_mode="sometimes")
    with pytest.raises(OCPConfigError, match="mc_samples must be an integer"):
        OCPConfig(mc_samples=10**8)


def test_clopper_pearson_bounds() -> None:
    # 0 of 1000: the exact 95 % one-sided bound is 1 − 0.05^(1/1000) = 0.299 %.
    assert rate_upper(0, 1000) == pytest.approx(1 - 0.05 ** (1 / 1000), rel=1e-9)
    assert rate_upper(1000, 1000) == 1.0
    assert rate_upper(5, 1000) > 0.005


def test_draft_monte_carlo_up_to_the_last_constraint_gives_the_same_tightening() -> None:
    """The robust loop's drafts simulate only up to the last constraint sample: every draw is a
    prefix of the full run's, so the tightening is the same to the last bit."""
    model = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))
    with torch.no_grad():
        model.machine_sigma.copy_(torch.tensor([0.05, 0.04, 0.03], dtype=torch.float64))
    config = OCPConfig()
    solution = NominalOCP(model, config).solve()
    heads = FusedHeads(model)
    full = slider_uncertainty(heads, solution, config)
    short = slider_uncertainty(heads, solution, config, constraints_only=True)
    assert np.array_equal(full.tightening, short.tightening)
    assert np.array_equal(full.tightening_se, short.tightening_se)
    assert len(short.std) == max(config.constraint_samples) < len(full.std)
