"""Settings of the nominal OCP (eq. 15) and of the robust iteration (eq. 16): one frozen,
validated config, and the normal-law helpers the tightening is sized with."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from typing import Any

from common.checks import check_choice, check_count, check_finite, check_seed
from common.errors import CrankError
from ppann.confidence import DEFAULT_CONFIDENCE
from ppann.modes import check_mode


class OCPConfigError(CrankError, ValueError):
    """An OCP setting is out of range."""


TIGHTENINGS = ("centred", "gaussian", "quantile")
MARGIN_SCHEMES = ("aware", "bracket")
TAIL_REMEDIES = ("raise-k", "quantile")
TAIL_SAMPLINGS = ("plain", "lines")
"""What a torque whose own tail is above its target is solved again with (control/tail.py):
"raise-k", the configured tightening at the k its check predicts to bring it to the target,
then the quantile tightening if that does not pass; "quantile", the quantile tightening
straight away (session 30's)."""
ROBUST_PROFILES = {"robust": "open", "robust-fb": "closed", "robust-pd": "closed"}
"""The robust profiles `crank solve` knows, each with the loop its tightening is sized for:
`robust`, open loop (the paper's eq. 16); `robust-fb`, the closed loop under the plan's
time-varying LQR law, saturated at the torque limit (a tube, beyond the paper; control/lqr.py);
`robust-pd`, the closed loop under a fixed PD (`pd_kp`, `pd_kd`: the user's own controller),
saturated too (a tube for the law the machine already runs)."""
FEEDBACK_LAWS = {"robust-fb": "lqr", "robust-pd": "pd"}
"""The feedback law each closed-loop profile's tube is sized for, and which ocp.json's gains
of that profile are (`law_of`)."""
PD_GAINS = (20.0, 0.5)
"""The fixed PD: Kp on the angle error, N·m/rad, and Kd on the speed error, N·m·s/rad (closed-
loop bandwidth ≈ 13 Hz on J ≈ 3e-3 kg·m², within the 2 ms sampling). One source for the
robust-pd tube (OCPConfig) and the replays' closed loop under "pd" (replay/config.py)."""
GAUSSIAN_SAMPLES = 1000
"""Default Monte-Carlo size for gaussian tightening: k·σ to 2.2 % standard error (100 gave 7 %)."""
QUANTILE_TAIL = 20
"""Quantile tightening draws enough trajectories that this many fall beyond the quantile."""
MAX_MC_SAMPLES = 200_000
"""Most Monte-Carlo trajectories (150 steps of 200 000 samples hold ~0.5 GB)."""
TARGET_RATE = 0.005
"""Largest share of the line's machines a robust torque may put below the height: what held-out
machines judge it by (replay/rates.py) and what its own tail is checked against
(control/tail.py)."""


def loop_of(profile: str) -> str:
    """The loop a profile's robust claim is about: "closed" for a profile tightened for a closed
    loop (robust-fb, robust-pd), else "open" (the paper's experiment)."""
    return ROBUST_PROFILES.get(profile, "open")


def loops_of(profiles: Iterable[str]) -> tuple[str, ...]:
    """The loops the robust claims of `profiles` are about (`loop_of`), "open" first: what a
    held-out check plays."""
    loops = {loop_of(profile) for profile in profiles}
    return tuple(loop for loop in ("open", "closed") if loop in loops)


def law_of(profile: str) -> str:
    """The feedback law of a profile's closed loop and of its gains in ocp.json: "pd" for
    robust-pd (the fixed PD), else "lqr" (the plan's LQR, also the nominal and open-loop
    profiles' gains)."""
    return FEEDBACK_LAWS.get(profile, "lqr")


def lower_tail(k_sigma: float) -> float:
    """The one-sided probability that k·σ stands for under a normal law, Φ(−k)."""
    return 0.5 * math.erfc(k_sigma / math.sqrt(2))


@dataclass(frozen=True)
class OCPConfig:
    """Settings of the nominal OCP (eq. 15) and of the robust iteration (eq. 16)."""

    horizon: int = 150
    """N, samples including the first and last."""
    theta_start: float = math.pi
    omega_start: float = 0.0
    theta_end: float = 3 * math.pi
    omega_end: float = 0.0
    height: float = 0.08
    """Lowest slider position allowed at the constraint samples, m."""
    constraint_samples: tuple[int, ...] = (50, 100)
    """1-based sample indices of the slider constraint."""
    torque_limit: float = 10.0
    """|u| bound, N·m (the twin's actuator range)."""
    smoothness_weight: float = 1e-4
    """Weight of sum((du / Ts)^2) in the cost."""
    k_sigma: float = 3.0
    """k of the robust constraint slider - k sigma >= height (eq. 16)."""
    mc_samples: int = 0
    """Monte-Carlo trajectories per tightening; 0 chooses them for the tightening's precision:
    GAUSSIAN_SAMPLES for centred and gaussian (k·σ to ~2 % standard error), and for quantile
    enough that QUANTILE_TAIL samples fall beyond the quantile."""
    mc_mode: str = "mixed"
    """Monte-Carlo mode (ppann/montecarlo.py): step (eq. 11), trajectory, machine or mixed (the
    default: one machine per trajectory plus white noise, the machine-level model)."""
    tightening: str = "centred"
    """centred (the default since session 17): plan − mean + k·σ, k·σ below the Monte-Carlo's
    mean rather than below the plan; gaussian: k·σ (eq. 16); quantile: plan − the lower quantile
    at Φ(−k) (control/robust.py, control/tightening.py)."""
    confidence: float = DEFAULT_CONFIDENCE
    """Confidence that the robust tightening is not short, beyond the paper (control/robust.py):
    the training machines are a few draws of the line, so its mean and spread are known only to
    within what they show, and the Monte-Carlo estimates the tightening from finitely many
    trajectories. 0 takes the fitted line and the estimate as the truth (the paper's eq. 16)."""
    mc_seed: int = 0
    """Seed of the Monte-Carlo draws; the same draws serve every robust iteration."""
    profiles: tuple[str, ...] = ("robust",)
    """The robust profiles solved beside the nominal one (ROBUST_PROFILES): "robust" (tightened
    for the open loop, the paper's eq. 16), "robust-fb" (the Monte-Carlo runs each machine
    under the time-varying LQR law along the plan, saturated at the torque limit: a tube) and
    "robust-pd" (the same under the fixed PD pd_kp, pd_kd)."""
    fallback: tuple[str, ...] = ("robust-fb",)
    """Robust profiles solved from the same nominal plan only where every one of `profiles` is
    refused (ROBUST_PROFILES; those already in `profiles` are not tried twice; () for none):
    on a line whose spread no open-loop torque keeps above the height, the LQR tube the machine
    can run instead, so that the run ends with a torque that holds and the refusal beside it
    (beyond the paper; ocp.json's `fallback` names what was solved so)."""
    pd_kp: float = PD_GAINS[0]
    """robust-pd: the fixed PD's gain on the angle error, N·m/rad."""
    pd_kd: float = PD_GAINS[1]
    """robust-pd: the fixed PD's gain on the speed error, N·m·s/rad."""
    feedback_theta: float = 0.02
    """LQR: acceptable crank-angle deviation, rad (Bryson: q_theta = 1 / this^2)."""
    feedback_omega: float = 1.0
    """LQR: acceptable speed deviation, rad/s."""
    feedback_torque: float = 1.0
    """LQR: acceptable torque correction, N·m."""
    margin_tolerance: float = 1e-4
    """The robust loop stops when k sigma moves by less than this between iterations, m."""
    margin_scheme: str = "aware"
    """How the open-loop profile's margins are found: "aware" (the tightening inside the NLP
    as a function of theta_k, corrected by the Monte-Carlo: control/aware.py; the bracket
    where it does not settle) or "bracket" (the bracketed secant on the margins alone,
    control/robust.py). The tubes always use the bracket."""
    max_robust_iterations: int = 30
    max_ipopt_iterations: int = 3000
    tail_check: bool = True
    """After a robust profile's loop, check its torque's own violation rate (its Monte-Carlo,
    with the tightening's allowances, in stages of 5000 to 80 000 trajectories until one
    decides) and solve it again with the `tail_remedy` where that rate is above its target,
    TARGET_RATE or what k stands for if looser (control/tail.py): k sigma reads a skewed spread
    as normal. With the quantile tightening the check is recorded and nothing is solved
    again."""
    tail_remedy: str = "raise-k"
    """What the tail check solves such a torque again with (TAIL_REMEDIES)."""
    tail_sampling: str = "lines"
    """How the tail check draws (TAIL_SAMPLINGS): "plain" trajectories (control/tail.py) or
    "lines" (line sampling along the direction the crank runs ahead or behind,
    control/tail_lines.py: the same rate from far fewer trajectories)."""
    compiled: bool = False
    """Compile the NLP's functions to C (CasADi's JIT with the system's C compiler, ~15 s once
    per model; CasADi's virtual machine if there is none). Each IPOPT iteration is then ~3x
    cheaper: worth it when one model is solved many times (tasks, sweeps), not for one run."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "constraint_samples", tuple(self.constraint_samples))
        if self.horizon < 3:
            raise OCPConfigError(f"horizon must be >= 3 samples, got {self.horizon}")
        for name in ("theta_start", "omega_start", "theta_end", "omega_end", "height"):
            check_finite(name, getattr(self, name), error=OCPConfigError)
        for name in (
            "torque_limit",
            "margin_tolerance",
            "feedback_theta",
            "feedback_omega",
            "feedback_torque",
        ):
            check_finite(name, getattr(self, name), positive=True, error=OCPConfigError)
        for name in ("smoothness_weight", "k_sigma", "pd_kp", "pd_kd"):
            check_finite(name, getattr(self, name), nonneg=True, error=OCPConfigError)
        samples = self.constraint_samples
        if not samples:
            raise OCPConfigError("constraint_samples must name at least one sample, got none")
        if len(set(samples)) != len(samples):
            raise OCPConfigError(f"constraint_samples must be distinct, got {samples}")
        bad = [k for k in samples if not 1 < k < self.horizon]
        if bad:
            raise OCPConfigError(
                f"constraint samples {bad} outside 2..{self.horizon - 1} "
                f"(1-based, strictly inside the horizon)"
            )
        check_seed("mc_seed", self.mc_seed, error=OCPConfigError)
        check_finite("confidence", self.confidence, nonneg=True, error=OCPConfigError)
        if self.confidence >= 1:
            raise OCPConfigError(f"confidence must be in [0, 1), got {self.confidence:g}")
        check_mode(self.mc_mode, error=OCPConfigError)
        object.__setattr__(self, "profiles", tuple(self.profiles))
        unknown = [p for p in self.profiles if p not in ROBUST_PROFILES]
        if not self.profiles or unknown or len(set(self.profiles)) != len(self.profiles):
            raise OCPConfigError(
                f"profiles must be distinct names among {', '.join(ROBUST_PROFILES)}, "
                f"got {', '.join(self.profiles) or 'none'}"
            )
        object.__setattr__(self, "fallback", tuple(self.fallback))
        unknown = [p for p in self.fallback if p not in ROBUST_PROFILES]
        if unknown or len(set(self.fallback)) != len(self.fallback):
            raise OCPConfigError(
                f"fallback must be distinct names among {', '.join(ROBUST_PROFILES)} (or none), "
                f"got {', '.join(self.fallback) or 'none'}"
            )
        check_choice("margin_scheme", self.margin_scheme, MARGIN_SCHEMES, error=OCPConfigError)
        check_choice("tightening", self.tightening, TIGHTENINGS, error=OCPConfigError)
        check_choice("tail_remedy", self.tail_remedy, TAIL_REMEDIES, error=OCPConfigError)
        check_choice("tail_sampling", self.tail_sampling, TAIL_SAMPLINGS, error=OCPConfigError)
        check_count("mc_samples", self.mc_samples, low=0, high=MAX_MC_SAMPLES, error=OCPConfigError)
        tail = lower_tail(self.k_sigma)
        needed = GAUSSIAN_SAMPLES
        if self.tightening == "quantile":
            needed = math.ceil(QUANTILE_TAIL / tail) if tail > 0 else MAX_MC_SAMPLES + 1
            if needed > MAX_MC_SAMPLES:
                raise OCPConfigError(
                    f"quantile tightening at k_sigma {self.k_sigma:g} (tail {tail:.2e}) needs "
                    f"{needed} Monte-Carlo samples, more than {MAX_MC_SAMPLES}"
                )
        if self.mc_samples == 0:
            object.__setattr__(self, "mc_samples", needed)
        elif self.mc_samples < 2:
            raise OCPConfigError(f"mc_samples must be >= 2, got {self.mc_samples}")
        elif self.tightening == "quantile" and self.mc_samples < needed:
            raise OCPConfigError(
                f"quantile tightening at k_sigma {self.k_sigma:g} needs >= {needed} Monte-Carlo "
                f"samples ({QUANTILE_TAIL} beyond the {100 * tail:.3g} % quantile), "
                f"got {self.mc_samples}"
            )
        for name in ("compiled", "tail_check"):
            if not isinstance(getattr(self, name), bool):
                raise OCPConfigError(f"{name} must be true or false, got {getattr(self, name)!r}")
        for name in ("max_robust_iterations", "max_ipopt_iterations"):
            if getattr(self, name) < 1:
                raise OCPConfigError(f"{name} must be >= 1, got {getattr(self, name)}")

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["constraint_samples"] = list(self.constraint_samples)
        out["profiles"] = list(self.profiles)
        out["fallback"] = list(self.fallback)
        return out

    @property
    def fallback_profiles(self) -> tuple[str, ...]:
        """The fallback profiles tried where every one of `profiles` is refused: `fallback`
        without those already asked for."""
        return tuple(p for p in self.fallback if p not in self.profiles)
