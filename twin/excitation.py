"""Excitation torque for dataset generation: semi-random, low-pass filtered (paper Fig. 5).

Random torque levels, drawn uniformly from [-amplitude, amplitude] (with `amplitude_spread`, from
a range each episode draws) and each held for a random time in [min_hold, max_hold], pass
through a second-order Butterworth low-pass filter and are clipped to the motor's torque limit.
With the defaults the motor turns both ways through whole revolutions, θ covers [0, 2π) and the
speeds span what the OCPs use (paper Fig. 6).

Why ±3.5 N·m (since session 18; it was ±7): the OCPs' profiles on the paper task and four others
run at 21-37 rad/s at most, while at ±7 N·m half the training samples ran faster than 33 rad/s
(95th percentile 73), and the PPANN learnt the slow crawl over top dead centre the robust
profiles make from few samples: on training seed 5 a torque impulse before that crawl moved the
model's crank angle after it 1.7-2.0x as much as the twin's, and its held-out horizon-200 torque
went below on 9 of 1000 machines. At ±3.5 N·m (95th percentile 36 rad/s) that sensitivity is
1.2-1.4x, and on ten training seeds x five tasks every returned robust torque held on 1000
held-out machines (docs/history.md, *Does the tightening keep its own promise?*).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.checks import check_finite
from common.errors import ConfigError


@dataclass(frozen=True)
class Excitation:
    """Semi-random torque: held random levels through a low-pass filter."""

    amplitude: float = 3.5
    """Largest torque level before filtering, in N·m (module docstring: why 3.5)."""
    amplitude_spread: float = 0.0
    """Above 0: every episode draws its own largest level uniformly in [amplitude -
    amplitude_spread, amplitude], in N·m, so that slow episodes crawling over top dead centre
    lie beside fast ones. 0: every episode uses `amplitude` (no draw: the torques are exactly
    those of a dataset made before this option)."""
    cutoff_hz: float = 20.0
    """Cut-off of the second-order Butterworth low-pass filter, in Hz."""
    min_hold: float = 0.05
    """Shortest time a level is held, in s."""
    max_hold: float = 0.4
    """Longest time a level is held, in s."""

    def __post_init__(self) -> None:
        check_finite("excitation.amplitude", self.amplitude, nonneg=True)
        check_finite("excitation.amplitude_spread", self.amplitude_spread, nonneg=True)
        if self.amplitude_spread > self.amplitude:
            raise ConfigError(
                f"excitation.amplitude_spread ({self.amplitude_spread}) must not exceed "
                f"amplitude ({self.amplitude}): a level range reaching below 0 N·m"
            )
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
        amplitude = self.amplitude
        if self.amplitude_spread > 0:  # after the holds: they stay those of a fixed amplitude
            amplitude = float(rng.uniform(self.amplitude - self.amplitude_spread, self.amplitude))
        levels = rng.uniform(-amplitude, amplitude, n_levels)
        raw = np.repeat(levels, holds.astype(int))[:n_samples]
        from scipy import signal  # here: the command line shows Excitation's defaults

        b, a = signal.butter(2, self.cutoff_hz, fs=rate)
        return np.clip(signal.lfilter(b, a, raw), -limit, limit)
