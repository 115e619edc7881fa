"""The line's bounds from M machines (ppann/confidence.py mean_quantile, spread_level): exact for
M directly observed normal machines, where the normal z about plug-in estimates was not; the
machine count travels from phase 2 through the checkpoint to the robust OCP's allowances."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.stats import chi2

from control.config import OCPConfig
from control.ocp import NominalOCP
from control.records import RobustError
from control.tightening import (
    line_allowance,
    mean_allowance_quantile,
    population_margin,
    slider_uncertainty,
)
from ppann import checkpoint
from ppann.confidence import confidence_quantile, mean_quantile, spread_level
from ppann.heads import FusedHeads
from ppann.machine import sigma_upper
from tests.test_tightening import _line_model

MISS = 0.05 / 3
"""One bound's miss probability at confidence 0.95 (three bounds, Bonferroni)."""
DRAWS = 200_000


def _machines(m: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """DRAWS lines' M unit-normal machine offsets: their mean and maximum-likelihood spread."""
    x = np.random.default_rng(seed).standard_normal((DRAWS, m))
    return x.mean(axis=1), x.std(axis=1)  # ddof 0, as phase 2's estimate


@pytest.mark.parametrize("m", [3, 8, 24])
def test_the_line_means_bound_misses_as_often_as_it_says(m: int) -> None:
    """x̄ + q s_ML / sqrt(M) is below the true mean (0) on 1/60 of lines at q = mean_quantile,
    within 4 standard errors of the count; the normal z about the same plug-in missed 2.6x as
    often with 8 machines."""
    mean, s = _machines(m, seed=m)
    q = mean_quantile(0.95, m)
    missed = np.mean(mean + q * s / math.sqrt(m) < 0.0)
    se = math.sqrt(MISS * (1 - MISS) / DRAWS)
    assert abs(missed - MISS) < 4 * se, (missed, MISS)
    plug_in = np.mean(mean + confidence_quantile(0.95) * s / math.sqrt(m) < 0.0)
    assert plug_in > missed + 8 * se
    if m == 8:
        assert plug_in == pytest.approx(0.0434, abs=0.002)  # P(t_7 > z sqrt(7/8))


@pytest.mark.parametrize("m", [3, 8, 24])
def test_the_spreads_bound_misses_as_often_as_it_says(m: int) -> None:
    """The likelihood-ratio bound at spread_level (the profile rise (M/2)(u - 1 - log u) of M
    directly observed machines, u = s_ML² / σ²) is below the true σ (1) on 1/60 of lines; at
    z²/2 it was below 3x as often with 8 machines. sigma_upper reads the same bound off that
    profile on its grid (to its interpolation, 3 %)."""
    _, s = _machines(m, seed=100 + m)

    def bound(level: float) -> np.ndarray:  # the root u < 1 of the rise, by bisection
        lo, hi = np.full(DRAWS, 1e-9), np.ones(DRAWS)
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            high = 0.5 * m * (mid - 1 - np.log(mid)) > level
            lo, hi = np.where(high, mid, lo), np.where(high, hi, mid)
        return s / np.sqrt(hi)

    level = spread_level(0.95, m)
    missed = np.mean(bound(level) < 1.0)
    se = math.sqrt(MISS * (1 - MISS) / DRAWS)
    assert abs(missed - MISS) < 4 * se, (missed, MISS)
    asymptotic = np.mean(bound(0.5 * confidence_quantile(0.95) ** 2) < 1.0)
    assert asymptotic > missed + 8 * se
    if m == 8:
        assert asymptotic == pytest.approx(0.052, abs=0.003)
    # sigma_upper on the closed-form profile of one line (s = 0.05) finds the same root
    from ppann.model import PROFILE_GRID

    u = chi2.ppf(MISS, m - 1) / m
    rise = m * (np.log(PROFILE_GRID / 0.05) + 0.05**2 / (2 * PROFILE_GRID**2) - 0.5)
    upper = sigma_upper(np.array([0.05]), rise[None, :], level)[0]
    assert upper == pytest.approx(0.05 / math.sqrt(u), rel=0.03)


def test_many_machines_or_an_unknown_count_take_the_normal_z() -> None:
    z = confidence_quantile(0.95)
    assert mean_quantile(0.95, 0) == z and spread_level(0.95, 0) == 0.5 * z * z
    assert mean_quantile(0.95, 10**6) == pytest.approx(z, rel=1e-4)
    assert spread_level(0.95, 10**6) == pytest.approx(0.5 * z * z, rel=1e-2)
    assert mean_quantile(0.0, 8) == 0.0 and spread_level(0.0, 1) == 0.0
    with pytest.raises(ValueError, match="learnt from one machine"):
        mean_quantile(0.95, 1)


def _counted(machines: int) -> FusedHeads:
    model = _line_model()  # 9 machines' closed-form profile; the count the checkpoint says
    with torch.no_grad():
        model.spread_machines.fill_(machines)
    return FusedHeads(model)


def test_the_robust_ocp_allows_for_the_machines_it_learnt_from() -> None:
    """The same line summaries read as 9 machines give wider allowances than with no count
    (the normal z, a checkpoint from before): the Monte-Carlo's spread from spread_level, the
    mean's drop at mean_quantile; one machine is refused with the reason, unless confidence 0."""
    config = OCPConfig(confidence=0.95)
    solution = NominalOCP(_line_model(), config).solve()
    unknown, nine = _counted(0), _counted(9)
    assert np.all(mean_allowance_quantile(unknown, config) == confidence_quantile(0.95))
    assert mean_allowance_quantile(nine, config) == pytest.approx([mean_quantile(0.95, 9)] * 3)
    wide, _ = line_allowance(nine, config)
    plain, _ = line_allowance(unknown, config)
    assert np.all(wide > 1.05 * plain)
    unc = slider_uncertainty(nine, solution, config)
    expected = population_margin(nine, solution, config, mean_quantile(0.95, 9))
    assert np.array_equal(unc.population, expected)
    assert np.all(unc.population > 1.1 * slider_uncertainty(unknown, solution, config).population)
    with pytest.raises(RobustError, match="learnt from one machine: it bounds nothing"):
        slider_uncertainty(_counted(1), solution, config)
    alone = slider_uncertainty(_counted(1), solution, OCPConfig(confidence=0.0))
    assert not np.any(alone.population)


def test_a_checkpoint_keeps_the_count_and_an_older_one_reads_as_unknown(tmp_path) -> None:
    model = _line_model()
    with torch.no_grad():
        model.spread_machines.fill_(8)
    path = tmp_path / "m.pt"
    checkpoint.save(path, model, kind="ppann", extra={})
    loaded, payload = checkpoint.load(path)
    assert FusedHeads(loaded).spread_machines == 8
    del payload["state_dict"]["spread_machines"]  # as written before session 79
    torch.save(payload, tmp_path / "old.pt")
    old, _ = checkpoint.load(tmp_path / "old.pt")
    assert FusedHeads(old).spread_machines == 0
    assert torch.equal(old.machine_profile, model.machine_profile)
