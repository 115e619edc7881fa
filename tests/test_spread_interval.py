"""The observed spread's bootstrap interval (replay/spread_interval.py): it covers a known σ as
often as it says, its width is the standard error's of a Gaussian sample, wider by the known
factor on a heavy-tailed one, and the same generator gives the same interval; the Monte-Carlo's
own standard error of σ is the spread of σ over repeated draws, and widens the ratio's interval
as two independent errors do."""

from __future__ import annotations

import numpy as np
import pytest

from control.tightening import sigma_relative_se
from replay.spread_interval import Z_LEVEL, ratio_interval, sigma_interval

N = 1000


def test_the_interval_covers_a_known_sigma_95_times_in_100() -> None:
    rng = np.random.default_rng(3)
    repeats, covered = 200, 0
    for _ in range(repeats):
        x = rng.normal(0.0, 2.0, N)
        low, high = sigma_interval(x, rng=rng, draws=1000)
        covered += low <= 2.0 <= high
    # 200 intervals at 95 %: 190 expected, standard deviation 3.1
    assert 180 <= covered <= 198


def test_the_width_is_the_standard_error_of_sigma_gaussian_or_heavy_tailed() -> None:
    rng = np.random.default_rng(4)
    widths = {"normal": [], "t5": []}
    for _ in range(20):
        for name, x in (("normal", rng.normal(size=N)), ("t5", rng.standard_t(5, size=N))):
            low, high = sigma_interval(x, rng=rng)
            widths[name].append((high - low) / x.std(ddof=1))
    # se(s)/s = sqrt((kurtosis - 1) / (4 n)): 2.24 % for a Gaussian (kurtosis 3); Student's t
    # with 5 degrees of freedom has kurtosis 9 (in the population; a sample of 1000 shows less)
    gaussian = 2 * 1.96 * np.sqrt(2 / (4 * N))
    assert np.mean(widths["normal"]) == pytest.approx(gaussian, rel=0.08)
    assert 1.4 < np.mean(widths["t5"]) / np.mean(widths["normal"]) < 2.1  # sqrt(8/2) = 2


def test_the_same_generator_gives_the_same_interval_and_ratios_invert_it() -> None:
    x = np.random.default_rng(5).normal(size=300)
    first = sigma_interval(x, rng=np.random.default_rng(9))
    assert first == sigma_interval(x, rng=np.random.default_rng(9))
    assert first != sigma_interval(x, rng=np.random.default_rng(10))
    assert ratio_interval(2.0, 0.7, (0.5, 1.0)) == pytest.approx([2.0, 4.0], rel=1e-15)
    assert ratio_interval(2.0, 0.7, (0.0, 1.0)) is None
    assert ratio_interval(float("nan"), 0.7, (0.5, 1.0), predicted_relative_se=0.01) is None
    with pytest.raises(ValueError, match="two or more"):
        sigma_interval(np.array([1.0]), rng=np.random.default_rng(0))


@pytest.mark.parametrize(("name", "kurtosis"), [("normal", 3.0), ("t9", 3 + 6 / 5)])
def test_the_monte_carlos_standard_error_is_the_spread_of_sigma_over_draws(
    name: str, kurtosis: float
) -> None:
    """sigma_relative_se (control/tightening.py) of one draw of n values against the standard
    deviation of σ over 400 draws (the truth it estimates), and against the closed form
    sqrt((kurtosis - 1) / (4 n))."""
    rng = np.random.default_rng(11)
    n = 4000

    def sample() -> np.ndarray:
        return rng.normal(size=n) if name == "normal" else rng.standard_t(9, size=n)

    sigmas = np.array([sample().std(ddof=1) for _ in range(400)])
    spread = sigmas.std(ddof=1) / sigmas.mean()  # itself known to ~3.5 % from 400 draws
    estimates = [sigma_relative_se(sample()) for _ in range(20)]
    assert np.mean(estimates) == pytest.approx(spread, rel=0.12)
    assert np.mean(estimates) == pytest.approx(np.sqrt((kurtosis - 1) / (4 * n)), rel=0.1)
    assert sigma_relative_se(np.array([1.0, np.inf])) == np.inf
    assert sigma_relative_se(np.full(5, 2.0)) == 0.0


def test_the_ratios_interval_adds_the_monte_carlos_error_in_log_space() -> None:
    """Without a Monte-Carlo error the ratio's interval is the prediction over the machines'
    interval; with one, each side's log half-width is the two in quadrature, so an interval as
    wide as the machines' own grows by sqrt(2) in log terms, and the ratio stays inside."""
    observed, interval = 2.0, (1.8, 2.25)
    low, high = ratio_interval(2.4, observed, interval, predicted_relative_se=0.0)
    assert (low, high) == pytest.approx((2.4 / 2.25, 2.4 / 1.8), rel=1e-12)
    se = np.log(2.25 / 2.0) / Z_LEVEL  # the Monte-Carlo as uncertain as the machines' high side
    low2, high2 = ratio_interval(2.4, observed, interval, predicted_relative_se=se)
    ratio = 2.4 / observed
    assert np.log(ratio / low2) == pytest.approx(np.sqrt(2) * np.log(ratio / low), rel=1e-12)
    assert np.log(high2 / ratio) == pytest.approx(
        np.hypot(np.log(high / ratio), np.log(2.25 / 2.0)), rel=1e-12
    )
    assert low2 < low < ratio < high < high2
