"""Excitation torque for dataset generation: semi-random, low-pass filtered (paper Fig. 5).

Random torque levels, drawn uniformly from [-amplitude, amplitude] and each held for a random time
in [min_hold, max_hold], pass through a second-order Butterworth low-pass filter and are clipped
to the motor's torque limit. With the defaults the motor turns both ways through whole
revolutions and reaches well beyond ±40 rad/s, so θ covers [0, 2π) and ω covers the range the OCP
later needs (paper Fig. 6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.checks import check_finite
from common.errors import ConfigError


@dataclass(frozen=True)
class Excitation:
    """Semi-random torque: held random levels through a low-pass filter."""

    amplitude: float = 7.0
    """Largest torque level before filtering, in N·m."""
    cutoff_hz: float = 20.0
    """Cut-off of the second-order Butterworth low-pass filter, in Hz."""
    min_hold: float = 0.05
    """Shortest time a level is held, in s."""
    max_hold: float = 0.4
    """Longest time a level is held, in s."""

    def __post_init__(self) -> None:
        check_finite("excitation.amplitude", self.amplitude, nonneg=True)
        check_finite("excitation.cutoff_hz", self.cutoff_hz, positive=True)
        check_finite("excitation.min_hold", self.min_hold, positive=True)
        check_finite("excitation.max_hold", self.max_hold, positive=True)
        if self.min_hold > self.max_hold:
            raise ConfigError(
                f"excitation.min_hold ({self.min_hold}) must not exceed max_hold ({self.max_hold})"
            )

    def torque(
        self, rng: np.random.Generator, n_samples: int, *, rate: float, limit: float
    ) -> np.ndarray:
        """Torque profile in N·m, one value per sample, shape (n_samples,)."""
        if self.cutoff_hz >= rate / 2:
            raise ConfigError(
                f"excitation.cutoff_hz must be below the Nyquist frequency {rate / 2} Hz, "
                f"got {self.cutoff_hz}"
            )
        # Enough held levels to cover n_samples even if every hold is the shortest one.
        n_levels = int(np.ceil(n_samples / (self.min_hold * rate))) + 1
        holds = np.maximum(1, np.round(rng.uniform(self.min_hold, self.max_hold, n_levels) * rate))
        levels = rng.uniform(-self.amplitude, self.amplitude, n_levels)
        raw = np.repeat(levels, holds.astype(int))[:n_samples]
        from scipy import signal  # here: the command line shows Excitation's defaults

        b, a = signal.butter(2, self.cutoff_hz, fs=rate)
        return np.clip(signal.lfilter(b, a, raw), -limit, limit)
