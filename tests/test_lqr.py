"""Feedback from the model: the PPANN's linearisation and the Riccati gains against exact
answers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import solve_discrete_are

from control.config import OCPConfig, OCPConfigError
from control.dynamics import CasadiPPANN
from control.lqr import LQRWeights, linearise, riccati_gains
from control.robust import solve_robust
from control.tightening import slider_uncertainty
from ppann.heads import FusedHeads
from ppann.model import constant_ppann
from ppann.montecarlo import Feedback, monte_carlo


def test_linearisation_equals_finite_differences_of_the_step() -> None:
    model = constant_ppann(z_mean=(0.1, -0.2, -0.9), z_sigma=(0.03, 0.05, 0.05))
    dynamics = CasadiPPANN(model)
    rng = np.random.default_rng(0)
    states = np.stack([rng.uniform(0.5, 12.0, 6), rng.uniform(-30, 30, 6)], axis=-1)
    tau = rng.uniform(-5, 5, 6)
    a, b = linearise(dynamics.step_on_turn, states, tau)
    assert a.shape == (5, 2, 2) and b.shape == (5, 2)
    h = 1e-6
    for k in range(5):
        turn = math.floor(states[k, 0] / (2 * math.pi))

        def step(x, u, turn=turn):
            return dynamics.step_on_turn(x, u, turn).full().ravel()

        for i in range(2):
            dx = np.zeros(2)
            dx[i] = h
            column = (step(states[k] + dx, tau[k]) - step(states[k] - dx, tau[k])) / (2 * h)
            np.testing.assert_allclose(a[k][:, i], column, rtol=1e-6, atol=1e-8)
        column = (step(states[k], tau[k] + h) - step(states[k], tau[k] - h)) / (2 * h)
        np.testing.assert_allclose(b[k], column, rtol=1e-6, atol=1e-10)


def test_long_horizon_gains_equal_the_stationary_lqr() -> None:
    """Time-invariant A, B over 2000 steps: the first gain is the infinite-horizon LQR gain of
    the discrete algebraic Riccati equation (scipy), to 1e-9 relative; the closed loop A - B K is
    stable."""
    dt, inertia, damping = 2e-3, 3e-3, 1e-3
    a = np.array([[1.0, dt], [0.0, 1.0 - dt * damping / inertia]])
    b = np.array([0.0, dt / inertia])
    weights = LQRWeights.from_config(OCPConfig())
    gains = riccati_gains(np.repeat(a[None], 2000, 0), np.repeat(b[None], 2000, 0), weights)
    q = np.diag([weights.q_theta, weights.q_omega])
    p = solve_discrete_are(a, b[:, None], q, np.array([[weights.r]]))
    stationary = (b @ p @ a) / (weights.r + b @ p @ b)
    np.testing.assert_allclose(gains[0], stationary, rtol=1e-9)
    assert np.max(np.abs(np.linalg.eigvals(a - np.outer(b, gains[0])))) < 1.0


@pytest.mark.parametrize("field", ["feedback_theta", "feedback_omega", "feedback_torque"])
@pytest.mark.parametrize("value", [0.0, -1.0, float("nan")])
def test_feedback_tolerances_must_be_positive_and_finite(field: str, value: float) -> None:
    with pytest.raises(OCPConfigError, match=field):
        OCPConfig(**{field: value})


@pytest.mark.parametrize(
    ("profiles", "shown"),
    [
        (("robust", "pd"), "robust, pd"),
        ((), "none"),
        (("robust-fb", "robust-fb"), "robust-fb, robust-fb"),
    ],
)
def test_unknown_empty_or_repeated_profiles_are_refused(profiles: tuple, shown: str) -> None:
    with pytest.raises(
        OCPConfigError,
        match=f"profiles must be distinct names among robust, robust-fb, robust-pd, got {shown}$",
    ):
        OCPConfig(profiles=profiles)


def _model():
    return constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))


def test_closed_loop_monte_carlo_with_zero_gains_or_no_authority_is_open_loop() -> None:
    """Zero gains: the closed-loop Monte-Carlo is the open-loop one bit for bit. A saturation of
    0 N·m: every torque is clipped to 0, so it is the open loop under zero torque."""
    heads = FusedHeads(_model())
    tau = np.linspace(-2, 3, 120)
    plan = np.zeros((120, 2))
    kwargs = {"n_samples": 64, "mode": "step", "seed": 3}
    open_loop = monte_carlo(heads, [math.pi, 0.0], tau, **kwargs)
    zero = Feedback(plan, np.zeros((120, 2)), 10.0)
    closed = monte_carlo(heads, [math.pi, 0.0], tau, feedback=zero, **kwargs)
    assert np.array_equal(open_loop.samples, closed.samples)
    idle = monte_carlo(heads, [math.pi, 0.0], np.zeros(120), **kwargs)
    clipped = Feedback(plan, np.full((120, 2), 50.0), 0.0)
    assert np.array_equal(
        idle.samples, monte_carlo(heads, [math.pi, 0.0], tau, feedback=clipped, **kwargs).samples
    )


def test_tube_tightening_is_the_closed_loop_spread_and_far_below_the_open_loop() -> None:
    """robust-fb: the robust loop settles on margins equal to the closed-loop Monte-Carlo's
    tightening under the robust plan's own LQR gains, and those margins are under a quarter of
    the open-loop ones (feedback shrinks the spread the tightening is sized for)."""
    model = _model()
    open_loop = solve_robust(model, OCPConfig())
    config = OCPConfig()
    tube = solve_robust(model, config, profile="robust-fb")
    last = tube.iterations[-1]
    np.testing.assert_array_less(np.abs(last.tightening - last.margin), config.margin_tolerance)
    again = slider_uncertainty(FusedHeads(model), tube.robust, config, gains=tube.robust_gains)
    np.testing.assert_allclose(again.tightening, last.tightening, rtol=0, atol=1e-12)
    assert np.all(last.margin < 0.25 * open_loop.iterations[-1].margin)
    assert tube.robust.cost < open_loop.robust.cost
