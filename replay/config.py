"""How a campaign is played (`ReplayConfig`) and the profiles and modes it knows, in a module of
their own so that the command line can show their defaults without importing the twin."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from common.checks import check_choice, check_count, check_finite, check_seed
from common.errors import CrankError
from common.resources import check_memory
from control.config import PD_GAINS
from control.mpc_config import MPCConfig
from twin import OPERATING_SECONDS
from twin.variability import Variability

MODES = ("open", "closed", "mpc")
DEFAULT_MODES = ("open", "closed")
FEEDBACKS = ("lqr", "pd")
MAX_RUNS = 100_000

CAMPAIGN_BYTES = (0.4e9, 1750.0)
"""Peak memory of a campaign: fixed bytes, and bytes per run of one profile and mode per sample
(measured: 0.62 and 2.97 GB peak for 250 and 2500 runs, 2 profiles x 2 modes x 150 samples)."""
HELDOUT_BYTES = (0.45e9, 3400.0)
"""Peak memory of a held-out check: fixed bytes, and bytes per machine of one profile per sample
(measured: 0.64 and 4.49 GB peak for 200 and 4000 machines, 2 profiles x 150 samples)."""


def loop_label(mode: str, feedback: str) -> str:
    """How a played loop is named in tables and progress lines: the mode, or "PD" for the
    closed loop under the fixed PD."""
    return "PD" if mode == "closed" and feedback == "pd" else mode


def played_line(profile: str, mode: str, *, feedback: str, below: int, runs: int) -> str:
    """The progress line of one profile played in one loop of a held-out check."""
    return f"  {profile} {loop_label(mode, feedback)}: {below} of {runs} below the height"


def check_campaign_memory(runs: int, *, modes: int, horizon: int, held_out: bool = False) -> None:
    """Refuse a campaign (or held-out check) whose replays cannot fit in memory, before any
    simulation (common.resources.ResourceError, with both figures)."""
    fixed, per = HELDOUT_BYTES if held_out else CAMPAIGN_BYTES
    what = f"a held-out check on {runs} machines" if held_out else f"a campaign of {runs} runs"
    check_memory(fixed + per * runs * 2 * modes * horizon, what=what)


"""Most runs per profile and mode (100 000 runs of 150 samples hold ~1 GB of arrays)."""


class ReplayConfigError(CrankError, ValueError):
    """A replay setting is out of its valid range."""


@dataclass(frozen=True)
class ReplayConfig:
    """How a campaign is played. Defaults: 100 runs per profile and mode, the fixed PD of
    control/config.py PD_GAINS."""

    runs: int = 100
    seed: int = 0
    modes: tuple[str, ...] = DEFAULT_MODES
    """open (the torque as planned), closed (plan + LQR or PD), mpc (the online MPC, opt-in:
    it needs the PPANN the plan was solved on)."""
    feedback: str = "lqr"
    """Closed loop: "lqr" (each profile's own gains in ocp.json: the plan's LQR, or for
    robust-pd its PD) or "pd" (kp, kd at every sample)."""
    kp: float = PD_GAINS[0]
    """PD: proportional gain on the angle error, N·m/rad (control/config.py PD_GAINS)."""
    kd: float = PD_GAINS[1]
    """PD: derivative gain on the speed error, N·m·s/rad."""
    max_start_time: float = OPERATING_SECONDS
    """Each machine has run U[0, max_start_time] s before its replay (warm-up drift), s; the
    same range as the dataset's episodes (twin.OPERATING_SECONDS)."""
    variability: Variability = field(default_factory=Variability)
    mpc: MPCConfig = field(default_factory=MPCConfig)
    """The online MPC of the mpc mode (control/mpc.py)."""

    def __post_init__(self) -> None:
        check_count("runs", self.runs, high=MAX_RUNS, error=ReplayConfigError)
        check_seed("seed", self.seed, error=ReplayConfigError)
        for name in ("kp", "kd", "max_start_time"):
            check_finite(name, getattr(self, name), nonneg=True, error=ReplayConfigError)
        check_choice("feedback", self.feedback, FEEDBACKS, error=ReplayConfigError)
        if not self.modes or any(m not in MODES for m in self.modes):
            raise ReplayConfigError(
                f"modes must be a non-empty subset of {MODES}, got {self.modes}"
            )
        if len(set(self.modes)) != len(self.modes):
            raise ReplayConfigError(f"modes repeat: {self.modes}")

    def as_dict(self) -> dict:
        return asdict(self)
