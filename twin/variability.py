"""Machine-to-machine variability of the slider-crank: uncertain parameters, draws, and the one
function that writes a draw into a compiled model.

A *draw* is one machine of the product line (or the same machine on another day): its Coulomb
friction and viscous damping on the motor and on the slider, its backlash width, and how much its
friction falls as it warms up. Within a run the friction and damping fall smoothly,

    value(t) = nominal_draw * (1 - warmup_drop * (1 - exp(-t / warmup_time_constant))),

with t the time since the machine started; `drift=False` switches this off.

The slider disturbance is white noise: one draw per 2 ms sample, held over the physics substeps,
uniformly distributed on [-amplitude, +amplitude] (default 30 N peak, so its standard deviation is
30 / sqrt(3) = 17.3 N). It is neither measured nor known to a learner.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from common.checks import check_finite
from common.errors import ConfigError

if TYPE_CHECKING:
    import mujoco
from twin.physics import Layout


@dataclass(frozen=True)
class Parameter:
    """An uncertain physical parameter: drawn uniformly from [low, high] for each machine."""

    name: str
    nominal: float
    low: float
    high: float
    unit: str

    def __post_init__(self) -> None:
        for attr in ("nominal", "low", "high"):
            check_finite(f"{self.name}.{attr}", getattr(self, attr), nonneg=True)
        if not self.low <= self.nominal <= self.high:
            raise ConfigError(
                f"{self.name}: need low <= nominal <= high, got "
                f"{self.low} <= {self.nominal} <= {self.high}"
            )

    def sample(self, rng: np.random.Generator) -> float:
        """One draw from U[low, high] (the nominal value when the range is empty)."""
        if self.low == self.high:
            return self.nominal
        return float(rng.uniform(self.low, self.high))

    def fixed(self, value: float | None = None) -> Parameter:
        """This parameter with no spread, at `value` (default: nominal)."""
        value = self.nominal if value is None else value
        return replace(self, nominal=value, low=value, high=value)


@dataclass(frozen=True)
class MachineDraw:
    """One machine of the line: the values its uncertain parameters took."""

    motor_frictionloss: float
    motor_damping: float
    slider_frictionloss: float
    slider_damping: float
    backlash_width: float
    warmup_drop: float

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


@dataclass(frozen=True)
class FrictionState:
    """Friction and damping in effect at one instant (what `apply` writes into the model)."""

    motor_frictionloss: float
    motor_damping: float
    slider_frictionloss: float
    slider_damping: float


@dataclass(frozen=True)
class Variability:
    """Distribution of machines and the disturbance they run under: friction and damping ±5 %
    around the MJCF, a 1-4 % warm-up drop, backlash 0.014-0.026 rad, 30 N white slider force.

    Open loop over the OCP's 0.3 s, persistent machine differences move the crank far more than
    the white force does: with ±30 % friction the slider's 3σ at sample 100 was 70 mm, with ±10 %
    26 mm, with ±5 % 17 mm, with none 14 mm (30 N alone). The step-mode Monte-Carlo (eq. 11)
    models white variability; ±5 % keeps the twin in the regime where it is the right model.
    """

    motor_frictionloss: Parameter = Parameter("motor_frictionloss", 0.03, 0.0285, 0.0315, "N·m")
    motor_damping: Parameter = Parameter("motor_damping", 0.08, 0.076, 0.084, "N·m·s/rad")
    slider_frictionloss: Parameter = Parameter("slider_frictionloss", 1.5, 1.425, 1.575, "N")
    slider_damping: Parameter = Parameter("slider_damping", 8.0, 7.6, 8.4, "N·s/m")
    backlash_width: Parameter = Parameter("backlash_width", 0.02, 0.014, 0.026, "rad")
    warmup_drop: Parameter = Parameter("warmup_drop", 0.025, 0.01, 0.04, "1")
    warmup_time_constant: float = 20.0
    """Time constant of the warm-up drift, in s."""
    drift: bool = True
    """Whether friction and damping drift within a run as the machine warms up."""
    disturbance_amplitude: float = 30.0
    """Peak of the uniform white-noise force on the slider, in N."""
    name: str = "paper"
    """The scenario's name (SCENARIOS, or the stem of a range file)."""

    def __post_init__(self) -> None:
        for p in self.parameters():
            if not isinstance(p, Parameter):
                raise ConfigError(f"variability parameter must be a Parameter, got {p!r}")
        if not isinstance(self.drift, bool):  # a range file's drift = "no" would read as true
            raise ConfigError(f"drift must be true or false, got {self.drift!r}")
        check_finite("warmup_time_constant", self.warmup_time_constant, positive=True)
        check_finite("disturbance_amplitude", self.disturbance_amplitude, nonneg=True)
        if self.warmup_drop.high >= 1:
            raise ConfigError(f"warmup_drop must stay below 1, got high={self.warmup_drop.high}")

    def as_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def scenario(cls, name: str) -> Variability:
        """A named scenario of `SCENARIOS`."""
        if name not in SCENARIOS:
            raise ConfigError(
                f"unknown variability scenario {name!r}; known: {', '.join(SCENARIOS)} "
                "(or a .toml/.json range file)"
            )
        return SCENARIOS[name]()

    @classmethod
    def from_file(cls, path: str | Path) -> Variability:
        """A custom scenario: a TOML or JSON table with `base` (a scenario name, default
        "paper"), optional `name`, and per parameter `{low, high}` (and `nominal`, default the
        base's), e.g. `[motor_damping] low = 0.06  high = 0.10`."""
        path = Path(path)
        try:
            text = path.read_text()
            values = tomllib.loads(text) if path.suffix == ".toml" else json.loads(text)
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise ConfigError(f"cannot read variability file {path}: {exc}") from None
        if not isinstance(values, dict):
            raise ConfigError(f"{path}: a variability file holds a table, got {type(values)}")
        base = cls.scenario(values.pop("base", "paper"))
        changes: dict = {"name": str(values.pop("name", path.stem))}
        names = {p.name for p in base.parameters()}
        for key, value in values.items():
            if key in names:
                if not isinstance(value, dict) or set(value) - {"low", "high", "nominal"}:
                    raise ConfigError(f"{path}: {key} must be a table of low, high (nominal)")
                old = getattr(base, key)
                low, high = value.get("low", old.low), value.get("high", old.high)
                nominal = value.get("nominal", old.nominal)
                if isinstance(low, int | float) and isinstance(high, int | float) and low > high:
                    raise ConfigError(f"{path}: {key} low {low} > high {high}")
                changes[key] = Parameter(key, nominal, low, high, old.unit)
            elif key in ("warmup_time_constant", "drift", "disturbance_amplitude"):
                changes[key] = value
            else:
                raise ConfigError(f"{path}: unknown variability key {key!r}")
        return replace(base, **changes)

    @classmethod
    def resolve(cls, text: str, *, drift: bool = True) -> Variability:
        """`--variability` as given on the command line: a scenario name or a range file."""
        chosen = cls.from_file(text) if text.endswith((".toml", ".json")) else cls.scenario(text)
        return chosen if drift else replace(chosen, drift=False)

    @classmethod
    def from_dict(cls, values: dict) -> Variability:
        """Rebuild from `asdict(variability)`, e.g. a dataset's `run` metadata."""
        try:
            changes = {k: Parameter(**v) if isinstance(v, dict) else v for k, v in values.items()}
            return cls(**changes)
        except TypeError as exc:
            raise ConfigError(f"not a variability description: {exc}") from None

    def parameters(self) -> tuple[Parameter, ...]:
        """The uncertain parameters, in MachineDraw's field order."""
        return tuple(getattr(self, f.name) for f in fields(MachineDraw))

    def sample(self, rng: np.random.Generator) -> MachineDraw:
        """Draw one machine."""
        return MachineDraw(*(p.sample(rng) for p in self.parameters()))

    def nominal(self) -> MachineDraw:
        """The nominal machine."""
        return MachineDraw(*(p.nominal for p in self.parameters()))

    @classmethod
    def none(cls, *, backlash_width: float | None = None) -> Variability:
        """Every machine nominal, no drift, no disturbance (optionally another backlash width)."""
        base = cls()
        changes = {p.name: p.fixed() for p in base.parameters()}
        changes["backlash_width"] = base.backlash_width.fixed(backlash_width)
        return replace(base, **changes, drift=False, disturbance_amplitude=0.0)

    def friction_at(self, draw: MachineDraw, t: float) -> FrictionState:
        """Friction and damping of machine `draw` at time `t` (s) since it started."""
        scale = 1.0
        if self.drift:
            scale = 1.0 - draw.warmup_drop * (1.0 - math.exp(-t / self.warmup_time_constant))
        return FrictionState(
            motor_frictionloss=draw.motor_frictionloss * scale,
            motor_damping=draw.motor_damping * scale,
            slider_frictionloss=draw.slider_frictionloss * scale,
            slider_damping=draw.slider_damping * scale,
        )

    def disturbance(self, rng: np.random.Generator, n_samples: int) -> np.ndarray:
        """White-noise slider force, one value per sample, U[-A, A], shape (n_samples,)."""
        if self.disturbance_amplitude == 0:
            return np.zeros(n_samples)
        a = self.disturbance_amplitude
        return rng.uniform(-a, a, n_samples)


def _line(spread: float, name: str) -> Callable[[], Variability]:
    """A product-line scenario: motor and slider friction and damping ±spread around the MJCF,
    backlash, warm-up drift and the 30 N disturbance as in "paper"."""

    def build() -> Variability:
        base = Variability()
        changes = {
            p.name: replace(p, low=p.nominal * (1 - spread), high=p.nominal * (1 + spread))
            for p in (
                base.motor_frictionloss,
                base.motor_damping,
                base.slider_frictionloss,
                base.slider_damping,
            )
        }
        return replace(base, **changes, name=name)

    return build


SCENARIOS: dict[str, Callable[[], Variability]] = {
    "paper": Variability,
    "line-15": _line(0.15, "line-15"),
    "line-30": _line(0.30, "line-30"),
}
"""Named variability scenarios: "paper" (friction and damping ±5 %, the default twin), "line-15"
and "line-30" (±15 % and ±30 %: a product line as it is, not narrowed for the open-loop method)."""


def apply(
    model: mujoco.MjModel, *, draw: MachineDraw, friction: FrictionState, layout: Layout
) -> None:
    """Write a machine's backlash and its current friction into `model`, in place.

    The only place the twin's variability touches MuJoCo. These fields (dof_frictionloss,
    dof_damping, jnt_range) are read directly at every step; none feeds a constant that
    mj_setConst would have to recompute.
    """
    motor, slider = layout.dof["motor"], layout.dof["slider"]
    model.dof_frictionloss[motor] = friction.motor_frictionloss
    model.dof_damping[motor] = friction.motor_damping
    model.dof_frictionloss[slider] = friction.slider_frictionloss
    model.dof_damping[slider] = friction.slider_damping
    half = 0.5 * draw.backlash_width
    model.jnt_range[layout.joint["backlash"]] = (-half, half)


__all__ = [
    "SCENARIOS",
    "ConfigError",
    "FrictionState",
    "MachineDraw",
    "Parameter",
    "Variability",
    "apply",
    "check_finite",
]
