"""The project's one JSON writer, with one policy for non-finite numbers: they become null, so
every file is strict JSON (a diverged Monte-Carlo draw can overflow; NaN literals are not JSON).

Reproducibility rule: the same seed and command give byte-identical datasets, checkpoints,
figures and campaign logs, and JSON files that are identical but for the wall-clock fields named
in WALL_CLOCK (how long a step took, when a file was written); `without_wall_clock` drops them.
A path an artifact records is relative to the artifact's folder when it lies inside it
(`recorded_path`), so a run folder reads the same wherever it sits. A campaign log attaches
the ocp.json it played as it is, wall-clock fields included. Rerun's `.rrd` (its own recording
ids and clock) and the human `report.md` (wall times) are outside the rule.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from common.atomic import atomic_path

WALL_CLOCK = frozenset(
    {
        "created",
        "timing",
        "wall_time_s",
        "wall_seconds",
        "wall_s",
        "solve_time_s",
        "monte_carlo_time_s",
        "train_seconds",
    }
)
"""The only keys whose values differ between two runs of the same command and seed."""


def recorded_path(path: str | Path, *, artifact: str | Path) -> str:
    """`path` as the file at `artifact` records it: relative to the artifact's folder if it lies
    inside that folder, else as given."""
    folder = Path(artifact).resolve().parent
    resolved = Path(path).resolve()
    if resolved.is_relative_to(folder):
        return resolved.relative_to(folder).as_posix()
    return str(path)


def without_wall_clock(payload: Any) -> Any:
    """`payload` (parsed JSON) without the WALL_CLOCK keys, at any depth."""
    if isinstance(payload, dict):
        return {k: without_wall_clock(v) for k, v in payload.items() if k not in WALL_CLOCK}
    if isinstance(payload, list):
        return [without_wall_clock(v) for v in payload]
    return payload


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
