"""z_K's mean network seeing theta_mod / 2 pi (`PPANNConfig.mean_wrap`): phase 1 then carries a
load torque continuous across the wrap (top dead centre), which the paper's (sin, cos) network
cannot; the OCP's step on a given turn equals the step; a checkpoint keeps the option."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from control.dynamics import CasadiPPANN
from ppann.checkpoint import load, save
from ppann.model import PPANN, PPANNConfig
from ppann.train import History, TrainConfig, make_splits, train_mean
from tests.test_ppann import synthetic

ANGLES = np.array([-0.3, -0.1, -0.03, 0.03, 0.1, 0.3])
"""Either side of the wrap, rad."""


def _static_torque(model: PPANN, theta: np.ndarray) -> np.ndarray:
    """The torque the model needs to hold the crank still at `theta`: its torque balance at
    omega = alpha = 0, K_m (1 + z_K) theta_mod."""
    angle = torch.from_numpy(np.mod(theta, 2 * math.pi))
    zero = torch.zeros_like(angle)
    with torch.no_grad():
        z = model.z_mean(angle, zero)
        inertia = model.physical[0] * (1 + z[:, 0])
        return (-model.acceleration(angle, zero, zero, z) * inertia).numpy()


def test_phase_1_carries_a_load_continuous_across_the_wrap() -> None:
    """The synthetic system's load 0.3 sin(theta) beside top dead centre (0.009-0.089 N·m):
    within 0.01 N·m with the wrapped angle; without it more than 0.05 N·m off at some angle
    (measured: 0.078 at -0.03 rad, 0.069 at 0.3; with it at most 0.004)."""
    data = synthetic(seconds=20.0)
    config = TrainConfig(
        max_epochs=40, patience=40, validation_fraction=0.1, batch_size=256, lr=1e-2
    )
    splits = make_splits(data, config)
    truth = 0.3 * np.sin(ANGLES)
    errors = {}
    for wrap in (True, False):
        torch.manual_seed(0)
        model = PPANN(PPANNConfig(mean_wrap=wrap))
        train_mean(model, splits, config, history=History())
        errors[wrap] = np.abs(_static_torque(model, ANGLES) - truth).max()
    assert errors[True] < 0.01 and errors[False] > 0.05, errors


@pytest.mark.parametrize("angle_update", ["euler", "trapezoid"])
def test_the_step_on_a_turn_equals_the_step_within_that_turn(angle_update: str) -> None:
    """With z_K jumping at the wrap, the OCP's step on a fixed turn (control/dynamics.py) sees
    the angle tables at theta on that turn: for theta inside it, the step itself, on both
    sides of the wrap; the angle moves by the model's update with the turn's acceleration."""
    torch.manual_seed(3)
    model = PPANN(PPANNConfig(mean_wrap=True, angle_update=angle_update))
    with torch.no_grad():
        for net in model.mean_nets.values():
            net[2].weight.mul_(3.0)
    dynamics = CasadiPPANN(model)
    for theta in (2 * math.pi - 1e-3, 2 * math.pi + 1e-3, 0.5, 4 * math.pi - 0.2, -0.1):
        turn = math.floor(theta / (2 * math.pi))
        step = dynamics.step([theta, 0.3], 0.2).full().ravel()
        on_turn = dynamics.step_on_turn([theta, 0.3], 0.2, turn).full().ravel()
        np.testing.assert_allclose(on_turn, step, rtol=0, atol=1e-9)
    # off its turn (an OCP iterate), z_K is the network at theta - 2 pi turn, where a B-spline
    # table would be 0 beyond its pads: theta = 6.0 on turn 1 is -0.28 rad
    theta, local = torch.tensor([6.0], dtype=torch.float64), 6.0 - 2 * math.pi
    with torch.no_grad():
        z = model.z_mean(theta, torch.tensor([0.3], dtype=torch.float64))[0]
        z_k = model.z_mean(torch.tensor([local], dtype=torch.float64), theta * 0, wrap=False)
        j, b, k = model.physical
        alpha = (0.2 - b * (1 + z[1]) * 0.3 - k * (1 + z_k[0, 2]) * local) / (j * (1 + z[0]))
    away = dynamics.step_on_turn([6.0, 0.3], 0.2, 1).full().ravel()
    np.testing.assert_allclose(away[1], 0.3 + model.config.dt * float(alpha), rtol=1e-12)
    moved = 6.0 + model.config.dt * 0.3 + model.config.half_step * float(alpha)
    np.testing.assert_allclose(away[0], moved, rtol=1e-12)
    # just below the wrap the two sides differ: the tables do jump there
    below = dynamics.z_mean(2 * math.pi - 1e-6, 0.0).full().ravel()
    above = dynamics.z_mean(2 * math.pi + 1e-6, 0.0).full().ravel()
    assert abs(below[2] - above[2]) > 1e-3


def test_a_checkpoint_keeps_the_option(tmp_path) -> None:
    model = PPANN(PPANNConfig(mean_hidden=20, mean_wrap=True))
    save(tmp_path / "m.pt", model, kind="ppann", extra={"history": {}})
    loaded, _ = load(tmp_path / "m.pt")
    assert loaded.config.mean_wrap is True
    assert loaded.mean_nets["K"][0].in_features == 3
    plain = PPANN(PPANNConfig(mean_hidden=20))
    save(tmp_path / "p.pt", plain, kind="ppann", extra={"history": {}})
    old = torch.load(tmp_path / "p.pt", weights_only=True)
    del old["config"]["mean_wrap"]  # saved before the option: the paper's (sin, cos) network
    torch.save(old, tmp_path / "old.pt")
    assert load(tmp_path / "old.pt")[0].mean_nets["K"][0].in_features == 2
