"""Value checks shared by every config: finite numbers, non-negative integer seeds, counts and
named choices."""

from __future__ import annotations

import math

from common.errors import ConfigError

MAX_SEED = 2**63 - 1
"""Largest seed accepted (NumPy and torch both take it)."""


def check_finite(
    name: str,
    value: float,
    *,
    positive: bool = False,
    nonneg: bool = False,
    error: type[Exception] = ConfigError,
) -> None:
    """Raise `error` unless `value` is a finite number (and > 0 or >= 0 when asked)."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise error(f"{name} must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise error(f"{name} must be > 0, got {value!r}")
    if nonneg and value < 0:
        raise error(f"{name} must be >= 0, got {value!r}")


def check_seed(name: str, value: object, *, error: type[Exception] = ConfigError) -> None:
    """Raise `error` unless `value` is an integer in [0, MAX_SEED]."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_SEED:
        raise error(f"{name} must be an integer in 0..{MAX_SEED}, got {value!r}")


def check_count(
    name: str,
    value: object,
    *,
    low: int = 1,
    high: int | None = None,
    error: type[Exception] = ConfigError,
) -> None:
    """Raise `error` unless `value` is an integer in [low, high]."""
    if (
        isinstance(value, bool)
        or not isinstance(value, int)
        or value < low
        or (high is not None and value > high)
    ):
        bound = f"{low}..{high}" if high is not None else f">= {low}"
        raise error(f"{name} must be an integer {bound}, got {value!r}")


def check_choice(
    name: str, value: object, choices: tuple[str, ...], *, error: type[Exception] = ConfigError
) -> None:
    """Raise `error` unless `value` is one of `choices`."""
    if value not in choices:
        raise error(f"{name} must be one of {', '.join(choices)}, got {value!r}")
