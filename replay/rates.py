"""Violation rates on held-out machines: the exact bound, and what a count can confirm.

No violation on 50 machines is a rate of 0 %, and its exact one-sided 95 % upper bound is
5.8 %: such a check cannot tell 0.1 % from 2 %. A robust torque *holds* against the target rate
when its observed rate is within the target and so is that bound; within the target with the
bound above it, the machines were too few to confirm it (`machines_to_confirm` says how many
would, with none below); above the target, it does not hold.
"""

from __future__ import annotations

import math
from typing import Any

from control.config import TARGET_RATE, loop_of
from replay.config import MAX_RUNS

CONFIDENCE = 0.95
"""The one-sided confidence of the rate's upper bound."""
SECOND_STAGE = 9000
"""Machines `crank run` and `crank heldout` play a robust torque on beyond the first 1000 where
those cannot decide its verdict (replay/heldout_stages.py): 10 000 in all confirm a torque on its
3σ level, Φ(−3), 99.7 % of the time (1000 alone: 61 %)."""


def second_stage_end(runs: int, more: int) -> int:
    """Where a second stage of `more` machines after the first `runs` ends, within MAX_RUNS in
    all (replay/config.py); 0 where there is none (`more` 0, or no room left)."""
    end = min(runs + more, MAX_RUNS) if more else 0
    return end if end > runs else 0


def rate_upper(violations: int, runs: int, *, confidence: float = CONFIDENCE) -> float:
    """Exact one-sided Clopper-Pearson upper bound of a binomial rate."""
    from scipy import stats as scistats  # the CLI's help imports this module for its numbers

    if violations >= runs:
        return 1.0
    return float(scistats.beta.ppf(confidence, violations + 1, runs - violations))


def machines_to_confirm(target: float = TARGET_RATE, *, confidence: float = CONFIDENCE) -> int:
    """The fewest machines whose exact bound is within `target` when none goes below:
    (1 − target)^n ≤ 1 − confidence."""
    return math.ceil(math.log(1.0 - confidence) / math.log(1.0 - target))


def verdict(violations: int, runs: int, *, target: float = TARGET_RATE) -> str:
    """ "holds" (rate and its 95 % bound within `target`), "unconfirmed" (the rate within it,
    the bound above: too few machines) or "fails" (the rate above it)."""
    if violations / runs > target:
        return "fails"
    return "holds" if rate_upper(violations, runs) <= target else "unconfirmed"


def verdict_text(
    violations: int, runs: int, *, target: float = TARGET_RATE, of: str = "machines"
) -> str:
    """The verdict in words, with the numbers that decide it; `of`: what was counted (machines,
    or the runs a machine recorded: crank verify)."""
    upper, pct = rate_upper(violations, runs), f"{100 * target:.1f} %"
    said = verdict(violations, runs, target=target)
    if said == "fails":
        return f"does NOT hold ({100 * violations / runs:.2f} % > {pct})"
    if said == "holds":
        return f"holds at <= {pct} (95 % bound {100 * upper:.2f} %)"
    return (
        f"is within {pct} on these {runs} {of} but not confirmed: the 95 % bound is "
        f"{100 * upper:.2f} % (none below on {machines_to_confirm(target)} {of} would "
        f"confirm it)"
    )


def staged_entry(heldout: dict[str, Any], profile: str | None) -> dict[str, Any] | None:
    """heldout.json's `staged` entry of a robust profile (version 8, replay/heldout_stages.py),
    or None: a check without a second stage, or a profile it did not judge."""
    return (heldout.get("staged") or {}).get("profiles", {}).get(profile)


def second_stage_entry(heldout: dict[str, Any], profile: str | None) -> dict[str, Any] | None:
    """`staged_entry` where the check played the profile's second stage (its counts then of all
    the machines played), else None: no second stage, or a first stage that decided."""
    staged = staged_entry(heldout, profile)
    return staged if staged is not None and len(staged["counts"]) > 1 else None


def heldout_verdict_text(heldout: dict[str, Any], profile: str) -> str:
    """A robust profile's held-out verdict in words: the staged one where the check had a
    second stage (heldout.json version 8, replay/heldout_stages.py), else one look's."""
    staged = staged_entry(heldout, profile)
    if staged is None:
        below = heldout["profiles"][profile][loop_of(profile)]["violating_runs"]
        return verdict_text(below, heldout["runs"], target=heldout["target_rate"])
    counts, machines = staged["counts"], staged["machines"]
    if len(counts) == 1:
        return verdict_text(counts[0], machines[0], target=heldout["target_rate"])
    pct = f"{100 * heldout['staged']['target_rate']:.1f} %"
    said = {
        "holds": f"holds at <= {pct}",
        "fails": f"does NOT hold ({100 * counts[-1] / machines[-1]:.2f} % > {pct})",
        "unconfirmed": f"is within {pct} but not confirmed",
    }[staged["verdict"]]
    return (
        f"{said}: {counts[-1]} of {machines[-1]} machines below (the first {machines[0]}: "
        f"{counts[0]}, too few to decide; a staged check, its risk of a wrong 'holds' "
        f"{100 * heldout['staged']['error']:.1f} %)"
    )
