"""The held-out check's second stage: a robust torque whose first machines cannot decide its
verdict (within the target, but too few for the exact bound to be: 2–5 of 1000 at 0.5 %) is
played on more machines of the same held-out draw, and judged on the total by a staged design
whose risk of a wrong "holds" stays within 5 % over both looks (replay/staged.py).

The first `runs` machines of a draw of `extend_to` are the first stage's own (replay/campaign.py
spawns one stream child per machine), so the second stage plays machines runs … extend_to − 1
only, MACHINES_PER_BATCH at a time (its memory that of one batch, whatever `extend_to`), and
counts the machines below the height at any constraint sample, as the first stage does. The
calibration tables stay those of the first stage.

heldout.json's `staged` (version 8):

  stages, thresholds     cumulative machines of each stage and the most below that says
                         "holds" after it (replay/staged.py)
  target_rate, confidence, error
                         the design's target, confidence, and its exact P("holds") at a true
                         rate equal to the target
  profiles.<name>        {loop, machines [per stage played], counts [below, cumulative],
                          verdict (holds | unconfirmed | fails), violating_machines (the second
                          stage's machines below, by index in the whole draw, or null beyond
                          replay/heldout.py's LISTED_MACHINES of them)}
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from control.ocp_file import OCPFile
from replay.campaign import Machines, draw_machines, play
from replay.config import ReplayConfig
from replay.rates import TARGET_RATE
from replay.staged import StagedError, decide, design
from twin.physics import SliderCrank


def check_extension(runs: int, extend_to: int) -> None:
    """Refuse a second stage that is not more machines than the first (0: none)."""
    if isinstance(extend_to, bool) or not isinstance(extend_to, int) or extend_to < 0:
        raise StagedError(f"extend_to is a machine count (0: no second stage), not {extend_to!r}")
    if extend_to and extend_to <= runs:
        raise StagedError(
            f"extend_to {extend_to} must exceed the first stage's {runs} machines (0: no second "
            "stage)"
        )


def _machines(drawn: Machines, start: int, stop: int) -> Machines:
    return Machines(
        draws=drawn.draws[start:stop],
        start_times=drawn.start_times[start:stop],
        disturbance=drawn.disturbance[start:stop],
    )


def extend(
    physics: SliderCrank,
    ocp: OCPFile,
    *,
    judged: dict[str, tuple[str, int]],
    config: ReplayConfig,
    extend_to: int,
    batch: int,
    listed_most: int,
    target: float = TARGET_RATE,
    on_extend: Callable[[str, str, int], None] | None = None,
    on_machines: Callable[[str, str, int], None] | None = None,
) -> dict[str, Any]:
    """heldout.json's `staged`: each of `judged` ({profile: (its loop, machines below of the
    first config.runs)}) judged against `target` by a two-stage design (config.runs,
    extend_to), played on the second stage's machines where the first did not decide (those
    below listed by index up to `listed_most` of them);
    `on_extend(profile, loop, machines)` before a second stage, `on_machines(profile, loop, n)`
    after each batch of it."""
    runs = config.runs
    check_extension(runs, extend_to)
    plan = design((runs, extend_to), target=target)
    out: dict[str, Any] = {**plan.as_dict(), "profiles": {}}
    drawn: Machines | None = None
    c = ocp.config
    for name, (loop, below) in judged.items():
        counts, listed = [below], None
        if decide(plan, counts) == "next":
            if drawn is None:  # the whole draw once; its first `runs` machines are not played
                drawn = draw_machines(replace(config, runs=extend_to), ocp.horizon, held_out=True)
            if on_extend is not None:
                on_extend(name, loop, extend_to - runs)
            more = np.zeros(extend_to - runs, dtype=bool)
            for start in range(runs, extend_to, batch):
                stop = min(start + batch, extend_to)
                replay = play(
                    physics,
                    ocp,
                    profile=name,
                    mode=loop,
                    machines=_machines(drawn, start, stop),
                    config=replace(config, runs=stop - start),
                )
                x = replay.slider_position[:, [k - 1 for k in c.constraint_samples]]
                more[start - runs : stop - runs] = (x < c.height).any(axis=1)
                if on_machines is not None:
                    on_machines(name, loop, stop - start)
            counts.append(below + int(more.sum()))
            if counts[-1] - below <= listed_most:
                listed = [runs + int(i) for i in np.flatnonzero(more)]
        out["profiles"][name] = {
            "loop": loop,
            "machines": [runs, extend_to][: len(counts)],
            "counts": counts,
            "verdict": decide(plan, counts),
            "violating_machines": listed,
        }
    return out


def settle(heldout: dict[str, Any]) -> None:
    """heldout.json's `holds` and `verdicts` from its `staged`: each judged on all its machines."""
    for name, s in heldout["staged"]["profiles"].items():
        heldout["holds"][name] = s["counts"][-1] / s["machines"][-1] <= heldout["target_rate"]
        heldout["verdicts"][name] = s["verdict"]
