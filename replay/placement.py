"""Where a held-out machine sits in its product line: each uncertain parameter's place in its
range (0 its low end, 1 its high end: the twin draws each uniformly, twin/variability.py), how
long it ran before its replay (warmer, less friction), and the slider force's mean up to the
last constraint sample, in N and in standard errors of such a mean.

The machines a robust torque leaves below the height are not a random few: on each root looked
at (sessions 31-33) the same machines went below under every torque played on that root, most
of them with low motor friction or damping and a positive mean slider force (root 20261167's
machine 3128: motor friction at 5 % of its range, +5.6 N, 3.2 standard errors from zero).
`heldout.json` gives each listed violating machine's placement (`violating_placements`) and the
console says its extremes in words, so that where the line's tail lives is read off the check
rather than dug out of the draws.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from twin.variability import MachineDraw, Variability

if TYPE_CHECKING:  # the campaign's simulation stack is not needed to place a machine
    from replay.campaign import Machines

EDGE = 0.1
"""A parameter within this share of its range from either end is named in words."""
FAR = 2.0
"""A mean force this many standard errors from zero is named in words (always given in N)."""
MOST_NAMED = 5
"""The most machines below the height a line names one by one (a robust profile's few): the
terminal and report.md, by index and by place; more are counted, not listed."""


def placement(
    draw: MachineDraw,
    variability: Variability,
    *,
    force: np.ndarray,
    start_s: float,
    max_start_s: float,
) -> dict[str, Any]:
    """One machine's place in `variability`'s line: `range_position` per uncertain parameter
    (None where the range is empty), `start_s` and its share of `max_start_s`, the mean of
    `force` (the slider force per sample up to the last constraint sample, N) and that mean over
    its standard error under the line's white force (U[-A, A] per sample: A / sqrt(3 n))."""
    positions: dict[str, float | None] = {}
    for parameter in variability.parameters():
        value = getattr(draw, parameter.name)
        span = parameter.high - parameter.low
        positions[parameter.name] = None if span == 0 else (value - parameter.low) / span
    force = np.asarray(force, dtype=float)
    mean = float(force.mean()) if force.size else 0.0
    se = variability.disturbance_amplitude / math.sqrt(3 * force.size) if force.size else 0.0
    return {
        "range_position": positions,
        "start_s": float(start_s),
        "start_share": float(start_s / max_start_s) if max_start_s > 0 else None,
        "force_mean_N": mean,
        "force_mean_z": mean / se if se > 0 else None,
    }


def in_words(placed: dict[str, Any]) -> str:
    """`placement`'s extremes: each parameter within EDGE of an end of its range, a start in the
    last or first EDGE of the start times, and the mean force (with its z where beyond FAR)."""
    words = [
        f"{name} at {100 * position:.0f} % of its range"
        for name, position in placed["range_position"].items()
        if position is not None and (position <= EDGE or position >= 1 - EDGE)
    ]
    share = placed.get("start_share")
    if share is not None and (share <= EDGE or share >= 1 - EDGE):
        words.append(f"{'warm' if share >= 1 - EDGE else 'cold'} ({placed['start_s']:.1f} s run)")
    force = f"mean slider force {placed['force_mean_N']:+.1f} N"
    z = placed.get("force_mean_z")
    if z is not None and abs(z) >= FAR:
        force += f" ({z:+.1f} standard errors)"
    return ", ".join([*words, force])


def placements(
    machines: Machines,
    indices: list[int] | None,
    variability: Variability,
    *,
    until: int,
    max_start_s: float,
) -> list[dict[str, Any]] | None:
    """`placement` of machines[i] for each i of `indices` (None: none listed, None back), its
    force up to sample `until` (the last constraint sample: later force cannot move the slider
    there)."""
    if indices is None:
        return None
    return [
        placement(
            machines.draws[i],
            variability,
            force=machines.disturbance[i][:until],
            start_s=float(machines.start_times[i]),
            max_start_s=max_start_s,
        )
        for i in indices
    ]


def named(entry: dict[str, Any], *, most: int = MOST_NAMED) -> list[tuple[int, dict[str, Any]]]:
    """A heldout.json entry's machines below the height with their placements, where it lists
    at most `most` (a robust profile's few), else none (nor from a file before version 7)."""
    machines = entry.get("violating_machines") or []
    where = entry.get("violating_placements") or []
    if len(machines) > most or len(where) != len(machines):
        return []
    return list(zip(machines, where, strict=True))
