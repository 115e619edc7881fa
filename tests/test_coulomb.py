"""The prior's Coulomb friction (`PPANNConfig.coulomb`, ppann/friction.py): the slider's slope
against the kinematics, the torque balance by hand, a machine's damping factor on it, the same
term on every path (torch, NumPy, the compiled kernel, CasADi), phase 1 learns a known friction,
and a checkpoint keeps it."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
import torch

from control.dynamics import CasadiPPANN
from ppann import kernel
from ppann.checkpoint import load, save
from ppann.heads import FusedHeads
from ppann.losses import propagated_terms
from ppann.machine import machine_design
from ppann.model import PPANN, PPANNConfig
from ppann.montecarlo import rollout
from ppann.train import History, TrainConfig, make_splits, train_mean
from tests.test_ppann import synthetic
from twin.dataset import Dataset
from twin.geometry import PAPER

DT = 0.002


def _model(motor: float, load: float, **config) -> PPANN:
    """A PPANN with Coulomb motor torque `motor` N·m and slider force `load` N, and seeded
    networks of order-1 outputs."""
    torch.manual_seed(4)
    model = PPANN(PPANNConfig(coulomb=True, **config))
    c = model.config
    with torch.no_grad():
        model.coulomb_log.copy_(
            torch.tensor(
                [math.log(motor / c.coulomb_m), math.log(load / c.coulomb_load)],
                dtype=torch.float64,
            )
        )
        for net in [*model.mean_nets.values(), *model.sigma_nets.values()]:
            net[2].weight.mul_(3.0)
    return model.eval()


def _friction(theta: np.ndarray, omega: np.ndarray, motor: float, load: float) -> np.ndarray:
    """C tanh(omega / 0.1) + F x' tanh(x' omega / (0.1 l1)), x' `Geometry.slider_slope`."""
    xp = PAPER.slider_slope(theta)
    return motor * np.tanh(omega / 0.1) + load * xp * np.tanh(xp * omega / (0.1 * 0.05))


def test_the_slider_slope_is_the_kinematics_derivative_in_every_library() -> None:
    theta = np.linspace(-7, 7, 301)
    h = 1e-6  # central differences of the slider's position
    want = (PAPER.slider_position(theta + h) - PAPER.slider_position(theta - h)) / (2 * h)
    np.testing.assert_allclose(PAPER.slider_slope(theta), want, rtol=0, atol=1e-9)
    with torch.no_grad():
        got = PAPER.slider_slope(torch.from_numpy(theta), torch).numpy()
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    x = ca.SX.sym("x")
    function = ca.Function("slope", [x], [PAPER.slider_slope(x, ca)])
    np.testing.assert_allclose(function(theta).full().ravel(), want, rtol=0, atol=1e-9)
    assert PAPER.slider_slope(0.0) == 0.0 and abs(PAPER.slider_slope(math.pi)) < 1e-17


def test_the_torque_balance_by_hand() -> None:
    """alpha = (tau - friction - B (1 + z_B) omega - K (1 + z_K) theta_mod) / (J (1 + z_J)); the
    residual of eq. 9 is zero at that alpha."""
    model = _model(0.03, 1.5)
    theta = np.array([0.3, 7.0, -1.0, 0.0])
    omega = np.array([0.05, -2.0, 30.0, 0.2])
    tau = torch.tensor([0.1, -0.4, 2.0, 0.3], dtype=torch.float64)
    z = torch.tensor([[0.2, -0.1, 0.05]] * 4, dtype=torch.float64)
    j, b, k = model.physical.detach()
    t, w = torch.from_numpy(theta), torch.from_numpy(omega)
    friction = torch.from_numpy(_friction(theta, omega, 0.03, 1.5))
    expected = (tau - friction - b * 0.9 * w - k * 1.05 * torch.remainder(t, 2 * math.pi)) / (
        j * 1.2
    )
    with torch.no_grad():
        got = model.acceleration(t, w, tau, z)
        assert torch.allclose(got, expected, rtol=1e-12, atol=0)
        alpha = model.step(torch.stack([t, w], -1), tau)[:, 1].sub(w).div(DT)
        residual, _ = propagated_terms(model, t, w, tau, alpha)
    assert residual.abs().max() < 1e-12


@pytest.mark.parametrize("terms", ["augmented", "prior"])
def test_a_machines_damping_factor_scales_its_whole_friction(terms: str) -> None:
    """A machine with damping factor f: f times the Coulomb friction beside its damping term, in
    FusedHeads' acceleration and in phase 2's design (the residual's derivative in eta_B at 0:
    the damping column plus the friction)."""
    model = _model(0.03, 1.5, machine_terms=terms)
    heads = FusedHeads(model)
    theta, omega = np.array([0.3, 4.0]), np.array([0.2, -3.0])
    z = np.array([[0.1, -0.2, 0.05], [0.0, 0.3, -0.1]])
    f = 1.1
    friction = _friction(theta, omega, 0.03, 1.5)
    j, b, k = heads.j, heads.b, heads.k
    damping = b * ((1 + z[:, 1]) * f if terms == "augmented" else z[:, 1] + f) * omega
    expected = (0.5 - f * friction - damping - k * (1 + z[:, 2]) * theta) / (j * (1 + z[:, 0]))
    factors = np.array([[1.0, f, 1.0]] * 2)
    got = heads.acceleration(theta, omega, 0.5, z, factors=factors)
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=0)
    t, w = torch.from_numpy(theta), torch.from_numpy(omega)
    derivative = torch.stack([j * t, b * w, k * t], -1)  # any dr/dz will do
    with torch.no_grad():
        design = machine_design(model, t, w, derivative).numpy()
        zb = model.z_mean(t, w)[:, 1].numpy()
    column = b * omega * (1 + zb if terms == "augmented" else 1) + friction
    np.testing.assert_allclose(design[:, 1], column, rtol=1e-12, atol=0)


def test_numpy_kernel_and_casadi_equal_torch() -> None:
    """The same friction on every path: the Monte-Carlo rollout (NumPy and compiled) follows the
    torch model's mean; the CasADi step equals it to 1e-9."""
    model = _model(0.04, 1.2)
    heads = FusedHeads(model)
    assert heads.coulomb == pytest.approx([0.04, 1.2], rel=1e-14)
    tau = 0.05 * np.sin(np.linspace(0, 12, 300))  # slow, through omega = 0 many times
    x0 = np.array([2.0, 0.0])
    mean = _mean(model, x0, tau)
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
    with torch.no_grad():
        model.coulomb_log.fill_(-60.0)  # C, F ~ 1e-27
    assert np.abs(mean[-1, 0] - _mean(model, x0, tau)[-1, 0]) > 0.05


def _mean(model: PPANN, x0: np.ndarray, tau: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        states = [torch.from_numpy(x0)]
        for u in tau:
            states.append(model.step(states[-1], torch.tensor(u, dtype=torch.float64)))
    return torch.stack(states).numpy()


MOTOR, LOAD = 0.03, 1.5
"""The known system's Coulomb torque (N·m) and slider force (N): the twin's MJCF values."""


def _viscous(theta: np.ndarray | float, omega: np.ndarray | float) -> np.ndarray | float:
    return 0.08 * omega + 8.0 * PAPER.slider_slope(np.asarray(theta, float)) ** 2 * omega


def _known_system(seconds: float) -> Dataset:
    """tests/test_ppann.py's known ODE with the twin's viscous motor and slider damping and its
    Coulomb motor torque and slider force (`_friction`) for friction, under slow torque levels
    (±0.6 N·m, 200 samples) that stop and reverse the motor."""

    def friction(theta: float, omega: float) -> float:
        coulomb = _friction(np.array([theta]), np.array([omega]), MOTOR, LOAD)[0]
        return _viscous(theta, omega) + coulomb

    return synthetic(seconds, amplitude=0.6, hold=200, friction=friction)


def _friction_ratio(model: PPANN, theta: float, speed: float) -> float:
    """The model's speed-dependent torque at (theta, speed) (its torque balance at alpha = 0,
    tau = 0 less the same at omega = 0) over the known system's."""
    angle = torch.tensor([theta], dtype=torch.float64)
    zero = torch.zeros(1, dtype=torch.float64)

    def torque(omega: float) -> float:
        w = torch.tensor([omega], dtype=torch.float64)
        z = model.z_mean(angle, w)
        inertia = model.physical[0] * (1 + z[:, 0])
        return float(-model.acceleration(angle, w, zero, z) * inertia)

    with torch.no_grad():
        rise = torque(speed) - torque(0.0)
    truth = _viscous(theta, speed) + _friction(np.array([theta]), np.array([speed]), MOTOR, LOAD)
    return rise / float(truth[0])


def test_phase_1_learns_the_friction_at_crawl_speeds() -> None:
    """Phase 1 on a system with the twin's Coulomb motor torque and slider force: at 0.3 rad/s,
    mid-stroke and near top dead centre, the model's friction is within 30 % of the truth with
    the term and more than 30 % off without it (the B network's B_m (1 + z_B) omega vanishes with
    omega)."""
    data = _known_system(20.0)
    config = TrainConfig(
        max_epochs=30, patience=30, validation_fraction=0.1, batch_size=256, lr=1e-2
    )
    splits = make_splits(data, config)
    for coulomb in (True, False):
        torch.manual_seed(0)
        model = PPANN(PPANNConfig(coulomb=coulomb))
        train_mean(model, splits, config, history=History())
        for theta in (0.2, math.pi / 2):
            error = abs(_friction_ratio(model, theta, 0.3) - 1)
            assert (error < 0.3) if coulomb else (error > 0.3), (coulomb, theta, error)


def test_a_checkpoint_keeps_the_levels(tmp_path) -> None:
    model = _model(0.027, 1.3, mean_hidden=20)
    save(tmp_path / "m.pt", model, kind="ppann", extra={"history": {}})
    loaded, _ = load(tmp_path / "m.pt")
    assert loaded.config.coulomb is True
    np.testing.assert_allclose(loaded.coulomb.detach().numpy(), [0.027, 1.3], rtol=1e-14)
    plain = PPANN(PPANNConfig(mean_hidden=20))
    save(tmp_path / "p.pt", plain, kind="ppann", extra={"history": {}})
    old = torch.load(tmp_path / "p.pt", weights_only=True)
    del old["config"]["coulomb"]  # saved before the option: no Coulomb friction
    torch.save(old, tmp_path / "old.pt")
    assert load(tmp_path / "old.pt")[0].config.coulomb is False
    assert not load(tmp_path / "old.pt")[0].coulomb.any()
