"""The prior's Coulomb friction torque (`PPANNConfig.coulomb`): the torque balance by hand, the
same term on every path (torch, NumPy, the compiled kernel, CasADi), phase 1 recovers a known
level, and a checkpoint keeps it."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from control.dynamics import CasadiPPANN
from ppann import kernel
from ppann.checkpoint import load, save
from ppann.losses import propagated_terms
from ppann.machine import machine_design
from ppann.model import PPANN, FusedHeads, PPANNConfig
from ppann.montecarlo import rollout
from ppann.train import History, TrainConfig, make_splits, train_mean
from twin.dataset import Dataset

DT = 0.002


def _model(level: float, **config) -> PPANN:
    """A PPANN with the Coulomb term at `level` N·m and seeded networks of order-1 outputs."""
    torch.manual_seed(4)
    model = PPANN(PPANNConfig(coulomb=True, **config))
    with torch.no_grad():
        model.coulomb_log.fill_(math.log(level / model.config.coulomb_m))
        for net in [*model.mean_nets.values(), *model.sigma_nets.values()]:
            net[2].weight.mul_(3.0)
    return model.eval()


def test_the_torque_balance_by_hand() -> None:
    """alpha = (tau - C tanh(omega / speed) - B (1 + z_B) omega - K (1 + z_K) theta_mod) /
    (J (1 + z_J)); the residual of eq. 9 is zero at that alpha."""
    model = _model(0.03)
    theta = torch.tensor([0.3, 7.0, -1.0], dtype=torch.float64)
    omega = torch.tensor([0.05, -2.0, 30.0], dtype=torch.float64)
    tau = torch.tensor([0.1, -0.4, 2.0], dtype=torch.float64)
    z = torch.tensor([[0.2, -0.1, 0.05]] * 3, dtype=torch.float64)
    j, b, k = model.physical.detach()
    friction = 0.03 * torch.tanh(omega / 0.1)
    expected = (
        tau - friction - b * 0.9 * omega - k * 1.05 * torch.remainder(theta, 2 * math.pi)
    ) / (j * 1.2)
    with torch.no_grad():
        got = model.acceleration(theta, omega, tau, z)
        assert torch.allclose(got, expected, rtol=1e-14, atol=0)
        alpha = model.step(torch.stack([theta, omega], -1), tau)[:, 1].sub(omega).div(DT)
        residual, _ = propagated_terms(model, theta, omega, tau, alpha)
    assert residual.abs().max() < 1e-12


@pytest.mark.parametrize("terms", ["augmented", "prior"])
def test_a_machines_damping_factor_scales_its_whole_friction(terms: str) -> None:
    """A machine with damping factor f: f C tanh(omega / speed) beside its damping term, in
    FusedHeads' acceleration and in phase 2's design (the residual's derivative in eta_B at 0:
    the damping column plus C tanh)."""
    model = _model(0.03, machine_terms=terms)
    heads = FusedHeads(model)
    theta, omega = np.array([0.3, 4.0]), np.array([0.2, -3.0])
    z = np.array([[0.1, -0.2, 0.05], [0.0, 0.3, -0.1]])
    f = 1.1
    friction = 0.03 * np.tanh(omega / 0.1)
    j, b, k = heads.j, heads.b, heads.k
    damping = b * ((1 + z[:, 1]) * f if terms == "augmented" else z[:, 1] + f) * omega
    expected = (0.5 - f * friction - damping - k * (1 + z[:, 2]) * theta) / (j * (1 + z[:, 0]))
    factors = np.array([[1.0, f, 1.0]] * 2)
    got = heads.acceleration(theta, omega, 0.5, z, factors=factors)
    np.testing.assert_allclose(got, expected, rtol=1e-13, atol=0)
    t, w = torch.from_numpy(theta), torch.from_numpy(omega)
    derivative = torch.stack([j * t, b * w, k * t], -1)  # any dr/dz will do
    with torch.no_grad():
        design = machine_design(model, t, w, derivative).numpy()
        zb = model.z_mean(t, w)[:, 1].numpy()
    column = b * omega * (1 + zb if terms == "augmented" else 1) + friction
    np.testing.assert_allclose(design[:, 1], column, rtol=1e-13, atol=0)


def test_numpy_kernel_and_casadi_equal_torch() -> None:
    """The same Coulomb term on every path: FusedHeads' acceleration and the Monte-Carlo rollout
    (NumPy and compiled) follow the torch model's mean; the CasADi step equals it to 1e-9."""
    model = _model(0.04)
    heads = FusedHeads(model)
    assert heads.coulomb == pytest.approx(0.04, rel=1e-14)
    tau = 0.05 * np.sin(np.linspace(0, 12, 300))  # slow, through omega = 0 many times
    x0 = np.array([2.0, 0.0])
    with torch.no_grad():
        states = [torch.from_numpy(x0)]
        for u in tau:
            states.append(model.step(states[-1], torch.tensor(u, dtype=torch.float64)))
        mean = torch.stack(states).numpy()
    paths = [False] + ([True] if kernel.load() is not None else [])
    for compiled in paths:
        runs = rollout(heads, x0, tau, n_samples=3, eps=np.zeros((300, 3, 3)), compiled=compiled)
        np.testing.assert_allclose(runs[0], mean, rtol=0, atol=2e-5)
    exported = CasadiPPANN(model)
    rng = np.random.default_rng(1)
    for theta, omega, u in zip(
        rng.uniform(-8, 8, 50), rng.uniform(-1, 1, 50), rng.uniform(-1, 1, 50), strict=True
    ):
        with torch.no_grad():
            want = model.step(torch.tensor([theta, omega]), torch.tensor(u)).numpy()
        got = exported.step([theta, omega], u).full().ravel()
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-9)
    # the term moves the motion: without it the same torque gives another trajectory
    assert np.abs(mean[-1, 0] - _without(model, x0, tau)[-1, 0]) > 0.05


def _without(model: PPANN, x0: np.ndarray, tau: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        model.coulomb_log.fill_(-60.0)  # C ~ 1e-28 N·m
        states = [torch.from_numpy(x0)]
        for u in tau:
            states.append(model.step(states[-1], torch.tensor(u, dtype=torch.float64)))
    return torch.stack(states).numpy()


def _known_system(seconds: float, level: float) -> Dataset:
    """J(θ) = 3e-3 (1 + 0.5 sin² θ), viscous 0.08, Coulomb level · tanh(ω / 0.1), load
    0.3 sin θ, Euler at 2 ms, under slow random torque levels that stop and reverse the motor."""
    rng = np.random.default_rng(0)
    n = int(seconds / DT)
    levels = np.repeat(rng.uniform(-0.6, 0.6, n // 200 + 1), 200)[:n]
    tau = np.convolve(levels, np.ones(50) / 50, mode="same")
    theta, omega = np.empty(n), np.empty(n)
    theta[0], omega[0] = 1.0, 0.0
    for k in range(n - 1):
        inertia = 3e-3 * (1 + 0.5 * np.sin(theta[k]) ** 2)
        load = 0.08 * omega[k] + level * np.tanh(omega[k] / 0.1) + 0.3 * np.sin(theta[k])
        theta[k + 1] = theta[k] + DT * omega[k]
        omega[k + 1] = omega[k] + DT * (tau[k] - load) / inertia
    return Dataset(
        t=np.arange(n) * DT,
        episode=np.zeros(n, dtype=np.int64),
        theta=theta,
        omega=omega,
        tau=tau,
        slider_position=np.zeros(n),
    )


def _friction_ratio(model: PPANN, speed: float) -> float:
    """The model's speed-dependent torque at `speed` (its torque balance at alpha = 0, tau = 0
    less the same at omega = 0, averaged over a turn) over the known system's friction."""
    theta = torch.linspace(0, 2 * math.pi, 64, dtype=torch.float64)
    zero = torch.zeros_like(theta)

    def torque(omega: torch.Tensor) -> torch.Tensor:
        z = model.z_mean(theta, omega)
        inertia = model.physical[0] * (1 + z[:, 0])
        return -model.acceleration(theta, omega, zero, z) * inertia

    with torch.no_grad():
        rise = float((torque(torch.full_like(theta, speed)) - torque(zero)).mean())
    return rise / (0.08 * speed + 0.03 * math.tanh(speed / 0.1))


def test_phase_1_learns_the_friction_at_crawl_speeds() -> None:
    """Phase 1 on a system with a 0.03 N·m Coulomb torque beside its viscous 0.08 N·m·s/rad: at
    0.3 and 0.5 rad/s the model's friction is within 30 % of the truth with the term, and more
    than 30 % short without it (the B network's B_m (1 + z_B) omega vanishes with omega; measured
    +26 % / +20 % against -49 % / -35 %). The level itself is not identified apart from z_B away
    from the crawl (0.043 N·m fitted here): the test holds the torque, not the split."""
    data = _known_system(20.0, 0.03)
    config = TrainConfig(
        max_epochs=30, patience=30, validation_fraction=0.1, batch_size=256, lr=1e-2
    )
    splits = make_splits(data, config)
    for coulomb in (True, False):
        torch.manual_seed(0)
        model = PPANN(PPANNConfig(coulomb=coulomb))
        train_mean(model, splits, config, history=History())
        for speed in (0.3, 0.5):
            error = abs(_friction_ratio(model, speed) - 1)
            assert (error < 0.3) if coulomb else (error > 0.3), (coulomb, speed, error)


def test_a_checkpoint_keeps_the_level(tmp_path) -> None:
    model = _model(0.027, mean_hidden=20)
    save(tmp_path / "m.pt", model, kind="ppann", extra={"history": {}})
    loaded, _ = load(tmp_path / "m.pt")
    assert loaded.config.coulomb is True
    assert float(loaded.coulomb) == pytest.approx(0.027, rel=1e-14)
    plain = PPANN(PPANNConfig(mean_hidden=20))
    save(tmp_path / "p.pt", plain, kind="ppann", extra={"history": {}})
    old = torch.load(tmp_path / "p.pt", weights_only=True)
    del old["config"]["coulomb"]  # saved before the option: no Coulomb term
    torch.save(old, tmp_path / "old.pt")
    assert load(tmp_path / "old.pt")[0].config.coulomb is False
    assert float(load(tmp_path / "old.pt")[0].coulomb) == 0.0
