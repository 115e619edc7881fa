"""The PPANN's spread of a plan split as its Monte-Carlo draws it (`crank verify`): the white
part alone (mode step: a machine at the line's centre, run after run) and the machines alone
(mode machine: the line's machine-to-machine spread, no white noise), in the profile's loop,
with the held-out check's draws. Runs recorded on one machine are read against the first; the
second is the scale on which their mean says where that machine sits (replay/verify.py)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from control.ocp_file import OCPFile
from replay.spread_interval import CALIBRATION_TRAJECTORIES

if TYPE_CHECKING:
    from ppann.model import PPANN

SPLIT_MODES = {"white": "step", "machine": "machine"}
"""The parts of the PPANN's spread and the Monte-Carlo mode that draws each alone
(ppann/modes.py)."""


def spread_split(
    ocp: OCPFile, profile: str, model: PPANN, *, n_samples: int = CALIBRATION_TRAJECTORIES
) -> dict[int, dict[str, float]]:
    """The PPANN's σ of the slider and of θ ("theta_" keys) at each constraint sample from its
    white part alone and from its machines alone (SPLIT_MODES), in the profile's loop (closed:
    under its own gains), with the held-out check's draws (replay/laws.py predicted_bands)."""
    from ppann.heads import FusedHeads
    from ppann.montecarlo import Feedback
    from replay.laws import own_gains, predicted_bands

    plan, c = ocp.profiles[profile], ocp.config
    law = None
    if plan.loop == "closed":
        states = np.stack([plan.theta, plan.omega], axis=-1)
        law = Feedback(states, own_gains(plan), c.torque_limit)
    modes = tuple(SPLIT_MODES.values())
    bands, delta = predicted_bands(
        FusedHeads(model), ocp, plan, law=law, n_samples=n_samples, modes=modes
    )
    x = ocp.geometry.slider_position
    split: dict[int, dict[str, float]] = {k: {} for k in c.constraint_samples}
    for k in c.constraint_samples:
        for part, mode in SPLIT_MODES.items():
            theta = bands[mode].samples[:, k - 1, 0]
            split[k][part] = float(np.std(x(theta + delta), ddof=1))
            split[k][f"theta_{part}"] = float(np.std(theta, ddof=1))
    return split
