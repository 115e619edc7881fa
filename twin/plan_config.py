"""The chain's plan round as configuration (`[plan]` of crank.toml; the round: plan_data.py)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from common.checks import check_count, check_finite
from common.errors import ConfigError

DITHER_SAMPLES = 10
"""Samples the dither's white noise is averaged over (20 ms at 500 Hz)."""
MAX_EPISODES = 10_000


@dataclass(frozen=True, kw_only=True)
class PlanConfig:
    """The chain's plan round; `episodes` = 0 runs none."""

    episodes: int = 240
    """Machines the first solve's torque is played on, each one added episode. The default
    since session 62, with `TrainConfig.mean_wrap` (whose docstring has the evidence): the
    chain trains and solves twice, about +80 % of `crank run`'s time. 0: one round."""
    dither: float = 0.3
    """Standard deviation of the smooth dither added to the planned torque, N·m."""

    def __post_init__(self) -> None:
        check_count("plan.episodes", self.episodes, low=0, high=MAX_EPISODES)
        check_finite("plan.dither", self.dither)
        if not 0.0 <= self.dither <= 5.0:
            raise ConfigError(f"plan.dither must be in [0, 5] N·m, got {self.dither:g}")

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)
