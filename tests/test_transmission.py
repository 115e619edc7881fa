"""Transmission error: the crank's angle to the motor recovered from the measured slider, drawn
by inverse CDF, and added to the Monte-Carlo's slider positions."""

from __future__ import annotations

import numpy as np
import pytest

from control.config import OCPConfig
from control.dynamics import CasadiPPANN
from control.lqr import LQRWeights, tracking_gains
from control.ocp import NominalOCP
from control.tightening import slider_uncertainty
from ppann.heads import FusedHeads
from ppann.model import constant_ppann
from ppann.transmission import (
    LEVELS,
    SLOPE_SHARE,
    draw,
    fit_quantiles,
    transmission_angles,
)
from tests.conftest import Written
from twin.geometry import PAPER


def test_angles_are_the_twins_backlash_angle(paper_dataset: Written) -> None:
    """On the twin's dataset, delta from motor angle and measured slider equals the simulated
    backlash angle (truth channel) on every sample away from the dead centres, to within what
    the MJCF's soft loop closure allows: its largest error (~4 um) over the smallest slope used
    (SLOPE_SHARE * l1 = 25 mm/rad), ~1.2e-4 rad."""
    data, truth = paper_dataset.dataset, paper_dataset.truth
    theta = data.theta
    slope = np.abs(
        (PAPER.slider_position(theta + 1e-6) - PAPER.slider_position(theta - 1e-6)) / 2e-6
    )
    usable = slope >= SLOPE_SHARE * PAPER.crank_length
    delta = transmission_angles(theta, data.slider_position, geometry=data.geometry)
    assert delta.shape == (int(usable.sum()),) and usable.mean() > 0.4
    bound = truth.loop_closure_error.max() / (SLOPE_SHARE * PAPER.crank_length)
    assert bound < 2e-4
    np.testing.assert_allclose(delta, truth.backlash_angle[usable], rtol=0, atol=bound)
    quantiles = fit_quantiles(theta, data.slider_position, geometry=data.geometry)
    assert quantiles[0] >= -0.013 - 1e-5 and quantiles[-1] <= 0.013 + 1e-5  # widest gap 0.026
    assert quantiles[75] - quantiles[25] > 0.005  # the crank does move in the gap


def test_draws_follow_the_stored_quantiles() -> None:
    quantiles = np.quantile(np.random.default_rng(0).normal(0.002, 0.006, 200_000), LEVELS)
    delta = draw(quantiles, (400, 500), np.random.default_rng(1))
    assert delta.shape == (400, 500)
    assert np.quantile(delta, [0.1, 0.5, 0.9]) == pytest.approx(
        np.interp([0.1, 0.5, 0.9], LEVELS, quantiles), abs=2e-4
    )
    assert np.array_equal(
        draw(np.zeros(len(LEVELS)), (3, 4), np.random.default_rng(1)), np.zeros((3, 4))
    )


def test_transmission_widens_the_monte_carlo_slider_spread_as_it_should() -> None:
    """A crank sitting +-5 mrad from the motor at random: at each constraint sample the slider's
    variance grows by about (dx/dtheta)^2 (5 mrad)^2 over the motor-angle Monte-Carlo's (the two
    are independent), to 10 %; with zero quantiles the tightening is unchanged bit for bit."""
    model = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))
    config = OCPConfig()  # closed loop below: a spread of the order of the effect
    solution = NominalOCP(model, config).solve()
    heads = FusedHeads(model)

    gains = tracking_gains(
        CasadiPPANN(model).step_on_turn,
        solution.states,
        solution.tau,
        LQRWeights.from_config(config),
    )
    bare = slider_uncertainty(heads, solution, config, gains=gains)
    heads.transmission = np.where(LEVELS < 0.5, -0.005, 0.005)
    heads.transmission[50] = 0.0
    shaken = slider_uncertainty(heads, solution, config, gains=gains)
    index = np.array(config.constraint_samples) - 1
    theta = solution.states[index, 0]
    slope = (PAPER.slider_position(theta + 1e-6) - PAPER.slider_position(theta - 1e-6)) / 2e-6
    expected = bare.std[index] ** 2 + (slope * 0.005) ** 2
    np.testing.assert_allclose(shaken.std[index] ** 2, expected, rtol=0.1)
    assert np.all(shaken.tightening > bare.tightening)
    heads.transmission = np.zeros(len(LEVELS))
    again = slider_uncertainty(heads, solution, config, gains=gains)
    assert np.array_equal(again.tightening, bare.tightening)
