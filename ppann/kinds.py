"""The model kinds, in one table: what each is, how a fresh one is made and how a checkpoint's
config rebuilds it, and whether it has the sigma phase.

  ppann     eq. 14: prior + mean networks (phase 1), then sigma networks (phase 2, eq. 9).
  physics   eq. 13 alone with J_m, B_m, K_m fitted by the same phase 1; no uncertainty.
  blackbox  an MLP for alpha with no physics, same phase 1; no uncertainty.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import torch

from common.checks import check_choice
from common.errors import CrankError
from ppann.baselines import BlackBox, BlackBoxConfig
from ppann.model import PPANN, PPANNConfig


class ModelKindError(CrankError, ValueError):
    """An unknown model kind."""


@dataclass(frozen=True)
class ModelKind:
    description: str
    config_type: type
    model_type: type[torch.nn.Module]
    defaults: dict[str, Any] = field(default_factory=dict)
    """Config fields of a fresh model of this kind that differ from the config type's defaults."""
    sigma_phase: bool = False
    """Trained in two phases (mean, then sigma networks); else phase 1 only."""

    def new(self, config: Any | None = None) -> torch.nn.Module:
        """An untrained model, of `config` or of this kind's defaults."""
        return self.model_type(config or self.config_type(**self.defaults))

    def build(self, config: dict[str, Any]) -> torch.nn.Module:
        """The model a checkpoint's config dict describes (weights not loaded)."""
        return self.model_type(self.config_type(**config))


MODEL_KINDS: dict[str, ModelKind] = {
    "ppann": ModelKind("prior + mean networks, then sigma networks", PPANNConfig, PPANN, {}, True),
    "physics": ModelKind(
        "eq. 13 alone, J_m, B_m, K_m fitted", PPANNConfig, PPANN, {"use_networks": False}
    ),
    "blackbox": ModelKind("an MLP for alpha, no physics", BlackBoxConfig, BlackBox),
}
KINDS: tuple[str, ...] = tuple(MODEL_KINDS)


def model_kind(kind: str) -> ModelKind:
    check_choice("model kind", kind, KINDS, error=ModelKindError)
    return MODEL_KINDS[kind]
