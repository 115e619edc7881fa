"""The machine-level uncertainty model (beyond the paper): what is constant within an episode,
separated from what is white.

Every dataset episode is one machine. Machine e multiplies the inertia, damping and stiffness
terms of eq. 14 by exp(eta_e), eta_e ~ N(0, diag(machine_sigma^2)), constant over the episode;
on top of that every sample has the white residual of eq. 9, variance
s_k^2 = sum_i (dr/dz_i sigma_i(x_k))^2. To first order in eta the torque residual at the mean
model is

    r_k = -D_k . eta_e + white_k,   D_k = ((1 + z_mu) * dr/dz)_k   (n_k, 3 per episode),

so an episode's residual vector is Gaussian with covariance diag(s^2) + D diag(machine_sigma^2)
D^T. Its negative log-likelihood, with eta integrated out (Woodbury and the determinant lemma,
written with S = diag(machine_sigma) so that machine_sigma -> 0 is regular):

    NLL_e = 1/2 [ sum_k (r_k^2 / s_k^2 + log s_k^2) - c^T (I + G)^-1 c + log det (I + G) ],
    M = sum_k D_k D_k^T / s_k^2,  b = sum_k r_k D_k / s_k^2,  G = S M S,  c = S b.

Phase 2 minimises the sum over episodes divided by the number of samples, over the sigma
networks and log machine_sigma jointly. With machine_sigma = 0 the loss is exactly eq. 9. The
posterior mean of each episode's eta, -S (I + G)^-1 c, is what the report shows per machine.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from ppann.losses import VARIANCE_FLOOR


def episode_sums(
    residual: torch.Tensor,
    design: torch.Tensor,
    variance: torch.Tensor,
    episode: torch.Tensor,
    n_episodes: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """M (E, 3, 3) and b (E, 3) of the module docstring; `episode` (n,) holds 0..E-1."""
    weight = 1.0 / variance
    outer = design[:, :, None] * design[:, None, :] * weight[:, None, None]
    m = torch.zeros((n_episodes, 3, 3), dtype=design.dtype).index_add(0, episode, outer)
    b = torch.zeros((n_episodes, 3), dtype=design.dtype).index_add(
        0, episode, design * (residual * weight)[:, None]
    )
    return m, b


@dataclass(frozen=True)
class EpisodeTerms:
    """What phase 2 needs of the data and the frozen mean model, per sample."""

    residual: torch.Tensor
    """r_k at the mean z, (n,)."""
    derivative: torch.Tensor
    """dr/dz_k, (n, 3)."""
    design: torch.Tensor
    """D_k = (1 + z_mu) dr/dz, (n, 3)."""
    episode: torch.Tensor
    """(n,) integer episode index in 0..n_episodes-1."""
    n_episodes: int

    def shifted(self, common: torch.Tensor) -> EpisodeTerms:
        """The same with the common log-factor offset (3,) taken out of the residual."""
        return replace(self, residual=self.residual + self.design @ common)

    def white_variance(self, sigma: torch.Tensor) -> torch.Tensor:
        """s_k^2 for white sigma-network outputs sigma (n, 3)."""
        return ((self.derivative * sigma) ** 2).sum(dim=-1) + VARIANCE_FLOOR

    def scaled(
        self, variance: torch.Tensor, machine_sigma: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """G = S M S (E, 3, 3), c = S b (E, 3) of the module docstring, and I + G."""
        m, b = episode_sums(self.residual, self.design, variance, self.episode, self.n_episodes)
        s = machine_sigma
        g = s[None, :, None] * m * s[None, None, :]
        return g, s[None, :] * b, torch.eye(3, dtype=g.dtype).expand_as(g) + g


def marginal_nll(
    terms: EpisodeTerms, sigma: torch.Tensor, machine_sigma: torch.Tensor
) -> torch.Tensor:
    """The phase-2 loss of the module docstring, averaged over samples, for white sigma-network
    outputs `sigma` (n, 3) and the machine spread `machine_sigma` (3,) >= 0."""
    variance = terms.white_variance(sigma)
    white = (terms.residual**2 / variance + torch.log(variance)).sum()
    _, c, identity_plus_g = terms.scaled(variance, machine_sigma)
    chol = torch.linalg.cholesky(identity_plus_g)
    solved = torch.cholesky_solve(c[:, :, None], chol)[:, :, 0]
    quad = (c * solved).sum()
    logdet = 2 * torch.log(torch.diagonal(chol, dim1=-2, dim2=-1)).sum()
    return 0.5 * (white - quad + logdet) / terms.residual.shape[0]


def posterior_offsets(
    terms: EpisodeTerms, sigma: torch.Tensor, machine_sigma: torch.Tensor
) -> torch.Tensor:
    """Posterior mean of each episode's log-factors eta_e, (E, 3)."""
    _, c, identity_plus_g = terms.scaled(terms.white_variance(sigma), machine_sigma)
    return -machine_sigma[None, :] * torch.linalg.solve(identity_plus_g, c[:, :, None])[:, :, 0]
