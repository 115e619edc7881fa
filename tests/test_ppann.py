"""PPANN: prior equality, the eq. 9 loss, recovery of a known system, frozen mean in phase 2,
Monte-Carlo collapse, and bad inputs."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pytest
import torch

from ppann.checkpoint import CheckpointError, load, save
from ppann.data import DataError
from ppann.heads import FusedHeads
from ppann.losses import propagated_nll
from ppann.model import (
    PPANN,
    ModelConfigError,
    PPANNConfig,
    n_step_prediction,
    rollout,
)
from ppann.montecarlo import monte_carlo
from ppann.train import History, TrainConfig, make_splits, train_mean, train_sigma
from twin.dataset import Dataset

DT = 0.002


def synthetic(
    seconds: float = 10.0,
    seed: int = 0,
    *,
    amplitude: float = 3.0,
    hold: int = 100,
    friction: Callable[[float, float], float] = lambda theta, omega: 0.1 * omega,
) -> Dataset:
    """A known ODE: J(θ) = 3e-3 (1 + 0.5 sin²θ), `friction` (viscous 0.1), load 0.3 sin θ;
    Euler at 2 ms, under random torque levels of ±`amplitude` held `hold` samples and smoothed
    over a quarter of that."""
    rng = np.random.default_rng(seed)
    n = int(seconds / DT)
    levels = np.repeat(rng.uniform(-amplitude, amplitude, n // hold + 1), hold)[:n]
    tau = np.convolve(levels, np.ones(hold // 4) / (hold // 4), mode="same")
    theta, omega = np.empty(n), np.empty(n)
    theta[0], omega[0] = 1.0, 0.0
    for k in range(n - 1):
        inertia = 3e-3 * (1 + 0.5 * np.sin(theta[k]) ** 2)
        alpha = (tau[k] - friction(theta[k], omega[k]) - 0.3 * np.sin(theta[k])) / inertia
        theta[k + 1] = theta[k] + DT * omega[k]
        omega[k + 1] = omega[k] + DT * alpha
    return Dataset(
        t=np.arange(n) * DT,
        episode=np.zeros(n, dtype=np.int64),
        theta=theta,
        omega=omega,
        tau=tau,
        slider_position=np.zeros(n),
    )


def _zero_mean_outputs(model: PPANN) -> None:
    with torch.no_grad():
        for net in model.mean_nets.values():
            net[2].weight.zero_()
            net[2].bias.zero_()


def test_zero_networks_give_the_prior_exactly() -> None:
    model = PPANN()
    _zero_mean_outputs(model)
    rng = np.random.default_rng(0)
    theta = torch.from_numpy(rng.uniform(-20, 20, 64))
    omega = torch.from_numpy(rng.uniform(-60, 60, 64))
    tau = torch.from_numpy(rng.uniform(-10, 10, 64))
    x = torch.stack([theta, omega], -1)
    nxt = model.step(x, tau)
    prior = (tau - 0.1 * omega - 1.0 * torch.remainder(theta, 2 * math.pi)) / 3e-3
    assert torch.equal(nxt[:, 1], omega + DT * prior)
    assert torch.equal(nxt[:, 0], theta + DT * omega)  # theta' = omega, exactly


def test_eq9_loss_by_hand() -> None:
    residual = torch.tensor([0.5, -1.0], dtype=torch.float64)
    derivative = torch.tensor([[1.0, 2.0, 3.0], [0.5, 0.0, 1.0]], dtype=torch.float64)
    sigma = torch.tensor([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]], dtype=torch.float64)
    # variances: 0.1² + 0.4² + 0.9² = 0.98 and 0.2² + 0 + 0.6² = 0.40
    expected = 0.5 * ((0.25 / 0.98 + math.log(0.98)) + (1.0 / 0.40 + math.log(0.40))) / 2
    assert float(propagated_nll(residual, derivative, sigma)) == pytest.approx(expected, abs=1e-10)


def test_eq9_loss_gradcheck() -> None:
    gen = torch.Generator().manual_seed(0)
    residual = torch.randn(5, dtype=torch.float64, generator=gen, requires_grad=True)
    derivative = torch.randn(5, 3, dtype=torch.float64, generator=gen, requires_grad=True)
    sigma = (torch.rand(5, 3, dtype=torch.float64, generator=gen) + 0.1).requires_grad_()
    assert torch.autograd.gradcheck(propagated_nll, (residual, derivative, sigma))


def test_recovers_a_known_system() -> None:
    """Phase 1 on the synthetic system: 10-step RMSE below 5e-3 rad and 0.5 rad/s (the prior
    alone is off by ~0.3 rad and ~27 rad/s; measured 1.1e-3 rad and 0.11 rad/s)."""
    data = synthetic(seconds=20.0)
    config = TrainConfig(
        max_epochs=40, patience=40, validation_fraction=0.1, batch_size=256, lr=1e-2
    )
    splits = make_splits(data, config)
    torch.manual_seed(0)
    model = PPANN()

    def rmse() -> torch.Tensor:
        with torch.no_grad():
            p = n_step_prediction(model, splits.validation.x0, splits.validation.tau)
            return (p[:, -1] - splits.validation.target[:, -1]).pow(2).mean(0).sqrt()

    prior = rmse()
    train_mean(model, splits, config, history=History())
    trained = rmse()
    assert trained[0] < 5e-3 and trained[1] < 0.5, trained
    assert torch.all(trained < prior / 20)


def test_phase2_leaves_the_mean_bit_identical() -> None:
    data = synthetic(seconds=3.0)
    config = TrainConfig(max_epochs=1, sigma_epochs=20, validation_fraction=0.2)
    splits = make_splits(data, config)
    model = PPANN(PPANNConfig(trainable_physics=True))
    train_mean(model, splits, config, history=History())
    phase2 = ("sigma", "common_covariance", "machine_profile", "spread_machines")  # phase 2 fits
    before = {
        k: v.clone() for k, v in model.state_dict().items() if not any(p in k for p in phase2)
    }
    sigma_before = {k: v.clone() for k, v in model.state_dict().items() if "sigma" in k}
    history = History()
    train_sigma(model, data, splits, config, history=history)
    after = model.state_dict()
    for key, value in before.items():
        assert torch.equal(value, after[key]), key
    assert any(not torch.equal(v, after[k]) for k, v in sigma_before.items())
    assert history.sigma[-1] < history.sigma[0]


def test_monte_carlo_collapses_to_the_mean_at_the_sigma_floor() -> None:
    torch.manual_seed(1)
    model = PPANN(PPANNConfig(sigma_floor=1e-12))
    with torch.no_grad():
        for net in model.sigma_nets.values():
            net[2].weight.zero_()
            net[2].bias.fill_(-60.0)  # softplus(-60) ~ 1e-26: sigma = floor
    x0 = torch.tensor([math.pi, 0.0], dtype=torch.float64)
    tau = torch.from_numpy(np.linspace(-2, 3, 150))
    mean = rollout(model, x0, tau).detach().numpy()
    for mode in ("step", "trajectory"):
        # the reference path (NumPy): the spread scales with sigma (9.9e-5 at a floor of 1e-6 in
        # trajectory mode, 1.1e-10 at 1e-12)
        reference = monte_carlo(model, x0.numpy(), tau.numpy(), mode=mode, seed=3, compiled=False)
        assert reference.std.max() < 1e-9
        # the compiled rollout agrees with it to its speed networks' float32 rounding
        # (tests/test_kernel.py), which sets a floor under the spread that depends on the CPU's
        # vector code: 6.1e-9 in trajectory mode on an AMD EPYC in session 57 (under 1e-9 on the
        # Intel machines before), four orders of magnitude below the spread at a floor of 1e-6
        bands = monte_carlo(model, x0.numpy(), tau.numpy(), mode=mode, seed=3)
        assert bands.std.max() < 1e-7
        # The fused float32 hidden layer: agreement to ~1e-6 relative over 150 steps.
        np.testing.assert_allclose(bands.mean, mean, rtol=0, atol=1e-5)
        np.testing.assert_allclose(reference.mean, mean, rtol=0, atol=1e-5)


@pytest.mark.parametrize(
    "config", [{}, {"sigma_speed": True}, {"sigma_wrap": True}, {"mean_wrap": True}]
)
def test_fused_heads_equal_the_networks(config: dict) -> None:
    torch.manual_seed(2)
    model = PPANN(PPANNConfig(**config))
    rng = np.random.default_rng(0)
    theta, omega = rng.uniform(-10, 10, 200), rng.uniform(-80, 80, 200)
    # the ends of the angle table's turn, and turns far from the first
    theta[:6] = [0.0, 2 * math.pi, -2 * math.pi, 2 * math.pi - 1e-12, 1e-12, 1e4 + 0.3]
    mean, sigma = FusedHeads(model)(theta, omega)
    t, w = torch.from_numpy(theta), torch.from_numpy(omega)
    np.testing.assert_allclose(mean, model.z_mean(t, w).detach().numpy(), rtol=0, atol=1e-6)
    np.testing.assert_allclose(sigma, model.z_sigma(t, w).detach().numpy(), rtol=0, atol=1e-6)


def test_fused_heads_give_nan_for_a_diverged_state() -> None:
    torch.manual_seed(2)
    heads = FusedHeads(PPANN())
    with np.errstate(invalid="ignore"):
        mean, sigma = heads(np.array([np.inf, np.nan, 1.0]), np.array([0.0, 0.0, 0.0]))
    assert np.isnan(mean[:2]).all() and np.isnan(sigma[:2]).all()
    assert np.isfinite(mean[2]).all() and np.isfinite(sigma[2]).all()


def test_monte_carlo_is_seeded() -> None:
    model = PPANN()
    a = monte_carlo(model, [1.0, 0.0], np.ones(50), seed=5)
    b = monte_carlo(model, [1.0, 0.0], np.ones(50), seed=5)
    c = monte_carlo(model, [1.0, 0.0], np.ones(50), seed=6)
    assert np.array_equal(a.samples, b.samples) and not np.array_equal(a.samples, c.samples)


@pytest.mark.parametrize(
    ("seconds", "config", "match"),
    [
        (0.1, TrainConfig(), "too short"),  # 50 samples: no validation window of 10 steps
        (1.0, TrainConfig(horizon=600), "too short"),
    ],
)
def test_too_short_for_split_or_horizon(seconds: float, config: TrainConfig, match: str) -> None:
    with pytest.raises(DataError, match=match):
        make_splits(synthetic(seconds=seconds), config)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_data_names_the_sample(bad: float) -> None:
    data = synthetic(seconds=1.0)
    omega = data.omega.copy()
    omega[123] = bad
    with pytest.raises(DataError, match=rf"omega is {bad} at sample 123 \(t = 0.246 s\)"):
        make_splits(replace(data, omega=omega), TrainConfig())


def test_checkpoint_round_trip_and_rejections(tmp_path) -> None:
    model = PPANN(PPANNConfig(mean_hidden=20))
    path = tmp_path / "model.pt"
    save(path, model, kind="ppann", extra={"history": {"train": [1.0]}})
    loaded, payload = load(path)
    for key, value in model.state_dict().items():
        assert torch.equal(value, loaded.state_dict()[key])
    assert payload["history"] == {"train": [1.0]}
    assert torch.load(path, weights_only=True)["kind"] == "ppann"

    # a checkpoint saved before `sigma_speed`, `sigma_wrap` and `machine_terms` existed is of
    # the paper's architecture, its machine factors on eq. 14's whole terms
    old = torch.load(path, weights_only=True)
    del old["config"]["sigma_speed"], old["config"]["sigma_wrap"], old["config"]["machine_terms"]
    torch.save(old, tmp_path / "old.pt")
    assert load(tmp_path / "old.pt")[0].config.sigma_speed is False
    assert load(tmp_path / "old.pt")[0].config.machine_terms == "augmented"
    wide = PPANN(PPANNConfig(mean_hidden=20, sigma_speed=True))
    save(tmp_path / "wide.pt", wide, kind="ppann", extra={"history": {}})
    assert load(tmp_path / "wide.pt")[0].sigma_nets["K"][0].in_features == 3
    assert load(tmp_path / "old.pt")[0].config.sigma_wrap is False
    wrapped = PPANN(PPANNConfig(mean_hidden=20, sigma_wrap=True))
    save(tmp_path / "wrapped.pt", wrapped, kind="ppann", extra={"history": {}})
    assert load(tmp_path / "wrapped.pt")[0].sigma_nets["K"][0].in_features == 3

    other = torch.load(path, weights_only=True)
    other["config"]["mean_hidden"] = 30
    torch.save(other, tmp_path / "arch.pt")
    with pytest.raises(CheckpointError, match="another architecture"):
        load(tmp_path / "arch.pt")
    other["config"]["mean_hidden"] = 20
    other["version"] = 99
    torch.save(other, tmp_path / "version.pt")
    with pytest.raises(CheckpointError, match="checkpoint version 99"):
        load(tmp_path / "version.pt")
    (tmp_path / "text.pt").write_text("not a checkpoint")
    with pytest.raises(CheckpointError, match="not a checkpoint"):
        load(tmp_path / "text.pt")
    torch.save(torch.zeros(3), tmp_path / "tensor.pt")
    with pytest.raises(CheckpointError, match="not a crank-ppann-checkpoint"):
        load(tmp_path / "tensor.pt")
    with pytest.raises(CheckpointError, match="checkpoint not found"):
        load(tmp_path / "absent.pt")


def test_sigma_wrap_gives_z_k_its_own_noise_on_each_side_of_the_wrap() -> None:
    """With `sigma_wrap` z_K's σ just below 2 pi and at 0 differ (the network sees theta_mod);
    without it they are equal (sin and cos are periodic); with sigma_speed it is refused."""
    for wrap in (False, True):
        torch.manual_seed(4)
        model = PPANN(PPANNConfig(sigma_wrap=wrap))
        with torch.no_grad():
            model.sigma_nets["K"][2].weight.mul_(5.0)
            theta = torch.tensor(
                [2 * math.pi - 1e-9, 2 * math.pi, 4 * math.pi - 1e-9], dtype=torch.float64
            )
            sigma = model.z_sigma(theta, torch.zeros_like(theta))[:, 2].numpy()
        assert (abs(sigma[0] - sigma[1]) > 1e-3) == wrap
        assert sigma[0] == pytest.approx(sigma[2], abs=1e-6)  # one turn is like another
    with pytest.raises(ModelConfigError, match="cannot be combined"):
        PPANNConfig(sigma_wrap=True, sigma_speed=True)


def test_the_training_config_asks_for_sigma_wrap_and_phase_2_fits_it() -> None:
    """`TrainConfig(sigma_wrap=True)` trains a PPANN whose z_K sigma network sees theta_mod;
    phase 2 moves its weights, and the saved model reloads with the option."""
    from ppann.fit import fit

    data = synthetic(seconds=3.0)
    config = TrainConfig(max_epochs=1, sigma_epochs=20, validation_fraction=0.2, sigma_wrap=True)
    fitted = fit(data, kind="ppann", config=config)
    model = fitted.model
    assert model.config.sigma_wrap and model.sigma_nets["K"][0].in_features == 3
    assert fitted.history.sigma[-1] < fitted.history.sigma[0]
    plain = fit(data, kind="ppann", config=replace(config, sigma_wrap=False)).model
    assert not plain.config.sigma_wrap and plain.sigma_nets["K"][0].in_features == 2
    # the physics-only baseline has no sigma networks to widen
    assert not fit(data, kind="physics", config=config).model.config.sigma_wrap
