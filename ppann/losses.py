"""The two training losses: N-step-ahead MSE (paper eq. 5) and the propagated NLL (eq. 9).

Eq. 9 for three PNNs. With the implicit (torque-balance) form of eq. 14,

    r = J_m (1 + z_J) alpha + B_m (1 + z_B) omega + K_m (1 + z_K) theta_mod - tau,

evaluated at the mean z, its derivatives are closed-form: dr/dz_J = J_m alpha,
dr/dz_B = B_m omega, dr/dz_K = K_m theta_mod (with `PPANNConfig.coulomb` r also has the
Coulomb friction of ppann/friction.py, which no z scales). Independent z_i give the residual
variance s^2 = sum_i (dr/dz_i sigma_i)^2 and the loss (1 / 2N) sum_k (r_k^2 / s_k^2 + log s_k^2).
"""

from __future__ import annotations

import torch

from ppann.model import theta_mod

VARIANCE_FLOOR = 1e-12
"""Added to s^2 so that a sample with alpha = omega = theta_mod = 0 cannot divide by zero."""


def n_step_mse(prediction: torch.Tensor, target: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """Eq. 5 over windows and steps, each state divided by its scale (2,)."""
    return (((prediction - target) / scale) ** 2).mean()


def gaussian_nll(residual: torch.Tensor, variance: torch.Tensor) -> torch.Tensor:
    """(1 / 2N) sum (r^2 / s^2 + log s^2)."""
    return 0.5 * (residual**2 / variance + torch.log(variance)).mean()


def propagated_terms(
    model: torch.nn.Module,
    theta: torch.Tensor,
    omega: torch.Tensor,
    tau: torch.Tensor,
    alpha: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Residual r (n,) at the mean z and its derivatives dr/dz (n, 3), in closed form."""
    z = model.z_mean(theta, omega)
    j, b, k = model.physical
    angle = theta_mod(theta)
    residual = (
        j * (1 + z[:, 0]) * alpha + b * (1 + z[:, 1]) * omega + k * (1 + z[:, 2]) * angle - tau
    )
    if model.config.coulomb:  # the prior's Coulomb torque (PPANNConfig.coulomb): no z of its own
        residual = residual + model.friction(theta, omega)
    derivative = torch.stack([j * alpha, b * omega, k * angle], dim=-1)
    return residual, derivative


def propagated_nll(
    residual: torch.Tensor, derivative: torch.Tensor, sigma: torch.Tensor
) -> torch.Tensor:
    """Eq. 9 for several PNNs: variance = sum_i (dr/dz_i sigma_i)^2."""
    variance = ((derivative * sigma) ** 2).sum(dim=-1) + VARIANCE_FLOOR
    return gaussian_nll(residual, variance)
