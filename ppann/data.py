"""Training data from a dataset: finite checks, the train/validation split, N-step windows, and
the measured angular acceleration used by the eq. 9 residual.

Split (paper section 3.3.2): the first (1 - validation_fraction) of the samples train, the rest
validate (87 s / 3 s of 90 s by default). A window of N steps starts at sample k and needs samples
k .. k + N from one episode and one split, so no window crosses an episode boundary.

Acceleration: alpha is the forward difference (omega_{k+1} - omega_k) / dt within an episode,
the acceleration forward Euler needs to reach the next sample; the last sample of each episode
has none and is left out of phase 2.
"""

from __future__ import annotations

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
    first = np.arange(start, max(start, stop - horizon))
    same = dataset.episode[first] == dataset.episode[first + horizon]
    first = first[same]
    if first.size == 0:
        raise DataError(
            f"samples {start}..{stop} hold no window of {horizon} steps inside one episode; "
            "the dataset is too short for the split or the horizon"
        )
    steps = first[:, None] + np.arange(1, horizon + 1)[None, :]
    states = np.stack([dataset.theta, dataset.omega], axis=-1)
    return Windows(
        x0=torch.from_numpy(states[first]),
        tau=torch.from_numpy(dataset.tau[first[:, None] + np.arange(horizon)[None, :]]),
        target=torch.from_numpy(states[steps]),
    )


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
