"""A rig's units and signs as the command line gives them (`crank import`, `crank export`):
each quantity's units with their factor to the contract's, and the `field=value,...` pairs of
`--map` and `--units`."""

from __future__ import annotations

import numpy as np

from common.errors import ConfigError

UNITS: dict[str, dict[str, float]] = {
    "t": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9},
    "theta": {"rad": 1.0, "deg": np.pi / 180, "rev": 2 * np.pi},
    "omega": {"rad/s": 1.0, "rpm": 2 * np.pi / 60, "deg/s": np.pi / 180, "rev/s": 2 * np.pi},
    "tau": {"N*m": 1.0, "Nm": 1.0, "mN*m": 1e-3, "mNm": 1e-3},
    "slider_position": {"m": 1.0, "mm": 1e-3, "cm": 1e-2},
    "episode": {"1": 1.0},
    "machine": {"1": 1.0},
}
"""Factor to the contract's unit (the first of each field) per unit name."""


def check_units(units: dict[str, str], fields: tuple[str, ...]) -> None:
    """Refuse a `--units` field not among `fields`, or a unit UNITS does not know for it.

    Raises:
      ConfigError: naming the field or unit and what would do.
    """
    for name, unit in units.items():
        if name not in fields:
            raise ConfigError(f"--units: unknown field {name!r} (fields: {', '.join(fields)})")
        if unit not in UNITS[name]:
            raise ConfigError(f"--units: {name} in {unit!r}? use one of {', '.join(UNITS[name])}")


def option_pairs(text: str, option: str) -> dict[str, str]:
    """A command line's `name=value,...` as a dict (`--map`, `--units`; crank export's too)."""
    out = {}
    for item in (i.strip() for i in text.split(",") if i.strip()):
        name, sep, value = item.partition("=")
        if not sep or not name.strip() or not value.strip():
            raise ConfigError(f"{option}: {item!r} is not field=value")
        out[name.strip()] = value.strip()
    return out
