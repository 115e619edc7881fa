"""Training data from a dataset: finite checks, the train/validation split, N-step windows, and
the measured angular acceleration used by the eq. 9 residual.

Split (paper section 3.3.2): the first (1 - validation_fraction) of the samples train, the rest
validate (87 s / 3 s of 90 s by default). A window of N steps starts at sample k and needs samples
k .. k + N from one episode and one split, so no window crosses an episode boundary. Phase 1's
early stopping scores the last fraction of every training episode (`machine_split`, held out of
its windows; `TrainConfig.early_stopping = "machines"`, the default) or the validation split as
the paper does ("tail").

Acceleration: alpha is the forward difference (omega_{k+1} - omega_k) / dt within an episode,
the acceleration forward Euler needs to reach the next sample; the last sample of each episode
has none and is left out of phase 2.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from common.errors import CrankError
from twin.dataset import Dataset


class DataError(CrankError, ValueError):
    """A dataset cannot be used for training; the message says why."""


def check_finite_data(dataset: Dataset) -> None:
    """Raise DataError naming the first non-finite value (field, sample, time)."""
    for name in ("t", "theta", "omega", "tau"):
        values = getattr(dataset, name)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            k = int(bad[0])
            when = f" (t = {dataset.t[k]:g} s)" if name != "t" else ""
            raise DataError(
                f"{name} is {values[k]} at sample {k}{when}; {bad.size} non-finite value(s) in all"
            )


@dataclass(frozen=True)
class Windows:
    """N-step windows: x0 (n, 2), tau (n, N), target states after 1..N steps (n, N, 2)."""

    x0: torch.Tensor
    tau: torch.Tensor
    target: torch.Tensor

    def __len__(self) -> int:
        return self.x0.shape[0]


def split_index(n_samples: int, validation_fraction: float) -> int:
    """First sample of the validation split."""
    return n_samples - max(1, round(n_samples * validation_fraction))


def windows(dataset: Dataset, *, start: int, stop: int, horizon: int) -> Windows:
    """Every window of `horizon` steps inside samples [start, stop) and inside one episode."""
    return windows_over(dataset, [(start, stop)], horizon=horizon)


def windows_over(dataset: Dataset, ranges: Sequence[tuple[int, int]], *, horizon: int) -> Windows:
    """Every window of `horizon` steps inside one of the sample ranges [start, stop) and inside
    one episode, in the order of the ranges."""
    firsts = []
    for start, stop in ranges:
        first = np.arange(start, max(start, stop - horizon))
        firsts.append(first[dataset.episode[first] == dataset.episode[first + horizon]])
    first = np.concatenate(firsts) if firsts else np.zeros(0, dtype=int)
    if first.size == 0:
        raise DataError(
            f"samples {_named(ranges, horizon)} hold no window of {horizon} steps inside one "
            "episode; the dataset is too short for the split or the horizon"
        )
    steps = first[:, None] + np.arange(1, horizon + 1)[None, :]
    states = np.stack([dataset.theta, dataset.omega], axis=-1)
    return Windows(
        x0=torch.from_numpy(states[first]),
        tau=torch.from_numpy(dataset.tau[first[:, None] + np.arange(horizon)[None, :]]),
        target=torch.from_numpy(states[steps]),
    )


def _named(ranges: Sequence[tuple[int, int]], horizon: int, *, listed: int = 3) -> str:
    """Sample ranges as `a..b` (end inclusive); more than `listed` + 1 of them as the first
    `listed`, the last and their count and lengths (a window needs `horizon` + 1 samples)."""
    shown = [f"{a}..{b - 1}" for a, b in ranges]
    if len(ranges) <= listed + 1:
        return ", ".join(shown)
    low, high = min(b - a for a, b in ranges), max(b - a for a, b in ranges)
    sizes = f"{low}" if low == high else f"{low} to {high}"
    return (
        f"{', '.join(shown[:listed])}, …, {shown[-1]} ({len(ranges)} ranges of {sizes} "
        f"samples; a window needs {horizon + 1})"
    )


def episode_ranges(dataset: Dataset, stop: int) -> list[tuple[int, int]]:
    """[start, stop) of every episode's samples before `stop`, in order."""
    episode = dataset.episode[:stop]
    edges = np.flatnonzero(np.diff(episode) != 0) + 1
    starts = np.concatenate([[0], edges]).astype(int)
    stops = np.concatenate([edges, [len(episode)]]).astype(int)
    return [(int(a), int(b)) for a, b in zip(starts, stops, strict=True) if b > a]


def machine_split(
    dataset: Dataset, stop: int, fraction: float
) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """Training and early-stopping ranges of the samples before `stop`: the last `fraction`
    (at least one sample) of every episode there stops, the rest trains. Every machine of the
    data is then in both, so the stop scores the mean model on the line, not on one machine."""
    train, stopping = [], []
    for start, end in episode_ranges(dataset, stop):
        cut = end - max(1, round((end - start) * fraction))
        train.append((start, cut))
        stopping.append((cut, end))
    return train, stopping


def acceleration(dataset: Dataset) -> tuple[np.ndarray, np.ndarray]:
    """Measured alpha (n_samples,) as the forward difference (omega_{k+1} - omega_k) / dt, and a
    mask (n_samples,) of samples where it is valid (not the last sample of an episode).

    This is the acceleration the forward-Euler model (eq. 4) must produce to land on the next
    measured state, so eq. 9 fits the one-step variance that the step-mode Monte-Carlo (eq. 11)
    propagates. A smoothed derivative (Savitzky-Golay over 11 samples, used before) averages the
    twin's white slider force over ~11 samples and left the sigma networks ~2x too small.
    """
    dt = float(dataset.t[1] - dataset.t[0])
    alpha = np.zeros_like(dataset.omega)
    alpha[:-1] = np.diff(dataset.omega) / dt
    valid = np.ones(len(dataset.omega), dtype=bool)
    valid[-1] = False
    valid[:-1] &= dataset.episode[1:] == dataset.episode[:-1]
    return alpha, valid
