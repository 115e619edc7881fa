"""The law a recorded run must have played to be counted for a profile (`crank verify`), at the
rate its controller evaluated it.

The plan's law (`crank export`): open loop u_k = tau_k; closed loop
u_k = clip(tau_k + gain_theta_k (theta_k − θ) + gain_omega_k (omega_k − ω), ±limit) on the
machine's own θ, ω, each row's reference and gains held from t_k to t_(k+1) (the last gain held
for sample N, as the twin holds it). A controller at the plan's rate evaluates it once a sample,
at t_k. One `per_sample` = m times as fast evaluates it at t_k + j dt / m, j = 0..m − 1, the row's
reference held, and `crank import` resamples its torque to the plan's rate as the mean of its
zero-order hold over each sample: the mean of those m torques. Between samples θ and ω are
taken on the straight line to the next sample's (the last sample's held). At the plan's rate
this is the twin's closed loop bit for bit (tests/test_verify.py). Simulated on the twin, a 1 kHz
controller of a default run's `robust-fb` departs from the once-a-sample law by 0.500–0.530
N·m RMS (at the 5 % tolerance of a 10 N·m limit; 9 machines of 10 over it), from this model of
its own law by 0.10–0.14 (the states between samples are not on a straight line); under gains
stiff enough that the clip acts, a faster loop is another loop, and neither law matches it.

Open loop the torque is the plan's at any rate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from control.ocp_file import Profile

FASTER = (2, 4, 8, 16)
"""The controllers, in evaluations a sample, a refused run is tried against for its hint."""
_BLOCK = 4096
"""Candidate offsets scored at a time by `nearest`."""


@dataclass(frozen=True)
class PlayedLaw:
    """A profile's law as a controller `per_sample` times as fast as the plan plays it."""

    profile: Profile
    limit: float
    per_sample: int = 1

    def torque(self, theta: np.ndarray, omega: np.ndarray) -> np.ndarray:
        """The torque over each sample, as `crank import` resamples it, on readings `theta`,
        `omega` (..., n) at the samples, n ≤ N (module docstring)."""
        plan, n = self.profile, theta.shape[-1]
        tau = plan.tau[:n]
        if plan.loop == "open":
            return np.broadcast_to(tau, theta.shape)
        gain_theta = np.append(plan.gain_theta, plan.gain_theta[-1])[:n]
        gain_omega = np.append(plan.gain_omega, plan.gain_omega[-1])[:n]
        theta_next = np.concatenate([theta[..., 1:], theta[..., -1:]], axis=-1)
        omega_next = np.concatenate([omega[..., 1:], omega[..., -1:]], axis=-1)
        total = np.zeros(np.broadcast_shapes(theta.shape, tau.shape))
        for j in range(self.per_sample):
            share = j / self.per_sample  # 0 at the sample itself: its readings as they are
            th = theta + share * (theta_next - theta)
            om = omega + share * (omega_next - omega)
            feedback = gain_theta * (plan.theta[:n] - th) + gain_omega * (plan.omega[:n] - om)
            total = total + np.clip(tau + feedback, -self.limit, self.limit)
        return total / self.per_sample

    def rms(self, theta: np.ndarray, omega: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """RMS over the last axis of `tau` minus the law's torque on `theta`, `omega`, N·m."""
        return np.sqrt(np.mean((tau - self.torque(theta, omega)) ** 2, axis=-1))

    def nearest(
        self, theta: np.ndarray, omega: np.ndarray, tau: np.ndarray, *, window: int
    ) -> tuple[int, float]:
        """The sample of one run from which its torque is nearest the law's over `window`
        samples, and that RMS (N·m)."""
        views = [sliding_window_view(x, window) for x in (theta, omega, tau)]
        best, best_rms = 0, np.inf
        for start in range(0, len(views[0]), _BLOCK):
            rms = self.rms(*(v[start : start + _BLOCK] for v in views))
            k = int(np.argmin(rms))
            if rms[k] < best_rms:
                best, best_rms = start + k, float(rms[k])
        return best, best_rms

    def faster_match(
        self, theta: np.ndarray, omega: np.ndarray, tau: np.ndarray, *, tolerance: float
    ) -> bool:
        """Whether the run's torque is within `tolerance` of the law evaluated more often than
        this one, at some rate of FASTER (closed loop). Which rate is not told reliably: on the
        twin, a 2 kHz controller's torque was nearest the 4 kHz law's model (0.105 N·m against
        0.132 at its own), a 1 kHz one's nearest its own (0.105 against 0.131 at 2 kHz)."""
        if self.profile.loop == "open":
            return False
        return any(
            float(PlayedLaw(self.profile, limit=self.limit, per_sample=m).rms(theta, omega, tau))
            <= tolerance
            for m in FASTER
            if m > self.per_sample
        )
