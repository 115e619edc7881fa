"""The prior's Coulomb friction (beyond the paper; `PPANNConfig.coulomb`), in one expression for
torch, NumPy and CasADi.

Eq. 14's damping term B_m (1 + z_B) omega vanishes with omega, so a friction that keeps its sign
down to omega = 0 is beyond it. A slider-crank has two: the motor's, a constant torque, and the
slider's, a constant force F on the slide that reaches the motor through the kinematics as
x'(theta) F sign(x'(theta) omega) (the slider moves at x' omega): nothing at the dead centres, most
mid-stroke. Both, smoothed by tanh at `speed` rad/s of the motor (`speed` times the crank length,
m/s, of the slider):

    friction(theta, omega) = C tanh(omega / speed) + F x'(theta) tanh(x'(theta) omega / (speed l1)).

C and F are fitted in phase 1 (ppann/model.py, `coulomb_log`); a machine's damping factor scales
both (ppann/machine.py).
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

from twin.geometry import Geometry


def coulomb_friction(
    theta: Any,
    omega: Any,
    *,
    motor: Any,
    load: Any,
    speed: float,
    geometry: Geometry,
    lib: ModuleType,
) -> Any:
    """The friction torque (module docstring) at theta, omega, N·m; motor torque C (N·m) and
    slider force F (N) as numbers or tensors; `lib` numpy, torch or casadi."""
    slope = geometry.slider_slope(theta, lib)
    slide = speed * geometry.crank_length
    return motor * lib.tanh(omega / speed) + load * slope * lib.tanh(slope * omega / slide)
