"""The CasADi export of a PPANN equals the torch model to 1e-9."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from control.dynamics import CasadiPPANN
from ppann.model import PPANN, PPANNConfig, rollout


def _trained_like(seed: int, **config) -> PPANN:
    """A PPANN with random, non-trivial weights (outputs of order 1)."""
    torch.manual_seed(seed)
    model = PPANN(PPANNConfig(**config))
    with torch.no_grad():
        for net in [*model.mean_nets.values(), *model.sigma_nets.values()]:
            net[2].weight.mul_(3.0)
    return model


@pytest.mark.parametrize(
    "config", [{}, {"trainable_physics": True}, {"use_networks": False}, {"sigma_speed": True}]
)
def test_networks_and_dynamics_equal_torch(config: dict) -> None:
    model = _trained_like(0, **config)
    exported = CasadiPPANN(model)
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
