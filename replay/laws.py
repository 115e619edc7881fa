"""The feedback law a replay plays, and the PPANN's slider spread under it.

Closed loop, a replay applies the profile's own gains from ocp.json (its LQR; robust-pd's
fixed PD) or the replay's fixed PD (`feedback="pd"`); the MPC is, while no bound is active, the
LQR of its own weights along the plan (control/mpc.py, MPCRecord.gains).

ocp.json carries each profile's Monte-Carlo slider σ open loop and closed under its own gains.
Beside a replay of another law (the fixed PD on a profile whose own gains are an LQR, or the
MPC) that σ is the prediction for a law nobody played: `predicted_sigma` runs the solve's own
Monte-Carlo (control/tightening.py slider_uncertainty: the plan's OCP settings and draws) under
the law that was played instead. For the profile's own law it returns the file's σ, which that
Monte-Carlo reproduces bit for bit (tests/test_replay.py). `predicted_bands` is the PPANN's
Monte-Carlo of a plan in each mode, as the held-out check and `crank verify` set it beside
the machines'.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from control.ocp_file import OCPFile, Profile
from replay.config import ReplayConfig

if TYPE_CHECKING:
    from control.ocp import Solution
    from ppann.heads import FusedHeads
    from ppann.montecarlo import Bands, Feedback


def closed_loop_gains(profile: Profile, config: ReplayConfig) -> np.ndarray:
    """The closed loop's gains on the angle and speed errors before samples 1..N-1, (N-1, 2):
    the profile's own gains in ocp.json (its LQR; robust-pd's fixed PD), or the fixed PD (kp,
    kd) of `config` at every sample. The twin's law (`tracking_law`) and the held-out check's
    closed-loop Monte-Carlo both use these."""
    if config.feedback == "pd":
        return np.tile([config.kp, config.kd], (len(profile.gain_theta), 1))
    return own_gains(profile)


def own_gains(profile: Profile) -> np.ndarray:
    """The profile's own gains in ocp.json, (N-1, 2): its LQR, or robust-pd's fixed PD."""
    return np.stack([profile.gain_theta, profile.gain_omega], axis=-1)


def plays_own_law(profile: Profile, config: ReplayConfig) -> bool:
    """Whether the closed loop of `config` applies the gains the profile's tube was sized
    with: its own (feedback "lqr"), or a fixed PD equal to them (robust-pd under "pd")."""
    return bool(np.array_equal(closed_loop_gains(profile, config), own_gains(profile)))


def played_gains(
    profile: Profile, mode: str, config: ReplayConfig, *, mpc_gains: np.ndarray | None = None
) -> np.ndarray | None:
    """The feedback gains (N-1, 2) a replay in `mode` applied: None open loop, the closed
    loop's (`closed_loop_gains`), or the MPC's LQR (`mpc_gains`,
    MPCRecord.gains)."""
    if mode == "open":
        return None
    if mode == "closed":
        return closed_loop_gains(profile, config)
    if mpc_gains is None:
        raise ValueError("the mpc mode's law is its own LQR: give mpc_gains (MPCRecord.gains)")
    return mpc_gains


def profile_solution(profile: Profile, ocp: OCPFile) -> Solution:
    """A profile of ocp.json as the solve's `Solution` (the Monte-Carlo needs its torque, its
    states and the mechanism; nothing of the solver's is kept in the file)."""
    from control.ocp import Solution

    return Solution(
        tau=profile.tau,
        states=np.stack([profile.theta, profile.omega], axis=-1),
        heights=profile.heights,
        cost=profile.cost,
        status=profile.status,
        iterations=profile.ipopt_iterations,
        wall_time=profile.wall_time_s,
        turn_passes=0,
        geometry=ocp.geometry,
        lam_g=np.zeros(0),
        lam_x=np.zeros(0),
    )


def predicted_sigma(
    ocp: OCPFile,
    profile: str,
    gains: np.ndarray | None,
    *,
    heads: FusedHeads | None,
) -> np.ndarray | None:
    """The PPANN's slider σ (N,), m, of `profile` played open loop (`gains` None) or under
    `gains`: the file's where that is the profile's own law, else the solve's Monte-Carlo under
    `gains` on `heads` (the plan's PPANN); None if that law needs `heads` and there are none."""
    planned = ocp.profiles[profile]
    if gains is None:
        return planned.slider_sigma_open
    if np.array_equal(gains, own_gains(planned)):
        return planned.slider_sigma_closed
    if heads is None:
        return None
    from control.tightening import slider_uncertainty

    return slider_uncertainty(heads, profile_solution(planned, ocp), ocp.config, gains=gains).std


def predicted_bands(
    heads: FusedHeads,
    ocp: OCPFile,
    planned: Profile,
    *,
    law: Feedback | None,
    n_samples: int,
    modes: tuple[str, ...] | None = None,
) -> tuple[dict[str, Bands], np.ndarray]:
    """The PPANN's Monte-Carlo of `planned` in each of `modes` (default every mode), open loop
    or under `law`, on the plan's own stream; and the crank's angle to the motor
    (ppann/transmission.py), one draw per trajectory, the same for every mode and sample: the
    slider of trajectory i at sample k is x(θ_ik + delta_i)."""
    from common import streams
    from ppann.modes import MODES
    from ppann.montecarlo import monte_carlo
    from ppann.transmission import draw

    seed = ocp.config.mc_seed
    bands = {
        mode: monte_carlo(
            heads,
            [planned.theta[0], planned.omega[0]],
            planned.tau[:-1],
            n_samples=n_samples,
            mode=mode,
            seed=streams.stream(seed, "monte_carlo"),
            feedback=law,
        )
        for mode in (MODES if modes is None else modes)
    }
    return bands, draw(heads.transmission, (n_samples,), streams.rng(seed, "transmission"))
