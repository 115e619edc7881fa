"""The line's bounds calibrated by simulation (ppann/inversion.py): its fast likelihood is phase
2's, its simulated laws are the exact ones where those are known (machines seen directly), the
test is inverted where the observed rise meets the simulated quantile, and without a
calibration (or outside its tails) the exact levels stand."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ppann.confidence import mean_quantile, spread_level
from ppann.inversion import (
    Calibration,
    adam_fit,
    calibrate,
    calibrated_radius,
    calibrated_upper,
    calibration_epochs,
    line_bounds,
    line_nll,
    profile_rises,
    simulate,
)
from ppann.machine import EpisodeTerms, machine_sums, marginal_nll, sigma_upper
from ppann.model import PROFILE_GRID, RISE_GRID, TAIL_GRID

TAIL = (1 - 0.95) / 3  # each of the three bounds at confidence 0.95


def _terms(counts: list[int], seed: int) -> EpisodeTerms:
    """Machines of `counts` one-sample blocks, a random design and residual, white variance 1."""
    rng = np.random.default_rng(seed)
    n = sum(counts)
    derivative = torch.zeros((n, 3), dtype=torch.float64)
    derivative[:, 0] = 1.0
    return EpisodeTerms(
        residual=torch.from_numpy(rng.standard_normal(n) * 0.5),
        design=torch.from_numpy(rng.standard_normal((n, 3)) * np.array([1.0, 0.7, 1.3])),
        derivative=derivative,
        block=torch.arange(n),
        machine=torch.repeat_interleave(torch.arange(len(counts)), torch.tensor(counts)),
        n_machines=len(counts),
    )


def test_fast_likelihood_is_phase_two_marginal_likelihood() -> None:
    """line_nll on the machines' sufficient statistics (the adjugate, elementwise) moves with the
    parameters exactly as ppann/machine.py's marginal_nll on the samples does (it drops only
    what does not depend on them), for machines of unequal runs."""
    terms = _terms([3, 40, 7, 12], seed=1)
    sigma = torch.ones((terms.residual.shape[0], 3), dtype=torch.float64)
    variance = terms.white_variance(sigma)
    info, b = machine_sums(terms.residual, terms.design, variance, terms.machine, 4)
    n = terms.residual.shape[0]
    rng = np.random.default_rng(2)
    settings = [
        (torch.from_numpy(rng.uniform(-4, 0.5, 3)), torch.from_numpy(rng.normal(0, 0.3, 3)))
        for _ in range(6)
    ]
    slow = [float(n * marginal_nll(terms.shifted(c), sigma, s.exp())) for s, c in settings]
    fast = [float(line_nll(info, b[None], s[None], c[None])[0]) for s, c in settings]
    assert np.allclose(np.diff(fast), np.diff(slow), rtol=1e-10, atol=1e-9)


def test_simulated_laws_are_the_exact_ones_for_machines_seen_directly() -> None:
    """Eight machines whose runs show their log-factors to 1e-3 of the spread: the one-sided
    rise at the truth has the exact law of ppann/confidence.py (the chi-square bound's level,
    whatever the candidate: the statistic is pivotal), and the mean's pivot Student's t, so the
    calibrated quantiles at each bound's tail are spread_level and mean_quantile for 8 machines,
    within the simulation's error (600 lines a candidate; the 12 candidates' levels averaged)."""
    info = torch.eye(3, dtype=torch.float64).expand(8, 3, 3) * 1e6 / 0.02**2
    truth = torch.tensor([[0.02, 0.03, 0.015]], dtype=torch.float64)
    rng = np.random.default_rng(3)
    b = simulate(info, truth, torch.zeros((1, 3), dtype=torch.float64), rng)
    log_s, c = adam_fit(info, b, epochs=400, lr=0.02, start=0.05)
    profile = profile_rises(info, b, log_s, c)[0].numpy()
    epochs: list[int] = []  # what `calibrate` reports, against its bar's length
    found = calibrate(
        info,
        log_s[0].exp(),
        c[0],
        profile,
        epochs=400,
        lr=0.02,
        start=0.05,
        rng=rng,
        lines=600,
        on_epoch=lambda epoch, loss: epochs.append(epoch),
    )
    assert np.allclose(found.candidates[:, 0], log_s[0].exp().numpy())
    assert epochs == list(range(calibration_epochs(400, lines=600)))

    def at_tail(table: np.ndarray) -> np.ndarray:  # read at TAIL, in log tail as line_bounds
        return np.apply_along_axis(
            lambda row: np.interp(np.log(TAIL), np.log(TAIL_GRID[::-1]), row[::-1]), -1, table
        )

    levels = at_tail(found.rise_tail).mean(1)  # the estimate's and the 11 candidates' alike
    radius = at_tail(found.mean_tail)  # (candidates, 3)
    exact_level = spread_level(0.95, 8)
    print("levels", levels, "exact", exact_level, "radius", radius.mean(0))
    assert levels == pytest.approx([exact_level] * 3, rel=0.1)
    assert radius.mean(0) == pytest.approx([mean_quantile(0.95, 8)] * 3, rel=0.1)


def _profile(estimate: float) -> np.ndarray:
    """A profile rising as 30 (log(s / estimate))^2 above the estimate, one row per component."""
    rise = np.where(estimate < PROFILE_GRID, 30 * np.log(PROFILE_GRID / estimate) ** 2, 0.0)
    return np.tile(rise, (3, 1))


def test_test_inversion_at_a_constant_level_is_the_likelihood_ratio_bound() -> None:
    """Candidates on the profile's grid and a simulated quantile the same at every candidate:
    the inverted test is sigma_upper at that level, to the last interpolation."""
    estimate = PROFILE_GRID[30]
    profile = _profile(estimate)
    candidates = np.tile(PROFILE_GRID[30 : 30 + len(RISE_GRID)], (3, 1))
    for level in (0.7, 2.3, 3.51):
        rise_tail = np.full((3, len(RISE_GRID), len(TAIL_GRID)), level)
        rise_tail[:, 0] = 0.0
        upper = calibrated_upper(profile, candidates, rise_tail, TAIL)
        expected = sigma_upper(np.full(3, estimate), profile, level)
        assert upper == pytest.approx(expected, rel=1e-12)
    rise_tail = np.full((3, len(RISE_GRID), len(TAIL_GRID)), 1e3)  # nothing rejected
    upper = calibrated_upper(profile, candidates, rise_tail, TAIL)
    assert np.all(upper == PROFILE_GRID[-1])
    # a rejection just above the estimate, none after it until the level's own crossing: the
    # bound is the largest spread not rejected, not the first rejection
    rise_tail = np.full((3, len(RISE_GRID), len(TAIL_GRID)), 2.3)
    rise_tail[:, 0], rise_tail[:, 1] = 0.0, 1e-3
    upper = calibrated_upper(profile, candidates, rise_tail, TAIL)
    assert upper == pytest.approx(sigma_upper(np.full(3, estimate), profile, 2.3), rel=1e-12)
    # not interpolated: the first candidate rejected after the last one not rejected, itself
    step = calibrated_upper(profile, candidates, rise_tail, TAIL, interpolate=False)
    observed = 30 * np.log(candidates[0] / estimate) ** 2
    first = candidates[0, np.flatnonzero(observed > 2.3)[0]]
    assert np.all(step == first) and np.all(step > upper)


def test_mean_radius_is_the_largest_over_the_spreads_left_open() -> None:
    """Each component's radius is its largest quantile over the joint candidates up to the
    first that covers the spread's bound; beyond the last candidate (or outside the tails)
    there is none."""
    candidates = np.tile(np.geomspace(0.01, 0.1, len(RISE_GRID)), (3, 1))
    rise = np.linspace(2.0, 3.0, len(RISE_GRID))[:, None, None]
    mean_tail = np.tile(rise * np.array([1.0, 1.5, 0.5])[:, None], (1, 1, len(TAIL_GRID)))
    mean_tail[2, 0] = 9.0  # not monotone: the third candidate's J is the largest
    upper = np.array([0.011, candidates[0, 4] * 0.99, 0.01])  # covered by the fifth
    radius = calibrated_radius(mean_tail, candidates, upper, TAIL)
    assert radius == pytest.approx([9.0, 1.5 * rise[4, 0, 0], 0.5 * rise[4, 0, 0]])
    assert calibrated_radius(mean_tail, candidates, np.full(3, 0.2), TAIL) is None
    assert calibrated_radius(mean_tail, candidates, upper, 1e-4) is None


def test_without_a_calibration_the_exact_levels_stand() -> None:
    """line_bounds: no calibration, or a confidence whose tail is beyond the simulated ones,
    gives the exact levels; confidence 0 the estimate and no radius."""
    estimate = PROFILE_GRID[30]
    sigma, profile = np.full(3, estimate), _profile(estimate)
    exact = (sigma_upper(sigma, profile, spread_level(0.95, 6)), mean_quantile(0.95, 6))
    upper, radius, calibrated = line_bounds(
        machine_sigma=sigma, profile=profile, machines=6, confidence=0.95, calibration=None
    )
    assert np.array_equal(upper, exact[0]) and np.all(radius == exact[1]) and not calibrated
    candidates = np.tile(PROFILE_GRID[30 : 30 + len(RISE_GRID)], (3, 1))
    some = Calibration(
        candidates,
        np.full((3, len(RISE_GRID), len(TAIL_GRID)), 1.0),
        np.full((len(RISE_GRID), 3, len(TAIL_GRID)), 2.0),
    )
    options = {"machine_sigma": sigma, "profile": profile, "machines": 6, "calibration": some}
    upper, radius, calibrated = line_bounds(confidence=0.95, **options)
    assert calibrated and np.all(radius == 2.0)
    assert upper == pytest.approx(sigma_upper(sigma, profile, 1.0))
    upper, radius, calibrated = line_bounds(confidence=0.9999, **options)
    assert not calibrated and np.all(radius == mean_quantile(0.9999, 6))
    assert np.array_equal(upper, sigma_upper(sigma, profile, spread_level(0.9999, 6)))
    upper, radius, calibrated = line_bounds(confidence=0.0, **options)
    assert np.array_equal(upper, sigma) and not radius.any() and not calibrated
