"""The observed spread's bootstrap interval (replay/spread_interval.py): it covers a known σ as
often as it says, its width is the standard error's of a Gaussian sample, wider by the known
factor on a heavy-tailed one, and the same generator gives the same interval."""

from __future__ import annotations

import numpy as np
import pytest

from replay.spread_interval import ratio_interval, sigma_interval

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
    assert ratio_interval(2.0, (0.5, 1.0)) == [2.0, 4.0]
    assert ratio_interval(2.0, (0.0, 1.0)) is None
    with pytest.raises(ValueError, match="two or more"):
        sigma_interval(np.array([1.0]), rng=np.random.default_rng(0))
