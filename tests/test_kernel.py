"""The Monte-Carlo's compiled rollout (ppann/kernel.py) against NumPy's (ppann/montecarlo.py)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from common.threads import set_rollout_threads
from ppann import kernel
from ppann.heads import FusedHeads
from ppann.model import PPANN, PPANNConfig, constant_ppann
from ppann.montecarlo import Feedback, monte_carlo, rollout

pytestmark = pytest.mark.skipif(kernel.load() is None, reason="no C compiler on this machine")


def _trained_like(config: PPANNConfig) -> PPANN:
    """A PPANN with random (seeded) networks of trained magnitude: z_mean of a few tenths, z_sigma
    of a few hundredths, every network bent by its tanh."""
    torch.manual_seed(7)
    model = PPANN(config)
    with torch.no_grad():
        for nets, scale, bias in ((model.mean_nets, 0.05, 0.0), (model.sigma_nets, 0.3, -3.0)):
            for net in nets.values():
                net[0].weight.mul_(3.0)
                net[2].weight.mul_(scale)
                net[2].bias.fill_(bias)
        model.machine_sigma.copy_(torch.tensor([0.02, 0.05, 0.03]))
    return model.eval()


CASES = {
    "paper": PPANNConfig(),
    "sigma_wrap": PPANNConfig(sigma_wrap=True),
    "sigma_speed": PPANNConfig(sigma_speed=True),
    "physics": PPANNConfig(use_networks=False),
    "machine_prior": PPANNConfig(machine_terms="prior"),
    "coulomb": PPANNConfig(coulomb=True, sigma_wrap=True),
    "mean_wrap": PPANNConfig(mean_wrap=True, sigma_wrap=True),
    "linear_inertia": PPANNConfig(white_inertia="linear", sigma_wrap=True),
    "linear_inertia_prior": PPANNConfig(white_inertia="linear", machine_terms="prior"),
    "trapezoid": PPANNConfig(angle_update="trapezoid", mean_wrap=True, white_inertia="linear"),
}


@pytest.mark.parametrize("name", sorted(CASES))
@pytest.mark.parametrize("mode", ["step", "mixed", "machine"])
def test_compiled_rollout_equals_numpy_to_float32_rounding(name: str, mode: str) -> None:
    """Every architecture and Monte-Carlo mode, open loop: the two paths agree to ~1e-6 over 250
    steps across the 2 pi wrap (the speed networks run in float32 on both, summed in another
    order), and the compiled one is deterministic bit for bit."""
    heads = FusedHeads(_trained_like(CASES[name]))
    tau = 1.5 * np.sin(np.linspace(0, 9, 250)) + 0.4
    args = ([5.9, 8.0], tau)
    options = {"n_samples": 257, "mode": mode, "seed": 3}
    compiled = monte_carlo(heads, *args, **options)
    again = monte_carlo(heads, *args, **options)
    assert np.array_equal(compiled.samples, again.samples)
    crossed = compiled.samples[:, -1, 0] - compiled.samples[:, 0, 0]
    assert np.abs(crossed).min() > 2 * np.pi  # every run goes over the wrap
    rng = np.random.default_rng(0)
    eps = rng.standard_normal((250, 257, 3)) if mode != "machine" else None
    factors = np.exp(0.05 * rng.standard_normal((257, 3))) if mode != "step" else None
    fast, slow = (
        rollout(heads, [5.9, 8.0], tau, n_samples=257, eps=eps, factors=factors, compiled=c)
        for c in (True, False)
    )
    assert np.all(np.isfinite(fast))
    np.testing.assert_allclose(fast[..., 0], slow[..., 0], rtol=0, atol=2e-6)
    np.testing.assert_allclose(fast[..., 1], slow[..., 1], rtol=0, atol=5e-5)


def test_compiled_rollout_under_feedback_and_saturation_equals_numpy() -> None:
    """Closed loop under a tracking law whose torque saturates on some samples."""
    heads = FusedHeads(_trained_like(PPANNConfig(sigma_wrap=True)))
    tau = np.full(120, 0.8)
    plan = np.stack([np.linspace(1.0, 6.0, 121), np.full(121, 20.0)], axis=1)
    law = Feedback(plan, np.tile([30.0, 1.0], (121, 1)), 2.0)
    eps = np.random.default_rng(1).standard_normal((120, 64, 3))
    fast, slow = (
        rollout(heads, plan[0], tau, n_samples=64, eps=eps, feedback=law, compiled=c)
        for c in (True, False)
    )
    torque = tau[0] - 30.0 * (slow[:, :-1, 0] - plan[:-1, 0]) - (slow[:, :-1, 1] - plan[:-1, 1])
    assert np.mean(np.abs(torque) > 2.0) > 0.05  # the clip is exercised
    np.testing.assert_allclose(fast, slow, rtol=0, atol=5e-5)


@pytest.mark.parametrize("per_step", [True, False])
def test_a_rollout_is_the_same_bits_on_one_thread_and_on_three(
    per_step: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Many trajectories run as blocks, one per thread (ppann/kernel.py): closed loop, machine
    factors, the slider force's channel, a draw per step or per trajectory, on 1 and on 3
    threads give the same bits, and 3 threads make 3 blocks of at least CHUNK_SAMPLES."""
    model = _trained_like(PPANNConfig(sigma_lever=True))
    with torch.no_grad():
        model.lever_sigma.fill_(15.0)
    heads = FusedHeads(model)
    n = 3 * kernel.CHUNK_SAMPLES + 5
    tau = np.full(120, 0.8)
    plan = np.stack([np.linspace(1.0, 6.0, 121), np.full(121, 20.0)], axis=1)
    law = Feedback(plan, np.tile([30.0, 1.0], (121, 1)), 2.0)
    rng = np.random.default_rng(2)
    rows = 120 if per_step else 1
    draws = {
        "eps": rng.standard_normal((rows, n, 3)),
        "lever_eps": rng.standard_normal((rows, n)),
        "factors": np.exp(0.05 * rng.standard_normal((n, 3))),
    }
    library, blocks = kernel.load(), []

    class Counting:
        def crank_rollout(self, count, *args):
            blocks.append(count.value)
            return library.crank_rollout(count, *args)

    monkeypatch.setattr(kernel, "load", Counting)
    runs = {}
    for threads in (1, 3):
        set_rollout_threads(threads)
        try:
            runs[threads] = rollout(heads, plan[0], tau, n_samples=n, feedback=law, **draws)
        finally:
            set_rollout_threads(None)
    assert np.all(np.isfinite(runs[1])) and np.array_equal(runs[1], runs[3])
    assert blocks[0] == n and len(blocks) == 4 and sum(blocks[1:]) == n
    assert max(blocks[1:]) - min(blocks[1:]) <= 1 and min(blocks) >= kernel.CHUNK_SAMPLES


def test_a_diverging_draw_is_nan_from_where_it_diverges_on_both_paths() -> None:
    """A trajectory draw with negative effective damping runs away; both paths agree while it
    is still a number one can compute with (below 1e6 rad/s), leave it non-finite at the end and,
    on the compiled path, from its first non-finite state on; the other rows are kept. (Where
    each path overflows, ~1e308, depends on how each rounds numbers of that size.)"""
    model = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.01, 0.6, 0.01))
    heads = FusedHeads(model)
    eps = np.zeros((1, 4, 3))
    eps[0, 0, 1] = -5.0  # damping factor 1 - 3: runs away, x1.13 a step
    tau = np.full(8000, 1.0)
    fast, slow = (
        rollout(heads, [0.5, 1.0], tau, n_samples=4, eps=eps, compiled=c) for c in (True, False)
    )
    bad_fast = ~np.isfinite(fast[0, :, 0])
    bad_slow = ~np.isfinite(slow[0, :, 0])
    assert bad_fast.any() and bad_slow.any()
    assert bad_fast[-1] and bad_slow[-1]
    assert np.all(bad_fast[np.argmax(bad_fast) :])
    tame = np.abs(slow[0, :, 1]) < 1e6
    assert tame.sum() > 50
    np.testing.assert_allclose(fast[0, tame], slow[0, tame], rtol=1e-6)
    np.testing.assert_allclose(fast[1:], slow[1:], rtol=0, atol=1e-6)


def test_keeping_some_states_gives_the_full_runs_bits_there() -> None:
    """`at` (the tail check's constraint samples) keeps the states at those indices only: on
    either path the full run's numbers there bit for bit, a diverged draw NaN where its full
    run is; indices that are not increasing within 0..T are refused."""
    heads = FusedHeads(_trained_like(PPANNConfig()))
    tau = np.linspace(0.5, 1.5, 120)
    at = np.array([0, 1, 49, 99, 120])
    for compiled in (True, False):
        draws = {"n_samples": 700, "mode": "mixed", "seed": 3, "normals": "counter"}
        full = monte_carlo(heads, [0.2, 3.0], tau, compiled=compiled, **draws).samples
        kept = monte_carlo(heads, [0.2, 3.0], tau, compiled=compiled, at=at, **draws).samples
        assert kept.shape == (700, at.size, 2)
        assert np.array_equal(kept, full[:, at])
    runaway = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.01, 0.6, 0.01))
    eps = np.zeros((1, 4, 3))
    eps[0, 0, 1] = -5.0  # runs away (the test above): non-finite long before state 8000
    long = np.full(8000, 1.0)
    ends = np.array([10, 7999, 8000])
    full = rollout(FusedHeads(runaway), [0.5, 1.0], long, n_samples=4, eps=eps)
    kept = rollout(FusedHeads(runaway), [0.5, 1.0], long, n_samples=4, eps=eps, at=ends)
    assert np.isnan(kept[0, 1:]).all() and np.isfinite(kept[1:]).all()
    np.testing.assert_array_equal(kept, full[:, ends])
    for bad in ([5, 5], [3, 1], [-1, 4], [0, 121], []):
        with pytest.raises(ValueError, match="at: increasing state indices"):
            monte_carlo(heads, [0.2, 3.0], tau, n_samples=4, at=bad)


def test_without_the_kernel_the_numpy_path_runs(monkeypatch: pytest.MonkeyPatch) -> None:
    """CRANK_KERNEL=0 (or no compiler) gives NumPy's numbers exactly."""
    heads = FusedHeads(_trained_like(PPANNConfig()))
    tau = np.full(50, 1.0)
    reference = rollout(heads, [0.0, 0.0], tau, n_samples=8, compiled=False)
    monkeypatch.setenv("CRANK_KERNEL", "0")
    kernel.load.cache_clear()
    try:
        assert kernel.load() is None
        assert np.array_equal(rollout(heads, [0.0, 0.0], tau, n_samples=8), reference)
    finally:
        monkeypatch.delenv("CRANK_KERNEL")
        kernel.load.cache_clear()
    assert kernel.load() is not None


def test_loading_the_kernel_leaves_the_process_arithmetic_alone() -> None:
    """A library linked with -ffast-math sets flush-to-zero for the whole process when it loads
    (GCC's crtfastmath.o); the kernel is linked without it, so subnormals survive NumPy's (and
    MuJoCo's) arithmetic after it loaded."""
    assert kernel.load() is not None
    tiny = np.array([1e-310, 3e-320])
    assert np.all(tiny * np.array([1.0, 1.0]) == tiny)
    assert np.all(np.array([2.2250738585072014e-308]) / 4 > 0)
