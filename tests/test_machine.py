"""The machine-level uncertainty model: the Monte-Carlo modes against each other, no divergence at
5σ, recovery of a known machine spread, and the marginal likelihood against a dense reference."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
import torch

from ppann.heads import FusedHeads
from ppann.losses import propagated_nll
from ppann.machine import EpisodeTerms, marginal_nll, sigma_upper, white_nll
from ppann.model import PPANN, PPANNConfig, constant_ppann
from ppann.montecarlo import monte_carlo
from ppann.train import History, TrainConfig, make_splits, train_sigma
from twin.dataset import Dataset

DT = 0.002
TAU = np.concatenate([np.full(60, 4.0), np.full(60, -3.0), np.full(29, 1.0)])


def _model(machine_sigma: tuple[float, float, float], terms: str = "augmented") -> PPANN:
    model = constant_ppann(
        z_mean=(0.1, -0.2, -0.9),
        z_sigma=(0.05, 0.3, 0.2),
        config=PPANNConfig(machine_terms=terms),
    )
    with torch.no_grad():
        model.machine_sigma.copy_(torch.tensor(machine_sigma, dtype=torch.float64))
    return model


def test_mixed_with_zero_machine_sigma_equals_step_exactly() -> None:
    model = _model((0.0, 0.0, 0.0))
    step = monte_carlo(model, [math.pi, 0.0], TAU, n_samples=64, mode="step", seed=4)
    mixed = monte_carlo(model, [math.pi, 0.0], TAU, n_samples=64, mode="mixed", seed=4)
    assert np.array_equal(step.samples, mixed.samples)


def test_mixed_with_zero_white_sigma_equals_per_trajectory_machines() -> None:
    """White σ exactly zero: each mixed trajectory is the mean model of one drawn machine,
    simulated here one by one with that machine's factors."""
    model = constant_ppann(
        z_mean=(0.1, -0.2, -0.9), z_sigma=(1e-300,) * 3, config=PPANNConfig(sigma_floor=1e-301)
    )
    with torch.no_grad():
        model.machine_sigma.copy_(torch.tensor((0.1, 0.2, 0.15), dtype=torch.float64))
    heads = FusedHeads(model)  # z + sigma eps == z to the last bit: no white noise
    compiled = {
        mode: monte_carlo(heads, [math.pi, 0.0], TAU, n_samples=16, mode=mode, seed=9).samples
        for mode in ("mixed", "machine")
    }
    assert np.array_equal(compiled["mixed"], compiled["machine"])
    # NumPy's rollout, whose arithmetic the loop below repeats bit for bit (the compiled one's
    # is bounded against it in tests/test_kernel.py)
    options = {"n_samples": 16, "seed": 9, "compiled": False}
    mixed = monte_carlo(heads, [math.pi, 0.0], TAU, mode="mixed", **options)
    machine = monte_carlo(heads, [math.pi, 0.0], TAU, mode="machine", **options)
    assert np.array_equal(mixed.samples, machine.samples)
    # The same machines, drawn as montecarlo draws them, simulated one at a time.
    _, machine_seq = np.random.SeedSequence(9).spawn(2)
    eta = 0.0 + np.array([0.1, 0.2, 0.15]) * np.random.default_rng(machine_seq).standard_normal(
        (16, 3)
    )
    for i in (0, 7, 15):
        theta, omega = np.array([math.pi]), np.array([0.0])
        factors = np.exp(eta[i : i + 1])
        for k, u in enumerate(TAU):
            mean, _ = heads(theta, omega)
            alpha = heads.acceleration(theta, omega, u, mean, factors=factors)
            theta, omega = theta + DT * omega, omega + DT * alpha
            assert mixed.samples[i, k + 1, 0] == theta[0]
    assert mixed.std[-1, 0] > 0.01  # the machines do differ


@pytest.mark.parametrize("terms", ["augmented", "prior"])
def test_no_machine_draw_diverges_at_five_sigma(terms: str) -> None:
    """Log-normal factors keep inertia, damping and stiffness positive ("prior": their prior
    parts): ±5σ machines of a wide spread (0.2 in log, 7× the paper twin's) stay finite and
    bounded over 1000 steps. (Forward Euler itself needs 2 J / B > dt; at 5σ of 0.2, J / B is
    5.5 ms against dt = 2 ms.)"""
    model = _model((0.2, 0.2, 0.2), terms)
    heads = FusedHeads(model)
    corners = np.array([[s1, s2, s3] for s1 in (-5, 5) for s2 in (-5, 5) for s3 in (-5, 5)])
    factors = np.exp(corners * heads.machine_sigma)
    theta, omega = np.full(8, math.pi), np.zeros(8)
    for _ in range(1000):
        mean, _ = heads(theta, omega)
        alpha = heads.acceleration(theta, omega, 5.0, mean, factors=factors)
        theta, omega = theta + DT * omega, omega + DT * alpha
    assert np.all(np.isfinite(theta)) and np.all(np.abs(omega) < 1e3)
    bands = monte_carlo(model, [math.pi, 0.0], np.full(1000, 5.0), n_samples=500, mode="mixed")
    assert np.all(np.isfinite(bands.samples))


def test_marginal_likelihood_equals_the_dense_gaussian() -> None:
    """Woodbury form == log N(r; 0, diag(s²) + D Σ Dᵀ) computed with dense matrices."""
    rng = np.random.default_rng(1)
    n, episodes = 40, 3
    residual = torch.from_numpy(rng.normal(size=n))
    derivative = torch.from_numpy(rng.normal(size=(n, 3)))
    design = torch.from_numpy(rng.normal(size=(n, 3)))
    sigma = torch.from_numpy(rng.uniform(0.2, 1.0, size=(n, 3)))
    machine = torch.tensor([0.3, 0.1, 0.5], dtype=torch.float64)
    episode = torch.from_numpy(np.repeat(np.arange(episodes), [10, 20, 10]))
    terms = EpisodeTerms.build(residual, derivative, design, episode)
    value = marginal_nll(terms, sigma, machine)
    total = dense_nll(residual, derivative, design, sigma, machine, episode)
    assert float(value) == pytest.approx(total / n, rel=1e-10)


def dense_nll(
    residual: torch.Tensor,
    derivative: torch.Tensor,
    design: torch.Tensor,
    sigma: torch.Tensor,
    spread: torch.Tensor,
    machine: torch.Tensor,
) -> float:
    """-log N(r; 0, diag(s²) + D Σ Dᵀ) summed over machines, each machine's samples (those of
    one value of `machine`) one dense Gaussian: the reference of the marginal likelihood."""
    total = 0.0
    for m in torch.unique(machine).tolist():
        idx = machine == m
        d = design[idx]
        cov = torch.diag(((derivative[idx] * sigma[idx]) ** 2).sum(-1) + 1e-12)
        cov = cov + d @ torch.diag(spread**2) @ d.T
        r = residual[idx]
        total += 0.5 * float(r @ torch.linalg.solve(cov, r) + torch.logdet(cov))
    return total


def test_blocks_of_one_sample_are_eq_9_and_blocks_stay_inside_episodes() -> None:
    """Blocks of one sample give eq. 9 bit for bit; blocks of 3 over episodes of 7 and 5 samples
    are 3, 3, 1 | 3, 2 samples long, and hold the sums of their samples."""
    rng = np.random.default_rng(2)
    n = 12
    residual = torch.from_numpy(rng.normal(size=n))
    derivative = torch.from_numpy(rng.normal(size=(n, 3)))
    sigma = torch.from_numpy(rng.uniform(0.2, 1.0, size=(n, 3)))
    episode = torch.from_numpy(np.repeat([0, 1], [7, 5]))
    single = EpisodeTerms.build(residual, derivative, derivative, episode)
    assert torch.equal(white_nll(single, sigma), propagated_nll(residual, derivative, sigma))
    blocks = EpisodeTerms.build(residual, derivative, derivative, episode, block_length=3)
    assert blocks.block.tolist() == [0, 0, 0, 1, 1, 1, 2, 3, 3, 3, 4, 4]
    assert blocks.machine.tolist() == [0, 0, 0, 1, 1]
    for b, (lo, hi) in enumerate([(0, 3), (3, 6), (6, 7), (7, 10), (10, 12)]):
        assert float(blocks.residual[b]) == pytest.approx(float(residual[lo:hi].sum()), abs=1e-12)
    variance = blocks.white_variance(sigma)
    per_sample = ((derivative * sigma) ** 2).sum(-1)
    assert float(variance[2]) == pytest.approx(float(per_sample[6]) + 1e-12, rel=1e-12)


@pytest.mark.parametrize(("block_length", "expected"), [(1, 1.25), (50, 0.25 + 1 / 50)])
def test_blocks_fit_the_low_frequency_power_of_a_blue_residual(
    block_length: int, expected: float
) -> None:
    """A residual e_k - 0.5 e_(k-1) (e white, unit variance) has one-step variance 1.25 but its
    sums over L samples have variance 0.25 L + 1: the constant white σ² that minimises the block
    likelihood is 1.25 with blocks of one (eq. 9) and 0.25 + 1/L with blocks of L, within the
    ~2 % standard error of 200 000 samples' variance estimate (4000 blocks at L = 50)."""
    rng = np.random.default_rng(5)
    n = 200_000
    e = rng.normal(size=n + 1)
    residual = torch.from_numpy(e[1:] - 0.5 * e[:-1])
    derivative = torch.zeros((n, 3), dtype=torch.float64)
    derivative[:, 0] = 1.0
    episode = torch.from_numpy(np.repeat(np.arange(4), n // 4))
    terms = EpisodeTerms.build(residual, derivative, derivative, episode, block_length=block_length)
    grid = np.linspace(0.5, 1.5, 201) * math.sqrt(expected)
    losses = [
        float(white_nll(terms, torch.full((n, 3), float(value), dtype=torch.float64)))
        for value in grid
    ]
    fitted = float(grid[int(np.argmin(losses))]) ** 2
    assert fitted == pytest.approx(expected, rel=0.05)


def _machines_dataset(
    *,
    episodes: int,
    seconds: float,
    spread: float,
    seed: int,
    column: int = 0,
    model: PPANN | None = None,
    extra: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
    runs: int = 1,
):
    """Episodes of a known PPANN (constant networks, `model`) whose machine factor of term
    `column` (0: inertia) is exp(eta) per machine, eta ~ N(0, spread²), and a small white torque
    noise (σ 0.02 N·m); `extra(theta, omega)`: a torque the machines get and the model has not
    (its own error, the same on every machine). `runs` > 1: each machine plays that many
    consecutive episodes, which the run record gives one `machine_id`; eta is per machine."""
    if model is None:
        model = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.01, 0.01, 0.01))
    heads = FusedHeads(model)
    rng = np.random.default_rng(seed)
    n = int(seconds / DT)
    eta = rng.normal(0.0, spread, episodes // runs)
    per_episode = np.repeat(eta, runs)
    levels = np.repeat(rng.uniform(-6, 6, (episodes, n // 50 + 1)), 50, axis=1)[:, :n]
    tau = np.stack([np.convolve(row, np.ones(10) / 10, mode="same") for row in levels])
    noise = rng.normal(0.0, 0.02, (episodes, n))
    theta, omega = np.empty((episodes, n)), np.zeros((episodes, n))
    theta[:, 0] = rng.uniform(0, 2 * np.pi, episodes)
    factors = np.ones((episodes, 3))
    factors[:, column] = np.exp(per_episode)
    for k in range(n - 1):  # all episodes at once
        mean, _ = heads(theta[:, k], omega[:, k])
        error = 0.0 if extra is None else extra(theta[:, k], omega[:, k])
        alpha = heads.acceleration(
            theta[:, k], omega[:, k], tau[:, k] + noise[:, k] + error, mean, factors=factors
        )
        theta[:, k + 1] = theta[:, k] + DT * omega[:, k]
        omega[:, k + 1] = omega[:, k] + DT * alpha
    episode = np.repeat(np.arange(episodes), n)
    theta, omega, tau = theta.ravel(), omega.ravel(), tau.ravel()
    dataset = Dataset(
        t=np.arange(len(theta)) * DT,
        episode=episode.astype(np.int64),
        theta=theta,
        omega=omega,
        tau=tau,
        slider_position=np.zeros(len(theta)),
        run={}
        if runs == 1
        else {"episodes": [{"index": e, "machine_id": e // runs} for e in range(episodes)]},
    )
    return dataset, model, eta


@pytest.fixture(scope="module")
def fitted_line():
    """Phase 2 on a synthetic line whose 40 machines differ in inertia only (log-spread 0.15)."""
    spread = 0.15
    dataset, truth_model, eta = _machines_dataset(episodes=40, seconds=2.0, spread=spread, seed=3)
    # the sigma networks' initial weights come from torch's global generator, which the tests
    # before this one advance; unseeded, phase 2 here depended on the test order: on 1 of 40
    # initialisations it left the damping's machine σ at 0.001 where its profile NLL is 360
    # lower at 0.005, and the likelihood-ratio bound read off that profile was the grid's end
    torch.manual_seed(0)
    model, split = _phase_two(truth_model, dataset, PPANNConfig(sigma_hidden=4))
    machines = int(np.unique(dataset.episode[:split]).size)
    return model, eta, machines


def _phase_two(
    truth: PPANN, dataset: Dataset, config: PPANNConfig, *, history: History | None = None, **train
) -> tuple[PPANN, int]:
    """A PPANN of `config` with `truth`'s mean networks and fresh sigma networks, phase 2 fitted
    on `dataset` (`train`: TrainConfig options); and the first sample of its validation split."""
    model = PPANN(config)
    model.load_state_dict(
        {k: v for k, v in truth.state_dict().items() if not k.startswith("sigma_nets")}
        | {k: v for k, v in model.state_dict().items() if k.startswith("sigma_nets")}
    )
    # the bounds' calibration (ppann/inversion.py) only where a test asks for it: not what these
    # tests measure, and on 30 machines at 400 epochs it took 110 s of a test's 115
    defaults = {"sigma_epochs": 400, "validation_fraction": 0.05, "bound_lines": 0}
    options = TrainConfig(**(defaults | train))
    splits = make_splits(dataset, options)
    train_sigma(model, dataset, splits, options, history=history or History())
    return model, splits.split


def test_machine_sigma_recovered_within_20_percent(fitted_line) -> None:
    """The fitted machine σ of the inertia is within 20 % of the spread of the 40 machines in the
    data (their sample σ; with 40 machines it has itself ~11 % standard error around 0.15, so that
    is the known answer), and the damping and stiffness get next to none."""
    model, eta, _ = fitted_line
    drawn = float(np.std(eta, ddof=1))
    print(f"drawn {drawn:.4f}, fitted {model.machine_sigma.tolist()}")
    assert model.machine_sigma[0].item() == pytest.approx(drawn, rel=0.2)
    assert model.machine_sigma[1].item() < 0.3 * drawn
    assert model.machine_sigma[2].item() < 0.3 * drawn


def test_population_uncertainty_matches_directly_observed_machines(fitted_line) -> None:
    """With little white noise each machine's inertia factor is as good as observed, and the
    population summaries take their textbook values for E directly observed normal draws with
    estimate s: the line's mean log-factor has standard error s / sqrt(E), and the
    likelihood-ratio upper bound u of σ solves E (log(u / s) + s² / (2 u²) − 1/2) = z² / 2."""
    model, _, machines = fitted_line
    s = model.machine_sigma[0].item()
    se = math.sqrt(model.common_covariance[0, 0].item())
    assert se == pytest.approx(s / math.sqrt(machines), rel=0.1)
    assert int(model.spread_machines) == machines  # what the OCP's bounds count (test_small_sample)
    z = 1.96
    upper = sigma_upper(model.machine_sigma.numpy(), model.machine_profile.numpy(), 0.5 * z * z)
    lo, hi = s, 3 * s  # bisection of the closed form
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        rise = machines * (math.log(mid / s) + s * s / (2 * mid * mid) - 0.5)
        lo, hi = (mid, hi) if rise < 0.5 * z * z else (lo, mid)
    print(f"machines {machines}, s {s:.4f}, upper {upper[0]:.4f}, closed form {lo:.4f}")
    assert upper[0] == pytest.approx(lo, rel=0.05)
    assert upper[0] > 1.15 * s
    # z = 0: the estimate itself; a component the data show none of gets a small bound.
    assert np.array_equal(
        sigma_upper(model.machine_sigma.numpy(), model.machine_profile.numpy(), 0.0),
        model.machine_sigma.numpy(),
    )
    assert upper[1] < 0.3 * s and upper[2] < 0.3 * s


def test_prior_machine_terms_shift_z_by_the_factor_minus_one() -> None:
    """With `machine_terms` "prior" a machine's factor f scales the prior's physical term alone:
    eq. 14 with z replaced by z + f - 1 (PPANN.acceleration, torch), to rounding; "augmented"
    multiplies the whole term, (1 + z) f."""
    z_mean = (0.3, 0.5, -0.9)
    rng = np.random.default_rng(2)
    theta, omega = rng.uniform(0, 2 * np.pi, 50), rng.uniform(-30, 30, 50)
    tau, factors = rng.uniform(-4, 4, 50), np.exp(0.2 * rng.standard_normal((50, 3)))
    z = np.tile(z_mean, (50, 1))
    for terms, expected_z, scale in (
        ("prior", z + factors - 1, np.ones((50, 3))),
        ("augmented", z, factors),
    ):
        model = constant_ppann(
            z_mean=z_mean, z_sigma=(0.01,) * 3, config=PPANNConfig(machine_terms=terms)
        )
        got = FusedHeads(model).acceleration(theta, omega, tau, z, factors=factors)
        j, b, k = (float(v) for v in model.physical.detach())
        angle = np.remainder(theta, 2 * np.pi)
        reference = (
            tau
            - b * (1 + expected_z[:, 1]) * scale[:, 1] * omega
            - k * (1 + expected_z[:, 2]) * scale[:, 2] * angle
        ) / (j * (1 + expected_z[:, 0]) * scale[:, 0])
        np.testing.assert_allclose(got, reference, rtol=1e-12)
        if terms == "prior":  # eq. 14 itself, in torch, at the shifted z
            inputs = (torch.tensor(v) for v in (theta, omega, tau, expected_z))
            torch_prior = model.acceleration(*inputs).numpy()
            np.testing.assert_allclose(got, torch_prior, rtol=1e-12)


@pytest.mark.parametrize("terms", ["prior", "augmented"])
def test_a_damping_line_is_read_on_the_term_the_machines_scale(terms: str) -> None:
    """Machines differ in the prior's damping alone (log-spread 0.15) while the B network's
    correction makes the damping term 1.5 B_m: a model whose machine factors scale the prior's
    term ("prior") recovers the drawn spread within 20 %; one whose factors scale the whole term
    ("augmented") reads the same torques as 1/1.5 of it, the damping term's prior share."""
    truth = constant_ppann(
        z_mean=(0.0, 0.5, -0.9),
        z_sigma=(0.01, 0.01, 0.01),
        config=PPANNConfig(machine_terms="prior"),
    )
    dataset, truth, eta = _machines_dataset(
        episodes=30, seconds=2.0, spread=0.15, seed=5, column=1, model=truth
    )
    torch.manual_seed(0)
    model, split = _phase_two(truth, dataset, PPANNConfig(sigma_hidden=4, machine_terms=terms))
    present = np.unique(dataset.episode[:split])
    drawn = float(np.std(eta[present], ddof=1))
    expected = drawn if terms == "prior" else drawn / 1.5
    print(f"{terms}: drawn {drawn:.4f}, fitted {model.machine_sigma.tolist()}")
    assert model.machine_sigma[1].item() == pytest.approx(expected, rel=0.2)
    assert model.machine_sigma[0].item() < 0.3 * expected


def test_a_few_machines_calibrate_their_bounds_reproducibly(tmp_path) -> None:
    """Phase 2 on 6 machines calibrates the line's bounds (ppann/inversion.py): the candidates
    start at the fitted spread and rise, the rises' quantiles are not negative, the same seed
    gives the same calibration to the bit, and the checkpoint and the OCP's heads carry it."""
    from ppann import checkpoint
    from ppann.inversion import CALIBRATED_MACHINES, calibration_of, line_bounds

    dataset, truth_model, _ = _machines_dataset(episodes=6, seconds=2.0, spread=0.15, seed=5)
    found = []
    for _ in range(2):
        torch.manual_seed(0)
        model, _ = _phase_two(
            truth_model, dataset, PPANNConfig(sigma_hidden=4), sigma_epochs=30, bound_lines=2000
        )
        found.append(calibration_of(model))
    first, again = found
    assert first is not None and int(model.spread_machines) <= CALIBRATED_MACHINES
    assert np.array_equal(first.candidates[:, 0], model.machine_sigma.numpy())
    assert np.all(np.diff(first.candidates, axis=1) >= 0)
    assert np.all(first.rise_tail >= 0)
    assert np.array_equal(first.rise_tail, again.rise_tail)
    assert np.array_equal(first.mean_tail, again.mean_tail)
    path = tmp_path / "m.pt"
    checkpoint.save(path, model, kind="ppann", extra={})
    loaded, _ = checkpoint.load(path)
    assert np.array_equal(FusedHeads(loaded).calibration.rise_tail, first.rise_tail)
    upper, radius, calibrated = line_bounds(
        machine_sigma=model.machine_sigma.numpy(),
        profile=model.machine_profile.numpy(),
        machines=int(model.spread_machines),
        confidence=0.95,
        calibration=first,
    )
    assert calibrated and np.all(upper >= model.machine_sigma.numpy()) and np.all(radius > 0)


def test_many_machines_keep_the_exact_levels() -> None:
    """40 machines (above ppann/inversion.py CALIBRATED_MACHINES): no calibration kept even where
    asked; 6 machines: none where bound_lines is 0."""
    from ppann.inversion import CALIBRATED_MACHINES, calibration_of

    options = {"sigma_epochs": 30}
    for episodes, lines in ((40, 2000), (6, 0)):
        dataset, truth, _ = _machines_dataset(episodes=episodes, seconds=2.0, spread=0.15, seed=5)
        torch.manual_seed(0)
        config = PPANNConfig(sigma_hidden=4)
        model, _ = _phase_two(truth, dataset, config, bound_lines=lines, **options)
        assert (int(model.spread_machines) > CALIBRATED_MACHINES) == (episodes == 40)
        assert calibration_of(model) is None and FusedHeads(model).calibration is None
