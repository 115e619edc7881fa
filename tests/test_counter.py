"""Counter-based normals (ppann/counter.py): their distribution, and the kernel's equal to
NumPy's (ppann/kernel.py, ppann/montecarlo.py `normals="counter"`)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from common.threads import set_rollout_threads
from ppann import kernel
from ppann.counter import counter_normals, key_of, splitmix
from ppann.heads import FusedHeads
from ppann.model import PPANN, PPANNConfig
from ppann.montecarlo import monte_carlo, rollout
from tests.test_kernel import _trained_like

KEY = key_of(np.random.SeedSequence(20261127))


def _lever_model(white_inertia: str = "quotient") -> PPANN:
    model = _trained_like(PPANNConfig(sigma_lever=True, white_inertia=white_inertia))
    with torch.no_grad():
        model.lever_sigma.fill_(15.0)
    return model


def test_splitmix_gives_the_reference_outputs() -> None:
    """SplitMix64 seeded 1234567: its first outputs as published (Vigna's splitmix64.c, state
    += golden before each output)."""
    state = np.uint64(1234567) + np.arange(1, 4, dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15)
    assert [int(v) for v in splitmix(state)] == [
        6457827717110365317,
        3203168211198807973,
        9817491932198370423,
    ]


def test_the_normals_are_standard_normal_and_independent() -> None:
    """1.6 million normals (2000 samples x 200 steps x 4): mean, variance, the share below -3
    and beyond +-2 within 4 standard errors of N(0, 1)'s; the correlation between the four
    normals of a sample and step, between neighbouring samples and between neighbouring steps
    within 4 / sqrt(n) of 0."""
    z = counter_normals(KEY, samples=2000, steps=200)
    flat = z.ravel()
    n = flat.size
    assert abs(flat.mean()) < 4 / math.sqrt(n)
    assert abs(flat.var() - 1) < 4 * math.sqrt(2 / n)
    for share, p in ((np.mean(flat < -3), 0.0013499), (np.mean(np.abs(flat) > 2), 0.0455003)):
        assert abs(share - p) < 4 * math.sqrt(p * (1 - p) / n)
    pairs = [(z[..., a].ravel(), z[..., b].ravel()) for a in range(4) for b in range(a + 1, 4)]
    pairs += [(z[:, 1:, c].ravel(), z[:, :-1, c].ravel()) for c in range(4)]  # samples
    pairs += [(z[1:, :, c].ravel(), z[:-1, :, c].ravel()) for c in range(4)]  # steps
    for a, b in pairs:
        assert abs(np.corrcoef(a, b)[0, 1]) < 4 / math.sqrt(a.size)


def test_a_sample_s_sum_over_its_steps_is_normal() -> None:
    """What a trajectory integrates: each sample's sum over 100 steps, divided by 10, over
    40 000 samples, is N(0, 1) to 4 standard errors (variance, the share below -2.5) for each of
    the four normals, and the sums of neighbouring samples, and of samples 2^j apart, are
    uncorrelated to 4 / sqrt(n)."""
    z = counter_normals(KEY, samples=40_000, steps=100)
    n = z.shape[1]
    p = 0.0062097  # Φ(-2.5)
    for c in range(4):
        total = z[:, :, c].sum(axis=0) / 10
        assert abs(total.var() - 1) < 4 * math.sqrt(2 / n)
        assert abs(np.mean(total < -2.5) - p) < 4 * math.sqrt(p * (1 - p) / n)
        for lag in (1, 2, 64, 1024, 2**14):
            r = np.corrcoef(total[:-lag], total[lag:])[0, 1]
            assert abs(r) < 4 / math.sqrt(n - lag)


def test_a_sample_s_normals_do_not_depend_on_its_block_or_on_the_length() -> None:
    """Samples 3..12 from offset 3 equal samples 3..12 of a run from 0; fewer steps are a
    prefix; another key gives other numbers."""
    whole = counter_normals(KEY, samples=13, steps=6)
    assert np.array_equal(counter_normals(KEY, samples=10, steps=6, offset=3), whole[:, 3:])
    assert np.array_equal(counter_normals(KEY, samples=13, steps=2), whole[:2])
    assert not np.any(counter_normals(KEY + 1, samples=13, steps=6) == whole)
    with pytest.raises(ValueError, match="out of range"):
        counter_normals(KEY, samples=4, steps=2, offset=-1)


needs_kernel = pytest.mark.skipif(kernel.load() is None, reason="no C compiler")


@needs_kernel
@pytest.mark.parametrize("white_inertia", ["quotient", "linear"])
@pytest.mark.parametrize("held", [False, True])
def test_the_kernel_generates_numpys_counter_normals(held: bool, white_inertia: str) -> None:
    """With a key the kernel's rollout equals NumPy's rollout on counter_normals' arrays (to the
    float32 rounding of the speed networks), a draw per step and per trajectory, the slider
    force's channel and machine factors included, over the 2 pi wrap; z_J's draw in either
    form (PPANNConfig.white_inertia)."""
    heads = FusedHeads(_lever_model(white_inertia))
    n, steps = 300, 250
    tau = 1.5 * np.sin(np.linspace(0, 9, steps)) + 0.4
    factors = np.exp(0.05 * np.random.default_rng(4).standard_normal((n, 3)))
    drawn = counter_normals(KEY, samples=n, steps=1 if held else steps)
    reference = rollout(
        heads,
        [5.9, 8.0],
        tau,
        n_samples=n,
        eps=drawn[..., :3],
        lever_eps=drawn[..., 3],
        factors=factors,
        compiled=False,
    )
    options = {"n_samples": n, "key": KEY, "per_trajectory": held, "factors": factors}
    fast = rollout(heads, [5.9, 8.0], tau, **options)
    slow = rollout(heads, [5.9, 8.0], tau, **options, compiled=False)
    assert np.all(np.isfinite(fast))
    assert np.array_equal(slow, reference)
    np.testing.assert_allclose(fast[..., 0], reference[..., 0], rtol=0, atol=2e-6)
    np.testing.assert_allclose(fast[..., 1], reference[..., 1], rtol=0, atol=5e-5)


@needs_kernel
def test_counter_normals_are_the_same_bits_on_one_thread_and_on_three() -> None:
    """Each block generates its own samples' normals from their index: 1 and 3 threads agree
    bit for bit."""
    heads = FusedHeads(_lever_model())
    n = 3 * kernel.CHUNK_SAMPLES + 7
    runs = {}
    for threads in (1, 3):
        set_rollout_threads(threads)
        try:
            runs[threads] = rollout(heads, [0.3, 5.0], np.full(90, 0.9), n_samples=n, key=KEY)
        finally:
            set_rollout_threads(None)
    assert np.all(np.isfinite(runs[1])) and np.array_equal(runs[1], runs[3])


def test_monte_carlo_draws_counter_normals_under_the_white_childs_key() -> None:
    """monte_carlo(normals="counter") is the rollout under the white child's key (the machine
    factors from the machine child as with "stream"); "trajectory" holds one draw per run; an
    unknown source is refused."""
    heads = FusedHeads(_trained_like(PPANNConfig()))
    tau = np.full(60, 1.2)
    options = {"n_samples": 40, "seed": 5, "normals": "counter", "compiled": False}
    step = monte_carlo(heads, [0.0, 0.0], tau, mode="step", **options).samples
    white, _ = np.random.SeedSequence(5).spawn(2)
    expected = rollout(heads, [0.0, 0.0], tau, n_samples=40, key=key_of(white), compiled=False)
    assert np.array_equal(step, expected)
    held = monte_carlo(heads, [0.0, 0.0], tau, mode="trajectory", **options).samples
    expected = rollout(
        heads,
        [0.0, 0.0],
        tau,
        n_samples=40,
        key=key_of(white),
        per_trajectory=True,
        compiled=False,
    )
    assert np.array_equal(held, expected) and not np.allclose(held, step)
    with pytest.raises(ValueError, match="normals must be one of"):
        monte_carlo(heads, [0.0, 0.0], tau, normals="sobol")
