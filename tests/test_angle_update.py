"""The PPANN's angle update (`PPANNConfig.angle_update`): forward Euler (eq. 4) against the
trapezoid, on an exact answer in every path that steps the model (torch, the Monte-Carlo's NumPy
reference and compiled rollouts, CasADi), and carried by the checkpoint and the training config."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from control.dynamics import CasadiPPANN
from ppann.checkpoint import load, save
from ppann.fit import new_model
from ppann.model import PPANN, PPANNConfig, rollout
from ppann.model_config import ModelConfigError
from ppann.montecarlo import monte_carlo
from ppann.train import TrainConfig
from tests.test_ppann import synthetic

DT = PPANNConfig.dt
STEPS = 100
TORQUE = 0.3


def _free_inertia(angle_update: str) -> PPANN:
    """The prior alone with no stiffness and a vanishing damping: under a constant torque from
    rest the motor turns at the constant acceleration TORQUE / J_m; sigma at its floor 1e-12."""
    config = PPANNConfig(
        use_networks=False, k_m=0.0, b_m=1e-12, sigma_floor=1e-12, angle_update=angle_update
    )
    model = PPANN(config)
    with torch.no_grad():
        for net in model.sigma_nets.values():
            net[2].weight.zero_()
            net[2].bias.fill_(-60.0)  # softplus(-60) ~ 1e-26: sigma = floor
    return model.eval()


def _every_path(model: PPANN) -> dict[str, np.ndarray]:
    """The mean trajectory's angles (STEPS + 1,) from rest under TORQUE by every stepping path."""
    tau = np.full(STEPS, TORQUE)
    x0 = np.zeros(2)
    with torch.no_grad():
        torch_path = rollout(model, torch.from_numpy(x0), torch.from_numpy(tau)).numpy()
    paths = {"torch": torch_path[:, 0], "casadi": CasadiPPANN(model).rollout(x0, tau)[:, 0]}
    for compiled in (False, True):
        bands = monte_carlo(model, x0, tau, n_samples=8, seed=0, compiled=compiled)
        paths["compiled" if compiled else "numpy"] = bands.mean[:, 0]
    return paths


@pytest.mark.parametrize("angle_update", ["euler", "trapezoid"])
def test_constant_acceleration_from_rest_in_every_path(angle_update: str) -> None:
    """theta(t) = alpha t^2 / 2 exactly at the samples with the trapezoid; forward Euler lags it by
    dt omega_k / 2 = alpha dt^2 k / 2 (bench/mean_offset.md's lag), in every path."""
    alpha = TORQUE / PPANNConfig.j_m
    k = np.arange(STEPS + 1)
    exact = 0.5 * alpha * (k * DT) ** 2
    expected = exact if angle_update == "trapezoid" else exact - 0.5 * alpha * DT**2 * k
    for name, theta in _every_path(_free_inertia(angle_update)).items():
        np.testing.assert_allclose(theta, expected, rtol=1e-9, atol=1e-12, err_msg=name)
    lag = 0.5 * alpha * DT**2 * STEPS if angle_update == "euler" else 0.0
    assert exact[-1] - expected[-1] == pytest.approx(lag, abs=1e-15)


def test_the_trapezoid_moves_the_angle_by_the_steps_mean_speed() -> None:
    """With networks: the angle moves by dt (omega_k + omega_{k+1}) / 2 of the step's own speeds,
    the speed's step is eq. 4's, and Euler's angle is another."""
    model = PPANN(PPANNConfig(angle_update="trapezoid")).eval()
    rng = np.random.default_rng(0)
    x = torch.from_numpy(np.stack([rng.uniform(-7, 7, 64), rng.uniform(-60, 60, 64)], -1))
    tau = torch.from_numpy(rng.uniform(-5, 5, 64))
    with torch.no_grad():
        nxt = model.step(x, tau)
    mean_speed = (x[:, 1] + nxt[:, 1]) / 2
    torch.testing.assert_close(nxt[:, 0], x[:, 0] + DT * mean_speed, rtol=0, atol=1e-12)
    euler = PPANN(PPANNConfig()).eval()
    euler.load_state_dict(model.state_dict())
    with torch.no_grad():
        assert torch.equal(euler.step(x, tau)[:, 1], nxt[:, 1])  # the speed's step is eq. 4's
        assert not torch.allclose(euler.step(x, tau)[:, 0], nxt[:, 0], rtol=0, atol=1e-6)


def test_the_checkpoint_and_the_training_config_carry_it(tmp_path) -> None:
    data = synthetic(seconds=1.0)
    model = new_model(data, kind="ppann", config=TrainConfig(angle_update="trapezoid"))
    assert model.config.angle_update == "trapezoid"
    euler = TrainConfig(angle_update="euler")
    assert new_model(data, kind="ppann", config=euler).config.angle_update == "euler"
    save(tmp_path / "m.pt", model, kind="ppann", extra={"history": {}})
    assert load(tmp_path / "m.pt")[0].config.angle_update == "trapezoid"
    old = torch.load(tmp_path / "m.pt", weights_only=True)
    del old["config"]["angle_update"]  # a checkpoint of before the setting: eq. 4's
    torch.save(old, tmp_path / "old.pt")
    assert load(tmp_path / "old.pt")[0].config.angle_update == "euler"
    with pytest.raises(ModelConfigError, match="angle_update must be one of"):
        PPANNConfig(angle_update="midpoint")
