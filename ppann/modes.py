"""The Monte-Carlo modes (ppann/montecarlo.py's docstring says what each draws), in a module of
their own so that configurations can check a mode name without importing torch."""

from __future__ import annotations

from dataclasses import dataclass

from common.checks import check_choice


@dataclass(frozen=True)
class DrawMode:
    """How one Monte-Carlo mode draws: its white z and its machine."""

    white: str | None
    """"step": a fresh eps every step; "held": one eps per trajectory; None: z = z_mu."""
    machine: bool
    """One log-normal machine exp(eta) per trajectory."""
    description: str


MONTE_CARLO_MODES: dict[str, DrawMode] = {
    "step": DrawMode("step", False, "fresh z every step (paper eq. 11)"),
    "trajectory": DrawMode("held", False, "one z per trajectory (may diverge)"),
    "machine": DrawMode(None, True, "one machine per trajectory (log-normal), no white noise"),
    "mixed": DrawMode("step", True, "one machine per trajectory plus white z every step"),
}
MODES: tuple[str, ...] = tuple(MONTE_CARLO_MODES)


def check_mode(mode: str, *, error: type[Exception] = ValueError) -> None:
    check_choice("Monte-Carlo mode", mode, MODES, error=error)
