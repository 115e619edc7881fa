"""The model's own violation rate under a profile (heldout.json's `model_rate`): what the PPANN
predicts the held-out machines' rate to be, from its own Monte-Carlo in the OCP's mode and the
profile's loop, with the model's transmission error (control/tail.py)."""

from __future__ import annotations

from typing import Any

import numpy as np

from common import streams
from control.config import OCPConfig
from control.ocp_file import Profile
from control.tail import crank_angles, lowered_sliders, share_below
from ppann.heads import FusedHeads
from ppann.montecarlo import Feedback


def model_rate(
    heads: FusedHeads,
    planned: Profile,
    c: OCPConfig,
    *,
    n_samples: int,
    law: Feedback | None,
) -> dict[str, Any]:
    """heldout.json's model_rate for one profile and loop (module docstring): `n_samples`
    trajectories of the model under `planned`'s torque, open loop or under `law`, simulated up
    to the last constraint sample only (every draw a prefix of the whole run's)."""
    crank = crank_angles(
        heads,
        np.array([planned.theta[0], planned.omega[0]]),
        planned.tau,
        c,
        draws=n_samples,
        paths=streams.stream(c.mc_seed, "monte_carlo"),
        angles=streams.stream(c.mc_seed, "transmission"),
        feedback=law,
    )
    lowered = lowered_sliders(heads.geometry, crank)
    rate, samples = share_below(lowered, c)
    return {
        "mode": c.mc_mode,
        "draws": n_samples,
        "rate": rate,
        "samples": {str(k): v for k, v in samples.items()},
    }
