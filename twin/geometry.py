"""The mechanism's geometry, read from the compiled MJCF: one source for every stage.

`Geometry.of_model` reads the crank length l1 (the `crank_pin` site's distance from the motor axis)
and the rod length l2 (the `rod_tip` site's distance from the rod's pivot) from the model's named
elements, and checks that the rest of the MJCF agrees with them (the rod hangs on the crank pin,
the slider joint's reference puts x = 0 at bottom dead centre and 2 l1 at top dead centre). The
dataset, the checkpoint and ocp.json carry it (`as_dict`), and each stage refuses inputs made on
another geometry (`check_same`).

`slider_position` is the one kinematics function, written once for NumPy and CasADi:
x = l1 cos(theta) + sqrt(l2^2 - l1^2 sin^2(theta)) + l1 - l2 (0 at bottom dead centre, theta = pi).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from common.errors import ConfigError, CrankError

if TYPE_CHECKING:
    import mujoco

TOLERANCE = 1e-9
"""Lengths that differ by less than this (m) are the same geometry."""


class GeometryError(CrankError, ValueError):
    """Two stages' inputs were made on different mechanisms, or an MJCF is inconsistent."""


@dataclass(frozen=True)
class Geometry:
    """Crank length l1 and connecting-rod length l2 in m (paper section 3.1: 0.05 and 0.3)."""

    crank_length: float = 0.05
    rod_length: float = 0.3

    def __post_init__(self) -> None:
        for name in ("crank_length", "rod_length"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and np.isfinite(value) and value > 0):
                raise ConfigError(f"geometry: {name} must be a positive length in m, got {value}")
        if self.rod_length <= self.crank_length:
            raise ConfigError(
                f"geometry: the rod ({self.rod_length} m) must be longer than the crank "
                f"({self.crank_length} m), or the slider locks"
            )

    @property
    def stroke_top(self) -> float:
        """Highest slider position (top dead centre), m; the lowest is 0."""
        return 2.0 * self.crank_length

    def slider_position(self, theta: Any, lib: ModuleType = np) -> Any:
        """Slider position for crank angle `theta` (rad); `lib` is numpy or casadi."""
        l1, l2 = self.crank_length, self.rod_length
        return l1 * lib.cos(theta) + lib.sqrt(l2**2 - (l1 * lib.sin(theta)) ** 2) + l1 - l2

    def slider_slope(self, theta: Any, lib: ModuleType = np) -> Any:
        """dx/dtheta of `slider_position`, m/rad, written out; `lib` is numpy, torch or casadi:
        -l1 sin(theta) (1 + l1 cos(theta) / sqrt(l2^2 - l1^2 sin^2(theta)))."""
        l1, l2 = self.crank_length, self.rod_length
        s, c = lib.sin(theta), lib.cos(theta)
        return -l1 * s * (1 + l1 * c / lib.sqrt(l2**2 - (l1 * s) ** 2))

    def crank_reach(self, x: npt.ArrayLike) -> np.ndarray:
        """The crank angle from top dead centre within which the slider is at or above `x` (m):
        slider_position(theta) >= x where |theta| <= crank_reach(x), theta taken to (-pi, pi]
        (the slider falls monotonically from theta = 0 to pi since l2 > l1), rad; pi at or below
        the stroke's bottom, -inf above its top (no angle reaches it). In closed form, well
        conditioned at both dead centres: with C = x - l1 + l2, 1 - cos(theta) = (2 l1 - x)
        (x + 2 l2 - 2 l1) / (2 C l1) and 1 + cos(theta) = x (x + 2 l2) / (2 C l1), so theta =
        2 atan2(sqrt((2 l1 - x)(x + 2 l2 - 2 l1)), sqrt(x (x + 2 l2)))."""
        l1, l2 = self.crank_length, self.rod_length
        x = np.asarray(x, dtype=float)
        inside = np.clip(x, 0.0, self.stroke_top)
        half = np.arctan2(
            np.sqrt((self.stroke_top - inside) * (inside + 2 * (l2 - l1))),
            np.sqrt(inside * (inside + 2 * l2)),
        )
        return np.where(x > self.stroke_top, -np.inf, 2 * half)

    def rod_angle(self, theta: npt.ArrayLike) -> np.ndarray:
        """phi = asin(l1/l2 sin(theta)), the rod's angle from the slide axis (rad)."""
        return np.arcsin(self.crank_length / self.rod_length * np.sin(np.asarray(theta, float)))

    def within_stroke(self, x: npt.ArrayLike) -> np.ndarray:
        """Slider positions clipped to the stroke [0, stroke_top]: how a predicted or observed
        mean -/+ k sigma is drawn, since no slider can leave it however wide the spread."""
        return np.clip(x, 0.0, self.stroke_top)

    def as_dict(self) -> dict[str, float]:
        return {"crank_length": self.crank_length, "rod_length": self.rod_length}

    @classmethod
    def from_dict(cls, values: dict[str, Any] | None, *, source: str) -> Geometry:
        """The geometry an artifact records; an artifact from before geometry was recorded was
        made on the paper's mechanism (the only one then possible).

        Raises:
          GeometryError: a key is missing or not a length.
        """
        if values is None:
            return cls()
        try:
            return cls(float(values["crank_length"]), float(values["rod_length"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise GeometryError(f"{source}: not a geometry record ({exc})") from None

    def check_same(self, other: Geometry, *, this: str, that: str) -> None:
        """Refuse to combine artifacts of two mechanisms, naming both.

        Raises:
          GeometryError: l1 or l2 differ by more than TOLERANCE.
        """
        if (
            abs(self.crank_length - other.crank_length) > TOLERANCE
            or abs(self.rod_length - other.rod_length) > TOLERANCE
        ):
            raise GeometryError(
                f"{this} is for a mechanism with l1 = {self.crank_length:g} m, "
                f"l2 = {self.rod_length:g} m, but {that} has l1 = {other.crank_length:g} m, "
                f"l2 = {other.rod_length:g} m"
            )

    @classmethod
    def of_model(cls, model: mujoco.MjModel) -> Geometry:
        """The geometry of a compiled slider-crank, checked for consistency.

        Raises:
          GeometryError: a named element is missing, or the elements disagree on l1 or l2.
        """
        import mujoco

        def element(kind: mujoco.mjtObj, name: str) -> int:
            index = mujoco.mj_name2id(model, kind, name)
            if index < 0:
                raise GeometryError(f"the MJCF has no {kind.name[6:].lower()} named {name!r}")
            return index

        pin = model.site_pos[element(mujoco.mjtObj.mjOBJ_SITE, "crank_pin")]
        tip = model.site_pos[element(mujoco.mjtObj.mjOBJ_SITE, "rod_tip")]
        rod = model.body_pos[element(mujoco.mjtObj.mjOBJ_BODY, "rod")]
        slider_body = model.body_pos[element(mujoco.mjtObj.mjOBJ_BODY, "slider")]
        slider_joint = element(mujoco.mjtObj.mjOBJ_JOINT, "slider")
        l1, l2 = float(np.linalg.norm(pin)), float(np.linalg.norm(tip))
        geometry = cls(l1, l2)
        if np.abs(rod - pin).max() > TOLERANCE:
            raise GeometryError(
                f"the MJCF's rod pivots at {rod.tolist()}, not at the crank_pin {pin.tolist()}"
            )
        ref = float(model.qpos0[model.jnt_qposadr[slider_joint]])
        # The slider's height is body z + (x - ref); at top dead centre x = 2 l1 and the pin is
        # at l1 + l2 above the motor axis.
        top = float(slider_body[2]) + geometry.stroke_top - ref
        if abs(top - (l1 + l2)) > 1e-6:
            raise GeometryError(
                f"the MJCF's slider puts top dead centre at {top:g} m above the motor axis, but "
                f"its crank (l1 = {l1:g} m) and rod (l2 = {l2:g} m) reach {l1 + l2:g} m: set the "
                f"slider joint's ref to 2 l1 = {geometry.stroke_top:g} and the slider body at "
                f"z = l1 + l2"
            )
        return geometry


PAPER = Geometry()
"""The paper's mechanism (section 3.1), the default twin's."""
