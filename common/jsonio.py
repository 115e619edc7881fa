"""The project's one JSON writer, with one policy for non-finite numbers: they become null, so
every file is strict JSON (a diverged Monte-Carlo draw can overflow; NaN literals are not JSON)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from common.atomic import atomic_path


def finite_or_none(value: Any) -> Any:
    """`value` with every non-finite float replaced by None and NumPy scalars/arrays made plain."""
    if isinstance(value, dict):
        return {str(k): finite_or_none(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite_or_none(v) for v in value]
    if isinstance(value, np.ndarray):
        return finite_or_none(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def dumps(payload: Any, *, indent: int | None = 1) -> str:
    """Strict JSON text of `payload` under the policy above."""
    return json.dumps(finite_or_none(payload), indent=indent, allow_nan=False) + "\n"


def write_json(path: str | Path, payload: Any, *, indent: int | None = 1) -> None:
    """Write `payload` as strict JSON at `path`, atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(dumps(payload, indent=indent))
