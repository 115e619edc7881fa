"""The machine-level uncertainty model (beyond the paper): what is constant within an episode,
separated from what is white.

Every dataset episode is one machine, unless the run record says several episodes are runs of
one machine (twin.dataset.episode_machines): their blocks then share one eta_e, and e below
counts machines. Machine e multiplies the inertia, damping and stiffness terms of eq. 14 by
exp(eta_e), eta_e ~ N(0, diag(machine_sigma^2)), constant over its episodes;
on top of that every sample has the white residual of eq. 9, variance
s_k^2 = sum_i (dr/dz_i sigma_i(x_k))^2. To first order in eta the torque residual at the mean
model is

    r_k = -D_k . eta_e + white_k,   D_k = ((1 + z_mu) * dr/dz)_k   (n_k, 3 per episode),

(with `PPANNConfig.machine_terms` "prior" the factors scale the prior's physical terms alone,
J_m (1 + z_J + e^eta_J - 1) and so on, and D_k = dr/dz_k: `machine_design`; with
`PPANNConfig.coulomb` the damping factor scales the prior's Coulomb friction too, the
machine's whole friction, and D_k's damping column gains it: ppann/friction.py)

so an episode's residual vector is Gaussian with covariance diag(s^2) + D diag(machine_sigma^2)
D^T. Its negative log-likelihood, with eta integrated out (Woodbury and the determinant lemma,
written with S = diag(machine_sigma) so that machine_sigma -> 0 is regular):

    NLL_e = 1/2 [ sum_k (r_k^2 / s_k^2 + log s_k^2) - c^T (I + G)^-1 c + log det (I + G) ],
    M = sum_k D_k D_k^T / s_k^2,  b = sum_k r_k D_k / s_k^2,  G = S M S,  c = S b.

Phase 2 minimises the sum over episodes divided by the number of blocks (below), over the sigma
networks and log machine_sigma jointly. With machine_sigma = 0 and blocks of one sample the loss
is exactly eq. 9. The posterior mean of each episode's eta, -S (I + G)^-1 c, is what the report
shows per machine.

Blocks (beyond the paper; `TrainConfig.sigma_block`): the same likelihood written for sums of
the residual over blocks of L consecutive samples of an episode, R_b = sum r_k, D_b = sum D_k,
white variance V_b = sum s_k^2 (the machine term is unchanged: eta is constant over the block).
The Monte-Carlo propagates z as white noise, so what sets the spread it predicts over tens of
steps is the residual's power at low frequencies, not its one-step variance; the two agree only
if the residual is white. On the seed-0 dataset it is not: with the machine offsets taken out,
the variance of L-step sums is 0.85 / 0.63 / 0.55 / 0.57 / 0.64 of L times the one-step
variance at L = 2 / 5 / 10 / 25 / 50 (backlash rattle and the discretisation make the one-step
residual partly blue: bounded, it does not accumulate), and the step Monte-Carlo over-predicted
the twin's white-force spread of the slider 1.2-1.5x at samples 50 and 100. Blocks of L samples
fit V_b to the power at periods of L samples and longer. L = 1 is eq. 9.

What a handful of machines cannot tell (`population`): the fitted line is E machines' worth of
evidence (9 in the default dataset), so its mean and its spread are estimates. The mean model
sits on the average of the training machines, which differs from the line's mean by about
machine_sigma / sqrt(E) (measured on line-15: the training machines were 2-4 % more damped than
the line, and the twin ran 0.1 rad ahead of the model at sample 100); and machine_sigma itself
has a ~1 / sqrt(2 E) relative error (24 % at E = 9). Two summaries of the marginal likelihood
carry this into the checkpoint:
- `common_covariance` (3, 3): the covariance of the mean model's offset from the line's mean
  log-factors. The mean model is not the likelihood's estimate of the line's mean: phase 1 fits
  every sample alike, knowing nothing of machines, so it averages the machines as a pooled fit
  does, each by the information its runs carry (M_e, with e now counting machines), not by the
  1 / (machine_sigma^2 + M_e^-1) the likelihood would. Its covariance is the pooled fit's
  (the sandwich) at the fitted spread,

      (sum_e M_e)^-1 [ sum_e M_e (S^2 + M_e^-1) M_e ] (sum_e M_e)^-1,

  never below the inverse Hessian of the summed NLL in the common offset (the likelihood's own,
  the best a linear average can do; Gauss-Markov), and equal to it when the machines carry
  equal information. Where they do not, it is wider: after the default chain's plan round the
  240 plan machines' short runs see a machine's damping to 0.8 sigma, the dataset's 70 to 0.1,
  and the pooled mean's standard error was 1.6x the likelihood's in the damping
  (bench/bound_coverage.md; until session 80 the inverse Hessian was used);
- `profile` (3, len(PROFILE_GRID)): the summed NLL with one machine_sigma component moved to
  each grid value and everything else at its estimate, minus the NLL at the estimate, so that a
  likelihood-ratio upper bound at any confidence can be read off later (`sigma_upper`): unlike
  a Hessian in log sigma it stays finite when a component's estimate is ~0 (the bound is then
  the smallest spread the data would have shown).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from ppann.losses import VARIANCE_FLOOR
from ppann.model import PPANN, PROFILE_GRID


def machine_design(
    model: PPANN, theta: torch.Tensor, omega: torch.Tensor, derivative: torch.Tensor
) -> torch.Tensor:
    """D_k of the module docstring, (n, 3), from dr/dz `derivative` (n, 3) at the samples:
    the torque residual's derivative in a machine's log-factors at eta = 0. (1 + z_mu) dr/dz
    when they scale eq. 14's whole terms (`PPANNConfig.machine_terms` "augmented"), dr/dz when
    they scale the prior's physical terms alone ("prior"); the damping column gains the prior's
    Coulomb friction, which the damping factor scales in either case (`PPANNConfig.coulomb`)."""
    if model.config.machine_terms == "prior":
        design = derivative
    else:
        design = (1 + model.z_mean(theta, omega)) * derivative
    if model.config.coulomb:
        design = design.clone()
        design[:, 1] = design[:, 1] + model.friction(theta, omega)
    return design


def machine_sums(
    residual: torch.Tensor,
    design: torch.Tensor,
    variance: torch.Tensor,
    machine: torch.Tensor,
    n_machines: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """M (E, 3, 3) and b (E, 3) of the module docstring; `machine` (n,) holds 0..E-1."""
    weight = 1.0 / variance
    outer = design[:, :, None] * design[:, None, :] * weight[:, None, None]
    m = torch.zeros((n_machines, 3, 3), dtype=design.dtype).index_add(0, machine, outer)
    b = torch.zeros((n_machines, 3), dtype=design.dtype).index_add(
        0, machine, design * (residual * weight)[:, None]
    )
    return m, b


@dataclass(frozen=True)
class EpisodeTerms:
    """What phase 2 needs of the data and the frozen mean model, per block of consecutive samples
    of one episode (module docstring, "Blocks"; a block of one sample is eq. 9's sample)."""

    residual: torch.Tensor
    """Sum of r_k at the mean z over each block, (B,)."""
    design: torch.Tensor
    """Sum of D_k = (1 + z_mu) dr/dz over each block, (B, 3)."""
    derivative: torch.Tensor
    """dr/dz_k per sample, (n, 3)."""
    block: torch.Tensor
    """(n,) the block of each sample, in 0..B-1."""
    machine: torch.Tensor
    """(B,) the machine of each block, in 0..n_machines-1: its episode's index, or the machine
    several episodes share (`build`'s `machine`), which then share one eta."""
    n_machines: int
    lever: torch.Tensor | None = None
    """x'(theta_k)^2 per sample, (n,), for the slider force's channel (ppann/lever.py)."""

    @classmethod
    def build(
        cls,
        residual: torch.Tensor,
        derivative: torch.Tensor,
        design: torch.Tensor,
        episode: torch.Tensor,
        *,
        machine: torch.Tensor | None = None,
        block_length: int = 1,
        lever: torch.Tensor | None = None,
    ) -> EpisodeTerms:
        """Blocks of `block_length` consecutive samples (the last of an episode may be shorter)
        from per-sample residual (n,), derivative and design (n, 3), episode (n,) in time order;
        `machine` (n,) in 0..M-1: the machine of each sample, whose episodes share one offset
        eta (None: every episode its own machine); `lever`: x'(theta)^2 per sample (n,) for a
        model with the slider force's channel."""
        n = residual.shape[0]
        start = torch.ones(n, dtype=torch.bool)
        start[1:] = episode[1:] != episode[:-1]
        first = torch.cummax(torch.where(start, torch.arange(n), 0), dim=0).values
        position = torch.arange(n) - first
        new_block = start | (position % block_length == 0)
        block = torch.cumsum(new_block.to(torch.int64), dim=0) - 1
        count = int(block[-1]) + 1 if n else 0
        group = episode if machine is None else machine

        def summed(values: torch.Tensor) -> torch.Tensor:
            return torch.zeros((count, *values.shape[1:]), dtype=values.dtype).index_add(
                0, block, values
            )

        return cls(
            residual=summed(residual),
            design=summed(design),
            derivative=derivative,
            block=block,
            machine=group[new_block],
            n_machines=int(group.max()) + 1 if n else 0,
            lever=lever,
        )

    def shifted(self, common: torch.Tensor) -> EpisodeTerms:
        """The same with the common log-factor offset (3,) taken out of the residual."""
        return replace(self, residual=self.residual + self.design @ common)

    def white_variance(
        self, sigma: torch.Tensor, lever_sigma: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Each block's white variance, the sum of its samples' s_k^2, for sigma-network outputs
        sigma (n, 3) and the slider force's standard deviation `lever_sigma` (None: no such
        channel), (B,)."""
        per_sample = ((self.derivative * sigma) ** 2).sum(dim=-1)
        if lever_sigma is not None and self.lever is not None:
            per_sample = per_sample + lever_sigma**2 * self.lever
        summed = torch.zeros_like(self.residual).index_add(0, self.block, per_sample)
        return summed + VARIANCE_FLOOR

    def scaled(
        self, variance: torch.Tensor, machine_sigma: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """G = S M S (E, 3, 3), c = S b (E, 3) of the module docstring, and I + G."""
        m, b = machine_sums(self.residual, self.design, variance, self.machine, self.n_machines)
        s = machine_sigma
        g = s[None, :, None] * m * s[None, None, :]
        return g, s[None, :] * b, torch.eye(3, dtype=g.dtype).expand_as(g) + g


def white_nll(
    terms: EpisodeTerms, sigma: torch.Tensor, lever_sigma: torch.Tensor | None = None
) -> torch.Tensor:
    """Eq. 9 on blocks, averaged over blocks: (1 / 2B) sum_b (R_b^2 / V_b + log V_b); with blocks
    of one sample, eq. 9 itself."""
    variance = terms.white_variance(sigma, lever_sigma)
    return 0.5 * (terms.residual**2 / variance + torch.log(variance)).mean()


def marginal_nll(
    terms: EpisodeTerms,
    sigma: torch.Tensor,
    machine_sigma: torch.Tensor,
    lever_sigma: torch.Tensor | None = None,
) -> torch.Tensor:
    """The phase-2 loss of the module docstring, averaged over blocks, for white sigma-network
    outputs `sigma` (n, 3), the machine spread `machine_sigma` (3,) >= 0 and the slider force's
    `lever_sigma` (ppann/lever.py; None: no such channel)."""
    variance = terms.white_variance(sigma, lever_sigma)
    white = (terms.residual**2 / variance + torch.log(variance)).sum()
    _, c, identity_plus_g = terms.scaled(variance, machine_sigma)
    chol = torch.linalg.cholesky(identity_plus_g)
    solved = torch.cholesky_solve(c[:, :, None], chol)[:, :, 0]
    quad = (c * solved).sum()
    logdet = 2 * torch.log(torch.diagonal(chol, dim1=-2, dim2=-1)).sum()
    return 0.5 * (white - quad + logdet) / terms.residual.shape[0]


def posterior_offsets(
    terms: EpisodeTerms,
    sigma: torch.Tensor,
    machine_sigma: torch.Tensor,
    lever_sigma: torch.Tensor | None = None,
) -> torch.Tensor:
    """Posterior mean of each episode's log-factors eta_e, (E, 3)."""
    variance = terms.white_variance(sigma, lever_sigma)
    _, c, identity_plus_g = terms.scaled(variance, machine_sigma)
    return -machine_sigma[None, :] * torch.linalg.solve(identity_plus_g, c[:, :, None])[:, :, 0]


@dataclass(frozen=True)
class Population:
    """What the training machines tell about the line (module docstring, last section)."""

    common_covariance: torch.Tensor
    """(3, 3) covariance of the mean model's offset from the line's mean log-factors: the pooled
    average's (`pooled_covariance`)."""
    profile: torch.Tensor
    """(3, len(PROFILE_GRID)) NLL increase with one machine_sigma component at each grid value."""


def population(
    terms: EpisodeTerms,
    sigma: torch.Tensor,
    machine_sigma: torch.Tensor,
    common: torch.Tensor,
    lever_sigma: torch.Tensor | None = None,
) -> Population:
    """`Population` at the phase-2 estimate: white sigma-network outputs `sigma` (n, 3), the fitted
    `machine_sigma` (3,), common offset (3,) and slider force (None: no such channel)."""
    sigma, machine_sigma, common = sigma.detach(), machine_sigma.detach(), common.detach()
    lever = None if lever_sigma is None else lever_sigma.detach()
    n = terms.residual.shape[0]

    shifted = terms.shifted(common)
    with torch.no_grad():
        base = n * marginal_nll(shifted, sigma, machine_sigma, lever)
        profile = torch.empty((3, len(PROFILE_GRID)), dtype=torch.float64)
        for i in range(3):
            for j, value in enumerate(PROFILE_GRID):
                moved = machine_sigma.clone()
                moved[i] = float(value)
                profile[i, j] = n * marginal_nll(shifted, sigma, moved, lever) - base
    return Population(pooled_covariance(terms, sigma, machine_sigma, lever), profile)


def pooled_covariance(
    terms: EpisodeTerms,
    sigma: torch.Tensor,
    machine_sigma: torch.Tensor,
    lever_sigma: torch.Tensor | None = None,
) -> torch.Tensor:
    """The covariance (3, 3) of the machines' pooled average log-factors (each machine weighted
    by its information M_e) about the line's mean, for machine spread `machine_sigma` (module
    docstring, `common_covariance`): (sum M)^-1 [sum M_e S^2 M_e + M_e] (sum M)^-1."""
    variance = terms.white_variance(sigma, lever_sigma)
    info, _ = machine_sums(terms.residual, terms.design, variance, terms.machine, terms.n_machines)
    return pooled_from_information(info, machine_sigma)


def pooled_from_information(info: torch.Tensor, machine_sigma: torch.Tensor) -> torch.Tensor:
    """`pooled_covariance` from the machines' information M_e `info` (E, 3, 3), for spreads
    `machine_sigma` (..., 3): (..., 3, 3) (bench/bound_coverage.py takes it for many lines)."""
    spread = torch.diag_embed(machine_sigma**2)[..., None, :, :]
    inverse = torch.linalg.inv(info.sum(-3))
    covariance = inverse @ (info @ spread @ info + info).sum(-3) @ inverse
    return 0.5 * (covariance + covariance.mT)


def sigma_upper(machine_sigma: np.ndarray, profile: np.ndarray, level: float) -> np.ndarray:
    """Likelihood-ratio upper bound of each machine_sigma component: the smallest value above the
    estimate where the profile NLL rises by `level` (z^2 / 2 at one-sided normal quantile z for
    many machines; ppann/confidence.py spread_level for M) (linear interpolation on
    PROFILE_GRID; the grid's end if it never does). level 0, or a profile row of zeros (no
    machine model fitted), gives the estimate."""
    machine_sigma = np.asarray(machine_sigma, dtype=float)
    upper = machine_sigma.copy()
    if level <= 0:
        return upper
    for i, (estimate, rise) in enumerate(zip(machine_sigma, profile, strict=True)):
        if not np.any(rise):
            continue
        above = estimate < PROFILE_GRID
        grid, values = PROFILE_GRID[above], rise[above]
        crossing = np.flatnonzero(values >= level)
        if crossing.size == 0:
            upper[i] = PROFILE_GRID[-1]
            continue
        j = int(crossing[0])
        x0, y0 = (estimate, 0.0) if j == 0 else (grid[j - 1], max(values[j - 1], 0.0))
        x1, y1 = grid[j], values[j]
        upper[i] = x0 + (x1 - x0) * (level - y0) / (y1 - y0) if y1 > y0 else x1
    return upper
