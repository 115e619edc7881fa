"""The records of a robust solve (control/robust.py): each solve of the margin loop, the result,
and what a failed loop leaves."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.errors import NoSolutionError
from control.config import OCPConfig
from control.ocp import Solution
from control.tail import TailCheck
from control.tightening import Uncertainty


class RobustError(NoSolutionError, RuntimeError):
    """The robust iteration did not reach a margin that its own Monte-Carlo confirms. Raised by
    solve_robust with `partial` set: what was solved before it failed; by solve_profiles, when
    every profile failed, with `partials` set too: each profile's."""

    partial: Partial | None = None
    partials: dict[str, Partial] | None = None
    tail_checked: bool = False
    """The refusal came after a torque's own tail check (control/profiles.py solve_decided; of
    any profile, for solve_profiles): without the check, the loop's torque might stand."""


class BeyondStrokeError(RobustError):
    """The model's tightening at a constraint sample exceeds the stroke left above the height:
    no open-loop profile exists for this model and task. Carries the figures, m."""

    def __init__(
        self,
        message: str,
        *,
        sample: int,
        tightening: float,
        available: float,
        line: float,
        se: float = 0.0,
    ) -> None:
        super().__init__(message)
        self.sample = sample
        self.tightening = tightening
        self.available = available
        self.line = line
        self.se = se
        """The tightening's Monte-Carlo standard error, m."""


@dataclass(frozen=True)
class Iteration:
    """One robust solve: the margin it used, the tightening its solution asks for, its cost."""

    margin: np.ndarray
    tightening: np.ndarray
    """The tightening (k·σ or plan − quantile) the solution's Monte-Carlo asks for, m."""
    tightening_se: np.ndarray
    cost: float
    ipopt_iterations: int
    solve_time: float
    monte_carlo_time: float
    damping: float
    draft: bool
    """A draft solve (one loose pass) rather than a full one."""
    k_sigma: float
    """The k its tightening was computed at (the configured one, or raised at a draft:
    control/profiles.py `_draft_raise`)."""
    profile: str = "robust"
    """The robust profile (control/config.py ROBUST_PROFILES) this solve was for."""
    samples: int = 0
    """Trajectories of its Monte-Carlo (control/profiles.py may draw more than configured)."""
    scheme: str = "bracket"
    """The margin scheme that made this solve (OCPConfig.margin_scheme; "aware": the margin
    is the one the solution keeps, slider - height)."""


@dataclass(frozen=True)
class Partial:
    """A robust solve that failed: the nominal plan (with its gains and spreads, as a result has
    them) and every robust iteration tried."""

    nominal: Solution
    nominal_uncertainty: Uncertainty
    nominal_gains: np.ndarray
    nominal_loops: dict[str, np.ndarray]
    iterations: tuple[Iteration, ...]
    failed_proposals: tuple[np.ndarray, ...]
    wall_time: float


@dataclass(frozen=True)
class RobustResult:
    nominal: Solution
    nominal_uncertainty: Uncertainty
    robust: Solution
    robust_uncertainty: Uncertainty
    iterations: tuple[Iteration, ...]
    """Every robust solve in order (the nominal solve is not among them). The returned one is
    the last full solve, or a full solve held before the draft that showed it sat by a jump
    (control/aware.py, `Acceptance`)."""
    failed_proposals: tuple[np.ndarray, ...]
    """Margins IPOPT could not meet, and which halved the damping."""
    wall_time: float
    """The robust loop: every solve and Monte-Carlo after the nominal solve, the nominal plan's
    own Monte-Carlo included (since session 34), s."""
    nominal_gains: np.ndarray
    """Gains (N-1, 2) of the profile's law (control/config.py law_of) along the nominal plan,
    whatever the loop: its LQR (control/lqr.py), or for robust-pd the fixed PD."""
    robust_gains: np.ndarray
    nominal_loops: dict[str, np.ndarray]
    """Monte-Carlo slider std (N,) of the nominal plan open loop and closed under its gains,
    whatever the tightening was sized for (the replay's rows compare against these)."""
    robust_loops: dict[str, np.ndarray]
    tightening: str
    """The tightening the torque was solved with (OCPConfig.tightening, or "quantile" where its
    own tail sent it there: control/tail.py)."""
    k_sigma: float
    """The k the torque was solved with (OCPConfig.k_sigma, or raised by its own tail's check:
    control/tail.py)."""
    tail_checks: tuple[TailCheck, ...] = ()
    """The torque's own tail, checked (control/tail.py), in order: the configured tightening's
    torque, then, where that was above the target, each torque solved again at a raised k, and
    last, where none of those passed, the quantile tightening's. The last is the one returned
    (its `iterations` are its own loop's). Empty without OCPConfig.tail_check."""


def iteration(
    solution: Solution,
    unc: Uncertainty,
    margin: np.ndarray,
    config: OCPConfig,
    profile: str,
    draft: bool,
    scheme: str,
    damping: float = 1.0,
) -> Iteration:
    """The record of one robust solve with `margin` and its Monte-Carlo `unc`."""
    return Iteration(
        margin=margin,
        tightening=unc.tightening,
        tightening_se=unc.tightening_se,
        cost=solution.cost,
        ipopt_iterations=solution.iterations,
        solve_time=solution.wall_time,
        monte_carlo_time=unc.wall_time,
        damping=damping,
        draft=draft,
        profile=profile,
        samples=config.mc_samples,
        scheme=scheme,
        k_sigma=config.k_sigma,
    )
