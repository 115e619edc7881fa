"""The slider force's channel (ppann/lever.py): its lever against the kinematics written out, its
one-step spread in the Monte-Carlo against the formula, the compiled path against NumPy's, a
zero force against no channel, recovery of a known force, and the checkpoint round trip."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ppann import kernel
from ppann.checkpoint import load, save
from ppann.heads import FusedHeads
from ppann.lever import lever_arm
from ppann.model import PPANN, PPANNConfig, constant_ppann
from ppann.montecarlo import monte_carlo, rollout
from ppann.train import History, TrainConfig, make_splits, train_sigma
from twin.dataset import Dataset
from twin.geometry import PAPER

DT = 0.002
FORCE = 30.0 / np.sqrt(3.0)
"""The twin's slider force, U[-30, 30] N, has this standard deviation (17.3 N)."""


def _lever_model(force: float, *, z_sigma: float = 2e-4) -> PPANN:
    model = constant_ppann(
        z_mean=(0.0, 0.0, -0.9), z_sigma=(z_sigma,) * 3, config=PPANNConfig(sigma_lever=True)
    )
    with torch.no_grad():
        model.lever_sigma.fill_(force)
    return model


def test_lever_arm_is_the_derivative_of_the_kinematics_written_out() -> None:
    """x(θ) = l1 cos θ + sqrt(l2² - l1² sin² θ) + l1 - l2, so
    x'(θ) = -l1 sin θ - l1² sin θ cos θ / sqrt(l2² - l1² sin² θ): zero at both dead centres."""
    l1, l2 = PAPER.crank_length, PAPER.rod_length
    theta = np.linspace(-1.0, 7.5, 301)
    s, c = np.sin(theta), np.cos(theta)
    exact = -l1 * s - l1**2 * s * c / np.sqrt(l2**2 - (l1 * s) ** 2)
    np.testing.assert_allclose(lever_arm(PAPER, theta), exact, rtol=0, atol=1e-9)
    assert np.abs(lever_arm(PAPER, np.array([0.0, np.pi, 2 * np.pi]))).max() < 1e-9


@pytest.mark.parametrize("compiled", [True, False])
def test_one_step_spread_is_the_force_through_the_lever(compiled: bool) -> None:
    """From rest, one Monte-Carlo step: ω₁ = dt (τ + x'(θ₀) F - K θ_mod ...) / J, so σ(ω₁) =
    dt σ_F |x'(θ₀)| / J_m at any angle, within the sampling error of 40 000 draws (0.35 % of σ;
    the networks' own noise, 2e-4 of the terms, is far below it); none at a dead centre."""
    force = 12.0
    heads = FusedHeads(_lever_model(force))
    for theta0 in (1.1, np.pi / 2, 4.0):
        bands = monte_carlo(
            heads, [theta0, 0.0], np.array([0.5]), n_samples=40_000, seed=1, compiled=compiled
        )
        expected = DT * force * abs(lever_arm(PAPER, np.array([theta0]))[0]) / heads.j
        assert bands.std[1, 1] == pytest.approx(expected, rel=0.02)
    at_dead_centre = monte_carlo(
        heads, [np.pi, 0.0], np.array([0.5]), n_samples=40_000, seed=1, compiled=compiled
    )
    assert at_dead_centre.std[1, 1] < 0.02 * expected


@pytest.mark.skipif(kernel.load() is None, reason="no C compiler on this machine")
@pytest.mark.parametrize("mode", ["step", "mixed", "trajectory"])
def test_compiled_rollout_with_the_force_equals_numpy(mode: str) -> None:
    """250 steps over the wrap, the force per step or per trajectory: the two paths agree to
    the float32 rounding of the speed networks, as without the channel (tests/test_kernel.py)."""
    model = _lever_model(15.0, z_sigma=0.02)
    with torch.no_grad():
        model.machine_sigma.copy_(torch.tensor([0.02, 0.05, 0.03]))
    heads = FusedHeads(model)
    tau = 1.5 * np.sin(np.linspace(0, 9, 250)) + 0.6
    fast, slow = (
        monte_carlo(heads, [5.9, 8.0], tau, n_samples=129, mode=mode, seed=3, compiled=c)
        for c in (True, False)
    )
    assert np.all(np.isfinite(fast.samples))
    np.testing.assert_allclose(fast.samples[..., 0], slow.samples[..., 0], rtol=0, atol=2e-6)
    np.testing.assert_allclose(fast.samples[..., 1], slow.samples[..., 1], rtol=0, atol=5e-5)


def test_the_forces_normals_are_common_random_numbers_kept_as_a_prefix() -> None:
    """The robust loop's drafts simulate 99 steps and its full solves more, with the same draws:
    kept between calls (ppann/montecarlo.py `_LEVER`), a short run is the first steps of a long
    one and a long run after a short one equals the long run drawn afresh, bit for bit."""
    from ppann import montecarlo

    heads = FusedHeads(_lever_model(15.0, z_sigma=0.02))
    tau = 1.5 * np.sin(np.linspace(0, 9, 250)) + 0.6
    montecarlo._LEVER._kept.clear()
    fresh = monte_carlo(heads, [5.9, 8.0], tau, n_samples=64, mode="mixed", seed=3)
    montecarlo._LEVER._kept.clear()
    short = monte_carlo(heads, [5.9, 8.0], tau[:99], n_samples=64, mode="mixed", seed=3)
    long = monte_carlo(heads, [5.9, 8.0], tau, n_samples=64, mode="mixed", seed=3)
    assert np.array_equal(long.samples, fresh.samples)
    assert np.array_equal(short.samples, fresh.samples[:, :100])


def test_a_zero_force_draws_nothing_and_equals_no_channel() -> None:
    """A model with the channel and lever_sigma 0 gives the numbers of one without it, bit for
    bit, in every mode: no extra draws, the same white normals."""
    plain = constant_ppann(z_mean=(0.1, -0.2, -0.9), z_sigma=(0.05, 0.3, 0.2))
    lever = _lever_model(0.0)
    lever.load_state_dict(plain.state_dict() | {"lever_sigma": torch.zeros(1)})
    tau = np.concatenate([np.full(60, 4.0), np.full(60, -3.0)])
    for mode in ("step", "mixed", "trajectory"):
        a, b = (
            monte_carlo(m, [0.3, 0.0], tau, n_samples=64, mode=mode, seed=9) for m in (plain, lever)
        )
        assert np.array_equal(a.samples, b.samples)


def test_the_force_acts_after_the_laws_saturation() -> None:
    """Closed loop with the torque saturated at every step: the force still moves the crank (it
    is a load, not part of the motor's torque), and both paths agree."""
    from ppann.montecarlo import Feedback

    heads = FusedHeads(_lever_model(20.0))
    plan = np.stack([np.linspace(1.0, 3.0, 41), np.full(41, 50.0)], axis=1)
    law = Feedback(plan, np.tile([500.0, 0.0], (41, 1)), 0.5)
    forces = np.random.default_rng(2).standard_normal((40, 32))
    paths = [
        rollout(heads, [0.0, 0.0], np.zeros(40), n_samples=32, eps=np.zeros((40, 32, 3)),
                feedback=law, compiled=c, lever_eps=forces)
        for c in (True, False)
    ]  # fmt: skip
    law_torque = -500.0 * (paths[1][:, :-1, 0] - plan[:-1, 0])
    assert np.all(np.abs(law_torque) > 0.5)  # saturated at every step of every sample
    np.testing.assert_allclose(paths[0], paths[1], rtol=0, atol=1e-9)
    assert paths[1][:, -1, 0].std() > 1e-3


def _force_dataset(*, episodes: int, seconds: float, seed: int) -> Dataset:
    """Episodes of a known PPANN (constant networks, no noise of their own) driven by random
    torque levels, with a white slider force F ~ N(0, FORCE²) through x'(θ) at every sample."""
    heads = FusedHeads(constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.01, 0.01, 0.01)))
    rng = np.random.default_rng(seed)
    n = int(seconds / DT)
    levels = np.repeat(rng.uniform(-4, 4, (episodes, n // 50 + 1)), 50, axis=1)[:, :n]
    tau = np.stack([np.convolve(row, np.ones(10) / 10, mode="same") for row in levels])
    force = rng.normal(0.0, FORCE, (episodes, n))
    theta, omega = np.empty((episodes, n)), np.zeros((episodes, n))
    theta[:, 0] = rng.uniform(0, 2 * np.pi, episodes)
    for k in range(n - 1):
        mean, _ = heads(theta[:, k], omega[:, k])
        load = force[:, k] * lever_arm(PAPER, theta[:, k])
        alpha = heads.acceleration(theta[:, k], omega[:, k], tau[:, k] + load, mean)
        theta[:, k + 1] = theta[:, k] + DT * omega[:, k]
        omega[:, k + 1] = omega[:, k] + DT * alpha
    total = episodes * n
    return Dataset(
        t=np.arange(total) * DT,
        episode=np.repeat(np.arange(episodes), n).astype(np.int64),
        theta=theta.ravel(),
        omega=omega.ravel(),
        tau=tau.ravel(),
        slider_position=np.zeros(total),
    )


def test_a_known_slider_force_is_recovered_within_10_percent() -> None:
    """Phase 2 on data whose only noise is a white slider force of 17.3 N: the channel takes it
    (the sigma networks could only imitate it with factors on J, B, K that do not vanish at the
    dead centres), and the machine spread stays near zero."""
    dataset = _force_dataset(episodes=12, seconds=2.0, seed=4)
    truth = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.01, 0.01, 0.01))
    torch.manual_seed(0)
    model = PPANN(PPANNConfig(sigma_hidden=4, sigma_lever=True))
    model.load_state_dict(
        {k: v for k, v in truth.state_dict().items() if not k.startswith("sigma_nets")}
        | {k: v for k, v in model.state_dict().items() if k.startswith("sigma_nets")}
        | {"lever_sigma": torch.zeros(1)}
    )
    config = TrainConfig(sigma_epochs=400, validation_fraction=0.05, bound_lines=0)  # not measured
    history = History()
    train_sigma(model, dataset, make_splits(dataset, config), config, history=history)
    print(f"lever_sigma {history.lever_sigma:.2f} N, machine {model.machine_sigma.tolist()}")
    assert history.lever_sigma == pytest.approx(FORCE, rel=0.1)
    assert float(model.lever_sigma[0]) == history.lever_sigma
    assert model.machine_sigma.max().item() < 0.02


def test_checkpoint_keeps_the_channel(tmp_path) -> None:
    """Saved and loaded, the force and the flag come back; a model without the flag has no
    such buffer (checkpoints from before the channel load unchanged)."""
    model = _lever_model(7.5)
    save(tmp_path / "m.pt", model, kind="ppann", extra={})
    loaded, payload = load(tmp_path / "m.pt")
    assert payload["config"]["sigma_lever"] is True
    assert float(loaded.lever_sigma[0]) == 7.5
    assert FusedHeads(loaded).lever_sigma == 7.5
    assert not hasattr(PPANN(), "lever_sigma")
    assert FusedHeads(PPANN()).lever_sigma == 0.0


def test_the_training_config_asks_for_the_channel() -> None:
    """The default training config builds the PPANN with the channel (since session 27);
    `TrainConfig(sigma_lever=False)` builds none."""
    from ppann.fit import new_model

    dataset = _force_dataset(episodes=1, seconds=0.1, seed=0)
    with_it = new_model(dataset, kind="ppann", config=TrainConfig())
    assert with_it.config.sigma_lever and float(with_it.lever_sigma[0]) == 0.0
    without = new_model(dataset, kind="ppann", config=TrainConfig(sigma_lever=False))
    assert not hasattr(without, "lever_sigma")


def test_the_force_draws_are_common_across_horizons() -> None:
    """A run of 80 steps is the first 80 steps of a run of 120 with the same seed, force and
    all: the robust loop's iterations and horizons share their random numbers."""
    model = _lever_model(10.0, z_sigma=0.01)
    short, long = (
        monte_carlo(model, [1.0, 0.0], np.full(steps, 0.5), n_samples=64, seed=4).samples
        for steps in (80, 120)
    )
    assert np.array_equal(short, long[:, :81])
    assert short[:, -1, 0].std() > 0
