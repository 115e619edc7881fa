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


def marginal_nll(
    residual: torch.Tensor,
    derivative: torch.Tensor,
    design: torch.Tensor,
    sigma: torch.Tensor,
    machine_sigma: torch.Tensor,
    episode: torch.Tensor,
    n_episodes: int,
) -> torch.Tensor:
    """The phase-2 loss of the module docstring, averaged over samples.

    Args:
      residual: r_k at the mean z, (n,).
      derivative: dr/dz_k, (n, 3).
      design: D_k = (1 + z_mu) dr/dz, (n, 3).
      sigma: white sigma-network outputs, (n, 3).
      machine_sigma: (3,), >= 0.
      episode: (n,) integer episode index in 0..n_episodes-1.
    """
    variance = ((derivative * sigma) ** 2).sum(dim=-1) + VARIANCE_FLOOR
    white = (residual**2 / variance + torch.log(variance)).sum()
    g, c = _scaled(residual, design, variance, machine_sigma, episode, n_episodes)
    eye = torch.eye(3, dtype=g.dtype).expand_as(g)
    chol = torch.linalg.cholesky(eye + g)
    solved = torch.cholesky_solve(c[:, :, None], chol)[:, :, 0]
    quad = (c * solved).sum()
    logdet = 2 * torch.log(torch.diagonal(chol, dim1=-2, dim2=-1)).sum()
    return 0.5 * (white - quad + logdet) / residual.shape[0]


def posterior_offsets(
    residual: torch.Tensor,
    derivative: torch.Tensor,
    design: torch.Tensor,
    sigma: torch.Tensor,
    machine_sigma: torch.Tensor,
    episode: torch.Tensor,
    n_episodes: int,
) -> torch.Tensor:
    """Posterior mean of each episode's log-factors eta_e, (E, 3)."""
    variance = ((derivative * sigma) ** 2).sum(dim=-1) + VARIANCE_FLOOR
    g, c = _scaled(residual, design, variance, machine_sigma, episode, n_episodes)
    eye = torch.eye(3, dtype=g.dtype).expand_as(g)
    return -machine_sigma[None, :] * torch.linalg.solve(eye + g, c[:, :, None])[:, :, 0]


def _scaled(
    residual: torch.Tensor,
    design: torch.Tensor,
    variance: torch.Tensor,
    machine_sigma: torch.Tensor,
    episode: torch.Tensor,
    n_episodes: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """G = S M S (E, 3, 3) and c = S b (E, 3) of the module docstring."""
    m, b = episode_sums(residual, design, variance, episode, n_episodes)
    s = machine_sigma
    return s[None, :, None] * m * s[None, None, :], s[None, :] * b
