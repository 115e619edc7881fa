"""The held-out verdict in stages: more machines only where the first ones cannot decide.

One count on 1000 machines confirms a rate of 0.5 % only if at most 1 machine is below (its
exact 95 % bound, replay/rates.py); a torque whose true rate is its 3σ level, Φ(−3) = 0.135 %,
shows 2 or more below 39 % of the time, and one look then leaves it "unconfirmed". A staged
check plays such a torque on more machines of the same draw (the first N₁ of N₂ held-out
machines are the N₁ of the first stage: replay/campaign.py) and decides on the total.

Stages N₁ < … < N_m are cumulative machine counts. After stage j, with c_j machines below:

  fails        c_j / N_j > target (the rate above it, as one look says);
  holds        c_j ≤ a_j;
  next stage   otherwise; after the last, unconfirmed.

a₁ is one look's own threshold on N₁ (a one-stage design is `rates.verdict` exactly); each
later a_j is the largest that keeps the probability of ever saying "holds", were the true
rate the target, at most 1 − confidence over all stages together. That probability is
computed exactly, by carrying the count's distribution over the machines still undecided from
stage to stage (`holds_probability`). It falls as the true rate rises (a path with more
machines below says "holds" no sooner), so above the target it is smaller still: a staged
"holds" is as sound as one look's, and a second look is not a second chance at 5 %.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats as scistats

from common.errors import CrankError
from replay.rates import CONFIDENCE, TARGET_RATE, rate_upper


class StagedError(CrankError, ValueError):
    """Stages or counts a staged check cannot use."""


def most_within(runs: int, target: float) -> int:
    """The largest count of `runs` machines whose rate is within `target` (c / runs ≤ target,
    the same comparison as `rates.verdict`)."""
    c = math.floor(target * runs)
    while c + 1 <= runs and (c + 1) / runs <= target:
        c += 1
    while c >= 0 and c / runs > target:
        c -= 1
    return c


def one_look_threshold(runs: int, *, target: float, confidence: float) -> int:
    """The largest count that one look on `runs` machines calls "holds" (−1: none can)."""
    c = -1
    while c + 1 <= most_within(runs, target) and (
        rate_upper(c + 1, runs, confidence=confidence) <= target
    ):
        c += 1
    return c


@dataclass(frozen=True)
class StagedDesign:
    """A staged check: its cumulative machine counts and "holds" thresholds, and what it
    risks."""

    stages: tuple[int, ...]
    thresholds: tuple[int, ...]
    """a_j: at most this many below after stage j says "holds" (−1: no count can)."""
    target: float
    confidence: float
    error: float
    """P("holds") at a true rate equal to the target, exact: at most 1 − confidence."""

    def as_dict(self) -> dict[str, object]:
        return {
            "stages": list(self.stages),
            "thresholds": list(self.thresholds),
            "target_rate": self.target,
            "confidence": self.confidence,
            "error": self.error,
        }


def _check_stages(stages: Sequence[int], target: float, confidence: float) -> tuple[int, ...]:
    if not 0.0 < target < 1.0 or not 0.0 < confidence < 1.0:
        raise StagedError(
            f"target {target} and confidence {confidence} must both lie strictly between 0 and 1"
        )
    if not stages:
        raise StagedError("a staged check needs at least one stage")
    for n in stages:
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise StagedError(f"stage sizes are machine counts >= 1, not {n!r}")
    out = tuple(int(n) for n in stages)
    if any(b <= a for a, b in itertools.pairwise(out)):
        raise StagedError(f"stages are cumulative machine counts, each above the last: {out}")
    return out


def _carry(mass: np.ndarray, added: int, rate: float, most: int) -> np.ndarray:
    """The distribution of the count after `added` more machines at `rate`, from `mass` (the
    undecided count's probabilities, index = count), cut at `most` (above it: fails)."""
    step = scistats.binom.pmf(np.arange(most + 1), added, rate)
    return np.convolve(mass, step)[: most + 1]


def design(
    stages: Sequence[int], *, target: float = TARGET_RATE, confidence: float = CONFIDENCE
) -> StagedDesign:
    """The thresholds of a staged check on `stages` (cumulative machine counts): the first is
    one look's, each later one the largest that keeps P("holds" | rate = target) within
    1 − confidence over all stages."""
    sizes = _check_stages(stages, target, confidence)
    alpha = 1.0 - confidence
    mass, before, spent, thresholds = np.ones(1), 0, 0.0, []
    for n in sizes:
        mass = _carry(mass, n - before, target, most_within(n, target))
        held = np.cumsum(mass)
        if thresholds:
            a = int(np.searchsorted(held, alpha - spent, side="right")) - 1
        else:
            a = one_look_threshold(n, target=target, confidence=confidence)
        thresholds.append(a)
        if a >= 0:
            spent += float(held[a])
            mass[: a + 1] = 0.0
        before = n
    return StagedDesign(
        stages=sizes,
        thresholds=tuple(thresholds),
        target=target,
        confidence=confidence,
        error=spent,
    )


def holds_probability(plan: StagedDesign, rate: float) -> float:
    """P(the staged check says "holds") on machines whose true rate below is `rate`, exact."""
    if not 0.0 <= rate <= 1.0:
        raise StagedError(f"a rate lies in [0, 1], not {rate}")
    mass, before, held = np.ones(1), 0, 0.0
    for n, a in zip(plan.stages, plan.thresholds, strict=True):
        mass = _carry(mass, n - before, rate, most_within(n, plan.target))
        if a >= 0:
            held += float(mass[: a + 1].sum())
            mass[: a + 1] = 0.0
        before = n
    return held


def decide(plan: StagedDesign, counts: Sequence[int]) -> str:
    """The verdict after the stages played so far (`counts`: machines below, cumulative, one per
    stage played): "holds", "fails", "unconfirmed" (the last stage played, neither), or "next"
    (neither yet, and a stage is left)."""
    if not 1 <= len(counts) <= len(plan.stages):
        raise StagedError(f"{len(counts)} counts for a check of {len(plan.stages)} stages")
    for j, (n, c) in enumerate(zip(plan.stages, counts, strict=False)):
        if not 0 <= c <= n or (j and c < counts[j - 1]):
            raise StagedError(f"counts are cumulative machines below, within each stage: {counts}")
    for n, a, c in zip(plan.stages, plan.thresholds, counts, strict=False):
        if c / n > plan.target:
            return "fails"
        if c <= a:
            return "holds"
    return "next" if len(counts) < len(plan.stages) else "unconfirmed"
