"""Settings of the online MPC (control/mpc.py), in a module without CasADi so that the command
line can show their defaults."""

from __future__ import annotations

from dataclasses import asdict, dataclass

from common.checks import check_count, check_finite
from common.errors import CrankError

DEADLINE = 2e-3
"""One sample at 500 Hz, s."""


class MPCConfigError(CrankError, ValueError):
    """An MPC setting is out of range, or does not fit the plan."""


@dataclass(frozen=True)
class MPCConfig:
    """Settings of the online MPC. Default weights: Bryson's rule with the LQR's acceptable
    deviations (20 mrad, 1 rad/s, 1 N·m; control/lqr.py), so that the two loops compare."""

    horizon: int = 10
    """H, samples predicted at every step (20 ms). bench/bench_mpc.py, idle: one step took 0.32 ms
    median (p99 0.72) at 10, 0.56 at 30 and 1.14 at 60 compiled, 1.15 at 30 on CasADi's virtual
    machine, against the 2 ms deadline; 10 leaves room on a busy machine and without a compiler,
    and the Riccati cost-to-go at the horizon's end stands for what lies beyond it (with no bound
    active the MPC is the LQR at any horizon)."""
    q_theta: float = 0.02**-2
    q_omega: float = 1.0
    r: float = 1.0
    deadline: float = DEADLINE
    """Compute time allowed per step, s."""
    compiled: bool = True
    """Compile the prediction to C (the system's C compiler; CasADi's virtual machine if there
    is none)."""
    slider_limit: bool = False
    """Also hold the OCP's slider height at its constraint samples in the QP, linearised about
    the prediction, while they are within the horizon (control/mpc.py, `SliderLimit`)."""

    def __post_init__(self) -> None:
        check_count("mpc horizon", self.horizon, error=MPCConfigError)
        for name in ("q_theta", "q_omega", "r"):
            check_finite(f"mpc {name}", getattr(self, name), nonneg=True, error=MPCConfigError)
        check_finite("mpc deadline", self.deadline, positive=True, error=MPCConfigError)
        for name in ("compiled", "slider_limit"):
            if not isinstance(getattr(self, name), bool):
                raise MPCConfigError(
                    f"mpc {name} must be true or false, got {getattr(self, name)!r}"
                )
        if self.r == 0 and self.q_omega == 0:
            raise MPCConfigError(
                "mpc weights: r and q_omega are both 0, so the torque is not determined "
                "(the first torque moves only the next speed); give r > 0 or q_omega > 0"
            )

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def check_fits(config: MPCConfig, plan_samples: int) -> None:
    """Refuse a horizon longer than the plan's steps (before anything is simulated)."""
    if config.horizon > plan_samples - 1:
        raise MPCConfigError(
            f"mpc horizon {config.horizon} is longer than the plan's {plan_samples - 1} steps"
        )
