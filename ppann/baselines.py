"""Baselines trained with the same data and loop as the PPANN.

- physics-only: eq. 13 with J_m, B_m, K_m fitted and no networks
  (`PPANNConfig(use_networks=False)`).
- black box: alpha = MLP(sin theta, cos theta, omega / omega_scale, tau / tau_scale), one hidden
  layer of 217 tanh neurons (1 303 parameters, as many as the PPANN's three mean networks), the
  same forward Euler and theta' = omega.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

from ppann.activation import Tanh


@dataclass(frozen=True)
class BlackBoxConfig:
    hidden: int = 217
    omega_scale: float = 50.0
    tau_scale: float = 5.0
    dt: float = 1 / 500

    def as_dict(self) -> dict:
        return asdict(self)


class BlackBox(nn.Module):
    """A neural ODE for alpha with no physics."""

    def __init__(self, config: BlackBoxConfig | None = None) -> None:
        super().__init__()
        self.config = config or BlackBoxConfig()
        self.net = nn.Sequential(
            nn.Linear(4, self.config.hidden), Tanh(), nn.Linear(self.config.hidden, 1)
        )
        self.double()

    def step(
        self, x: torch.Tensor, tau: torch.Tensor, z: torch.Tensor | None = None
    ) -> torch.Tensor:
        theta, omega = x[..., 0], x[..., 1]
        c = self.config
        g = torch.stack(
            [torch.sin(theta), torch.cos(theta), omega / c.omega_scale, tau / c.tau_scale], -1
        )
        alpha = 1000.0 * self.net(g)[..., 0]  # network output in units of 1000 rad/s²
        return torch.stack([theta + c.dt * omega, omega + c.dt * alpha], dim=-1)
