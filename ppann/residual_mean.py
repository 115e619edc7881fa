"""The residual's mean, taken out before phase 2 fits its spread (beyond the paper).

Eq. 9 reads the whole one-step residual r of the frozen mean model as noise: its sigma networks
fit E[r^2 | x], the white variance *plus the square of the mean model's own error at x*. Phase 1
fits the mean over N steps, so a one-step error is left, and it is deterministic: the same on
every machine under one torque. The Monte-Carlo then propagates it as independent noise and
over-predicts the spread. On the twin's nominal machines without any randomness a default
model's residual kept 13-20 % of the power it has with the white force (session 24, seed 1), and
the seed-3 default model predicted the slider's σ at sample 50 at 1.30x the machines' (session
25, 1000 development machines).

Here the residual's conditional mean given the sample's own state and torque is fitted first, by
least squares on a basis of (theta_k, omega_k, tau_k): Fourier harmonics 0..HARMONICS of theta
times (1, omega, omega^2, tau, tau omega). Those regressors are set before sample k's white force
acts (theta_k and omega_k by earlier forces, tau_k by the excitation), so the fit cannot take the
noise of its own sample; regressors of the recent past would (a block sums neighbouring samples,
and a past speed holds a past force), and on the seed-3 data they explained less of the blocks'
power, not more. Phase 2 then fits the sigma networks and the machine spread to r - mean.

The machines' own offsets are taken out of the residual the mean is fitted on (ppann/train.py: a
first pass of phase 2 gives them, a second fits the spread around the mean): on the seed-1 and
seed-3 default models (session 25, 1000 development machines) the mean fitted on the raw residual
moved the predicted / observed slider σ at sample 50 from 1.21 / 1.30 to 1.20 / 1.32, the mean
fitted with the offsets out to 1.15 / 1.25 (at sample 100: 1.14 / 1.10 to 1.07 / 1.07).

The mean is a nuisance of phase 2 only, as ppann/machine.py's common log-factor offset is: it is
not propagated, the Monte-Carlo's mean stays phase 1's N-step model. The two overlap (the
damping's design column, omega (1 + z_B) B_m, lies nearly in the basis), and need not be told
apart: phase 2's common offset fits what the mean left, and its covariance, which depends on the
design and the white variance alone, is the same either way. Machine offsets differ from episode
to episode and average out of the mean. Columns are scaled to unit RMS before the solve (the
fitted values do not depend on the scaling; the conditioning does), and the fit solves the
normal equations (`_normal_equations`: the same bits in any thread).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from common.errors import CrankError

HARMONICS = 8
"""Fourier harmonics of theta in the basis (0 is the constant); 5 x (2 HARMONICS + 1) columns."""


def basis(theta: torch.Tensor, omega: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
    """The mean's regressors at each sample, (n, 5 (2 HARMONICS + 1)): harmonics of theta times
    (1, omega, omega^2, tau, tau omega)."""
    factors = torch.stack([torch.ones_like(omega), omega, omega**2, tau, tau * omega], dim=-1)
    trig = [torch.ones_like(theta)]
    for h in range(1, HARMONICS + 1):
        trig += [torch.sin(h * theta), torch.cos(h * theta)]
    harmonics = torch.stack(trig, dim=-1)
    return (harmonics[:, :, None] * factors[:, None, :]).reshape(len(theta), -1)


CHUNK = 2048
"""Samples per partial sum of the normal equations."""


def _normal_equations(x: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """X^T X and X^T y, summed chunk after chunk in a fixed order, solved later by
    `torch.linalg.solve` on the small system: MKL's least squares (torch.linalg.lstsq) gave other
    last bits in a Python thread than in the main one, both on one torch thread, and
    `ppann.fit.fit_all` trains kinds side by side in threads, bit for bit as one after another
    (tests/test_fit_all.py). These products and the solve gave the same bits in both (session
    25: four trials, and with a misaligned copy of X)."""
    p = x.shape[1]
    gram = torch.zeros((p, p), dtype=x.dtype)
    moment = torch.zeros(p, dtype=x.dtype)
    for start in range(0, len(x), CHUNK):
        rows = x[start : start + CHUNK]
        gram += rows.T @ rows
        moment += rows.T @ y[start : start + CHUNK]
    return gram, moment


class ResidualMeanError(CrankError, ValueError):
    """The residual's mean cannot be fitted on these samples (a one-line error on the CLI)."""


@dataclass(frozen=True)
class ResidualMean:
    """The fitted mean at the samples, and how much of the residual it was."""

    mean: torch.Tensor
    """The residual's fitted mean at each sample (n,)."""
    share: float
    """The fraction of the residual's power the mean accounts for, in sums over the blocks phase
    2 fits (per sample without blocks)."""


def fit_residual_mean(
    residual: torch.Tensor,
    *,
    theta: torch.Tensor,
    omega: torch.Tensor,
    tau: torch.Tensor,
    block: torch.Tensor | None = None,
) -> ResidualMean:
    """Least squares of the residual (n,) on `basis` (module docstring). `block` (n,): each
    sample's block in phase 2 (`EpisodeTerms.block`), for the share.

    Raises:
      ResidualMeanError: fewer samples than regressors, or a residual that is not finite.
    """
    regressors = basis(theta, omega, tau)
    n, p = regressors.shape
    if n <= p:
        raise ResidualMeanError(
            f"the residual's mean needs more than {p} training samples, got {n} "
            "(a longer dataset, or --no-residual-mean)"
        )
    if not bool(torch.isfinite(residual).all()):
        raise ResidualMeanError("the residual holds NaN or inf")
    scale = regressors.pow(2).mean(dim=0).sqrt().clamp_min(1e-300)
    gram, moment = _normal_equations(regressors / scale, residual)
    solved = torch.linalg.solve(gram, moment)
    mean = (regressors * (solved / scale)).sum(dim=-1)
    whole, left = residual, residual - mean
    if block is not None:
        count = int(block.max()) + 1
        whole, left = (
            torch.zeros(count, dtype=v.dtype).index_add(0, block, v) for v in (whole, left)
        )
    power = float(whole.pow(2).sum())
    share = 1.0 - float(left.pow(2).sum()) / power if power > 0 else 0.0
    return ResidualMean(mean=mean, share=share)
