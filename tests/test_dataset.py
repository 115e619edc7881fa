"""Datasets: the paper's 90 s shape, the twin's bounds under the 30 N disturbance, determinism."""

from __future__ import annotations

from dataclasses import fields, replace

import numpy as np
import pytest

from common.errors import ConfigError
from twin.dataset import Dataset, GenerationConfig, GroundTruth, generate
from twin.excitation import Excitation
from twin.physics import SliderCrank
from twin.variability import Variability


def test_paper_dataset_shape(paper_dataset) -> None:
    data = paper_dataset.loaded
    assert len(data) == 45_000
    np.testing.assert_allclose(np.diff(data.t), 0.002, rtol=0, atol=1e-12)
    assert data.t[0] == 0.0
    assert np.array_equal(data.episode, np.repeat(np.arange(9), 5000))


def test_paper_dataset_disturbance_is_bounded_white_noise(paper_dataset) -> None:
    force = paper_dataset.loaded_truth.disturbance_force
    assert np.abs(force).max() <= 30.0
    assert np.abs(force).max() > 29.9  # it does reach its peak
    assert np.std(force) == pytest.approx(30 / np.sqrt(3), rel=0.02)  # uniform on [-30, 30]
    lag1 = np.corrcoef(force[:-1], force[1:])[0, 1]
    assert abs(lag1) < 0.02  # white: no correlation between samples


def test_paper_dataset_covers_the_ocp_region(paper_dataset) -> None:
    data = paper_dataset.loaded
    counts = np.histogram(np.mod(data.theta, 2 * np.pi), bins=12, range=(0, 2 * np.pi))[0]
    assert np.all(counts > 0), counts
    assert data.omega.min() <= -40 and data.omega.max() >= 40
    # Every 30° bin is crossed at speeds of both signs (both turning directions).
    bins = (np.mod(data.theta, 2 * np.pi) // (np.pi / 6)).astype(int)
    for b in range(12):
        assert np.any(data.omega[bins == b] > 20) and np.any(data.omega[bins == b] < -20)


def test_backlash_and_loop_closure_within_bounds(paper_dataset) -> None:
    """Under the 30 N disturbance: |backlash| <= 1.2 × half width, loop closure < 0.1 mm."""
    truth = paper_dataset.truth
    assert np.all(np.abs(truth.backlash_angle) <= 1.2 * truth.backlash_width / 2)
    assert truth.loop_closure_error.max() < 1e-4
    # The gap is really used: the crank swings across it.
    assert np.abs(truth.backlash_angle).max() > 0.9 * truth.backlash_width.max() / 2


@pytest.mark.parametrize("width", ["low", "high"])
def test_bounds_hold_at_the_ends_of_the_backlash_range(physics: SliderCrank, width: str) -> None:
    base = Variability()
    variability = replace(
        base, backlash_width=base.backlash_width.fixed(getattr(base.backlash_width, width))
    )
    _, truth, _ = generate(
        GenerationConfig(seconds=20, seed=11, variability=variability), physics=physics
    )
    assert np.all(np.abs(truth.backlash_angle) <= 1.2 * truth.backlash_width / 2)
    assert truth.loop_closure_error.max() < 1e-4


def test_slider_measured_on_the_slider_shows_backlash(paper_dataset) -> None:
    """slider_position follows the crank angle (motor + backlash), not the motor angle."""
    data, truth = paper_dataset.dataset, paper_dataset.truth
    x = data.geometry.slider_position
    by_crank = np.abs(data.slider_position - x(truth.crank_angle))
    by_motor = np.abs(data.slider_position - x(data.theta))
    assert by_crank.max() < 1e-4
    assert by_motor.max() > 3 * by_crank.max()


def _arrays(obj: Dataset | GroundTruth) -> dict[str, np.ndarray]:
    return {f.name: getattr(obj, f.name) for f in fields(obj) if f.name != "run"}


SHORT = GenerationConfig(seconds=4.0, episode_seconds=2.0, seed=0)


def test_same_seed_same_arrays(physics: SliderCrank) -> None:
    a = generate(SHORT, physics=physics)
    b = generate(SHORT, physics=physics, nthread=1)
    for x, y in zip(a[:2], b[:2], strict=True):
        for name, values in _arrays(x).items():
            assert np.array_equal(values, _arrays(y)[name]), name
    assert a[2] == b[2]


def test_other_seed_other_machines_and_noise(physics: SliderCrank) -> None:
    _, truth_a, episodes_a = generate(SHORT, physics=physics)
    _, truth_b, episodes_b = generate(replace(SHORT, seed=1), physics=physics)
    for ea, eb in zip(episodes_a, episodes_b, strict=True):
        for name, value in ea.machine.as_dict().items():
            assert value != getattr(eb.machine, name), name
    assert not np.any(truth_a.disturbance_force == truth_b.disturbance_force)


def test_episodes_run_warm_like_the_replays(physics: SliderCrank) -> None:
    """Each machine has run U[0, max_start_time] s before its episode: its first sample's
    friction is the warm-up drift at that time; max_start_time = 0 starts every machine cold and
    changes nothing else (machines, initial angles, torques)."""
    from replay.config import ReplayConfig
    from twin import OPERATING_SECONDS

    assert SHORT.max_start_time == OPERATING_SECONDS == ReplayConfig.max_start_time
    _, warm, episodes = generate(SHORT, physics=physics)
    _, cold, cold_episodes = generate(replace(SHORT, max_start_time=0.0), physics=physics)
    starts = np.array([e.start_time for e in episodes])
    assert np.all((starts > 0) & (starts < OPERATING_SECONDS)) and len(set(starts)) == len(starts)
    first = np.flatnonzero(np.diff(warm.episode, prepend=-1))
    variability = SHORT.variability
    for e, i in zip(episodes, first, strict=True):
        # the friction of the sample's first physics substep (twin/stepping.py: chunk midpoint)
        expected = variability.friction_at(e.machine, e.start_time)
        assert warm.motor_damping[i] == pytest.approx(expected.motor_damping, rel=1e-3)
        assert warm.motor_damping[i] < cold.motor_damping[i]
    for e, c in zip(episodes, cold_episodes, strict=True):
        assert (e.machine, e.theta0, c.start_time) == (c.machine, c.theta0, 0.0)


def test_episodes_are_different_machines(paper_dataset, physics: SliderCrank) -> None:
    truth = paper_dataset.truth
    starts = np.flatnonzero(np.diff(truth.episode, prepend=-1))
    widths = truth.backlash_width[starts]
    assert len(np.unique(widths)) == 9
    base = Variability()
    assert np.all((widths >= base.backlash_width.low) & (widths <= base.backlash_width.high))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"seconds": 0.0}, "seconds must be > 0"),
        ({"seconds": -3.0}, "seconds must be > 0"),
        ({"seconds": float("nan")}, "seconds must be a finite number"),
        ({"seconds": float("inf")}, "seconds must be a finite number"),
        ({"seconds": 0.001}, "at least 2 samples"),
        ({"episode_seconds": 0.0}, "episode_seconds must be > 0"),
        ({"seed": -1}, "seed must be an integer in 0..9223372036854775807, got -1"),
        ({"seed": 1.5}, "seed must be an integer in 0..9223372036854775807, got 1.5"),
    ],
)
def test_bad_generation_config(kwargs: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        GenerationConfig(**kwargs)


def _reference_torque(
    rng: np.random.Generator, n: int, *, amplitude: float, spread: float, rate: float = 500.0
) -> tuple[np.ndarray, float]:
    """The excitation written out from its docstring, and the episode's drawn peak level: the
    holds, then (with a spread) the level range, then the levels; filter; no clip needed."""
    from scipy import signal

    e = Excitation()
    n_levels = int(np.ceil(n / (e.min_hold * rate))) + 1
    holds = np.maximum(1, np.round(rng.uniform(e.min_hold, e.max_hold, n_levels) * rate))
    peak = float(rng.uniform(amplitude - spread, amplitude)) if spread > 0 else amplitude
    raw = np.repeat(rng.uniform(-peak, peak, n_levels), holds.astype(int))[:n]
    b, a = signal.butter(2, e.cutoff_hz, fs=rate)
    return signal.lfilter(b, a, raw), peak


def test_amplitude_spread_draws_one_level_range_per_episode() -> None:
    """Spread 0 is the excitation as it was before the option, bit for bit; with a spread every
    episode (its own generator) draws its own peak level in [amplitude - spread, amplitude]."""
    fixed = Excitation(amplitude=7.0)
    spread = Excitation(amplitude=7.0, amplitude_spread=5.0)
    peaks = []
    for episode in range(12):
        torque = fixed.torque(np.random.default_rng(episode), 2000, rate=500.0, limit=50.0)
        reference, _ = _reference_torque(
            np.random.default_rng(episode), 2000, amplitude=7.0, spread=0.0
        )
        np.testing.assert_array_equal(torque, reference)
        torque = spread.torque(np.random.default_rng(episode), 2000, rate=500.0, limit=50.0)
        reference, peak = _reference_torque(
            np.random.default_rng(episode), 2000, amplitude=7.0, spread=5.0
        )
        np.testing.assert_array_equal(torque, reference)
        peaks.append(peak)
    peaks = np.array(peaks)
    assert np.all((peaks >= 2.0) & (peaks <= 7.0)), peaks
    assert peaks.max() - peaks.min() > 2.5, peaks  # 12 uniform draws in a 5 N·m range


def test_amplitude_spread_reaches_the_dataset(physics: SliderCrank) -> None:
    """generate() plays, on every episode, the spread excitation drawn from that episode's own
    excitation stream, and the run records the spread."""
    from common.streams import stream

    excitation = Excitation(amplitude=7.0, amplitude_spread=5.0)
    config = GenerationConfig(seconds=4.0, episode_seconds=1.0, seed=3, excitation=excitation)
    data, _, _ = generate(config, physics=physics, nthread=1)
    children = stream(config.seed, "dataset_excitation").spawn(4)
    for e, child in enumerate(children):
        tau = data.tau[data.episode == e]
        expected = excitation.torque(
            np.random.default_rng(child), len(tau), rate=500.0, limit=physics.torque_limit
        )
        np.testing.assert_allclose(tau, expected, rtol=1e-6, atol=1e-6)
    assert config.as_dict()["excitation"]["amplitude_spread"] == 5.0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"amplitude_spread": -1.0}, "amplitude_spread must be >= 0"),
        ({"amplitude_spread": float("nan")}, "amplitude_spread must be a finite number"),
        ({"amplitude": 3.0, "amplitude_spread": 4.0}, "must not exceed amplitude"),
    ],
)
def test_bad_excitation(kwargs: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        Excitation(**kwargs)
