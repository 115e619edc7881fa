"""The CasADi export of a PPANN equals the torch model to 1e-9."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
import torch

from control.dynamics import CasadiPPANN, angle_splines
from ppann.model import PPANN, PPANNConfig, rollout


def _trained_like(seed: int, **config) -> PPANN:
    """A PPANN with random, non-trivial weights (outputs of order 1)."""
    torch.manual_seed(seed)
    model = PPANN(PPANNConfig(**config))
    with torch.no_grad():
        for net in [*model.mean_nets.values(), *model.sigma_nets.values()]:
            net[2].weight.mul_(3.0)
    return model


@pytest.mark.parametrize("splines", [True, False])
@pytest.mark.parametrize(
    "config",
    [
        {},
        {"trainable_physics": True},
        {"use_networks": False},
        {"sigma_speed": True},
        {"sigma_wrap": True},
        {"coulomb": True},
        {"mean_wrap": True, "sigma_wrap": True},
        {"angle_update": "trapezoid", "mean_wrap": True},
    ],
)
def test_networks_and_dynamics_equal_torch(config: dict, splines: bool) -> None:
    model = _trained_like(0, **config)
    exported = CasadiPPANN(model, splines=splines)
    rng = np.random.default_rng(1)
    theta = rng.uniform(-4 * math.pi, 4 * math.pi, 200)
    omega = rng.uniform(-80, 80, 200)
    tau = rng.uniform(-10, 10, 200)
    t, w, u = (torch.from_numpy(v) for v in (theta, omega, tau))
    with torch.no_grad():
        z = model.z_mean(t, w).numpy()
        s = model.z_sigma(t, w).numpy()
        nxt = model.step(torch.stack([t, w], -1), u).numpy()
    for i in range(len(theta)):
        np.testing.assert_allclose(
            exported.z_mean(theta[i], omega[i]).full().ravel(), z[i], rtol=0, atol=1e-9
        )
        np.testing.assert_allclose(
            exported.z_sigma(theta[i], omega[i]).full().ravel(), s[i], rtol=0, atol=1e-9
        )
        step = exported.step([theta[i], omega[i]], tau[i]).full().ravel()
        np.testing.assert_allclose(step, nxt[i], rtol=1e-12, atol=1e-9)


def test_trajectory_through_two_pi_agrees() -> None:
    """Across theta = 2 pi, theta_mod wraps in both models alike."""
    model = _trained_like(2)
    exported = CasadiPPANN(model)
    tau = np.full(150, 2.0)
    x0 = np.array([2 * math.pi - 0.2, 30.0])
    with torch.no_grad():
        expected = rollout(model, torch.from_numpy(x0), torch.from_numpy(tau)).numpy()
    got = exported.rollout(x0, tau)
    assert expected[0, 0] < 2 * math.pi < expected[:, 0].max()  # the wrap is crossed
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9)


def test_derivatives_of_the_angle_splines_equal_the_networks() -> None:
    """IPOPT sees the splines' derivatives: the one-step Jacobian equals torch's autograd of the
    networks (64 points per turn instead of 4096 miss it by ~1e-6)."""
    model = _trained_like(3)
    assert set(angle_splines(model)) == {"mean J", "mean K", "sigma J", "sigma K"}
    exported = CasadiPPANN(model)
    x, u = ca.SX.sym("x", 2), ca.SX.sym("u")
    jacobian = ca.Function(
        "step_jacobian", [x, u], [ca.jacobian(exported.step(x, u), ca.vertcat(x, u))]
    )
    rng = np.random.default_rng(4)
    for theta, omega, tau in zip(
        rng.uniform(-4 * math.pi, 4 * math.pi, 50),
        rng.uniform(-80, 80, 50),
        rng.uniform(-10, 10, 50),
        strict=True,
    ):
        inputs = torch.tensor([theta, omega, tau], dtype=torch.float64)
        expected = torch.autograd.functional.jacobian(
            lambda v: model.step(v[:2], v[2]), inputs
        ).numpy()
        got = jacobian([theta, omega], tau).full()
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
