"""Where a held-out machine sits in its line (replay/placement.py): exact places in the ranges,
the mean force's standard error, the words."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from replay.placement import in_words, placement
from twin.variability import MachineDraw, Variability

PAPER = Variability.scenario("paper")


def _draw(**values: float) -> MachineDraw:
    return replace(PAPER.nominal(), **values)


def test_places_in_the_ranges_are_exact() -> None:
    """Low end 0, high end 1, the nominal of a symmetric range 0.5, warmup_drop's nominal 0.025
    in [0.01, 0.04] 0.5; a parameter without spread has no place."""
    machine = _draw(motor_frictionloss=0.0285, motor_damping=0.084, slider_damping=7.8)
    placed = placement(machine, PAPER, force=np.zeros(10), start_s=30.0, max_start_s=60.0)
    where = placed["range_position"]
    assert where["motor_frictionloss"] == pytest.approx(0.0, abs=1e-12)
    assert where["motor_damping"] == pytest.approx(1.0, abs=1e-12)
    assert where["slider_damping"] == pytest.approx(0.25, abs=1e-12)
    assert where["slider_frictionloss"] == pytest.approx(0.5, abs=1e-12)
    assert where["warmup_drop"] == pytest.approx(0.5, abs=1e-12)
    assert placed["start_share"] == 0.5
    fixed = replace(PAPER, backlash_width=PAPER.backlash_width.fixed())
    assert (
        placement(machine, fixed, force=np.zeros(10), start_s=0.0, max_start_s=60.0)[
            "range_position"
        ]["backlash_width"]
        is None
    )


def test_the_mean_force_in_standard_errors() -> None:
    """A constant +3 N over 100 samples: its mean 3 N, 3 / (30 / sqrt(300)) = sqrt(3) standard
    errors; the line's own forces give z with mean 0 and standard deviation 1 (4000 machines:
    within 0.05 of each, ~3 standard errors)."""
    placed = placement(_draw(), PAPER, force=np.full(100, 3.0), start_s=0.0, max_start_s=60.0)
    assert placed["force_mean_N"] == pytest.approx(3.0)
    assert placed["force_mean_z"] == pytest.approx(math.sqrt(3.0))
    rng = np.random.default_rng(5)
    z = np.array(
        [
            placement(
                _draw(), PAPER, force=PAPER.disturbance(rng, 100), start_s=0.0, max_start_s=60.0
            )["force_mean_z"]
            for _ in range(4000)
        ]
    )
    assert abs(z.mean()) < 0.05 and abs(z.std() - 1.0) < 0.05
    calm = replace(PAPER, disturbance_amplitude=0.0)
    assert (
        placement(_draw(), calm, force=np.zeros(5), start_s=0.0, max_start_s=1.0)["force_mean_z"]
        is None
    )


def test_words_name_the_extremes_only() -> None:
    """Within 10 % of an end of its range a parameter is named, a start in the last tenth is
    warm, a mean force beyond two standard errors gets them; the middle goes unsaid."""
    machine = _draw(motor_frictionloss=0.0286, slider_frictionloss=1.574)
    force = np.full(100, 5.7)
    said = in_words(placement(machine, PAPER, force=force, start_s=58.0, max_start_s=60.0))
    assert said == (
        "motor_frictionloss at 3 % of its range, slider_frictionloss at 99 % of its range, "
        "warm (58.0 s run), mean slider force +5.7 N (+3.3 standard errors)"
    )
    middle = in_words(placement(_draw(), PAPER, force=np.zeros(100), start_s=30, max_start_s=60))
    assert middle == "mean slider force +0.0 N"
