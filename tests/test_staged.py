"""The staged held-out verdict (replay/staged.py): one stage is one look exactly; more stages
keep the exact chance of a wrong "holds" within 5 %, checked against a direct enumeration and a
simulation of the procedure itself."""

import itertools

import numpy as np
import pytest
from scipy import stats as scistats

from replay.rates import TARGET_RATE, verdict
from replay.staged import (
    StagedDesign,
    StagedError,
    decide,
    design,
    holds_probability,
    most_within,
)


@pytest.mark.parametrize("runs", [50, 300, 1000, 2000])
def test_one_stage_is_one_look(runs):
    plan = design((runs,))
    for count in range(runs + 1):
        assert decide(plan, [count]) == verdict(count, runs)


def test_the_known_thresholds():
    # one look on 1000 machines confirms 0.5 % with at most 1 below (bound 0.47 %; 2: 0.63 %),
    # on 10 000 with at most 38; at most 5 of 1000 are within the target
    assert design((1000,)).thresholds == (1,)
    assert design((10_000,)).thresholds == (38,)
    assert most_within(1000, TARGET_RATE) == 5
    assert most_within(10_000, TARGET_RATE) == 50
    staged = design((1000, 10_000))
    assert staged.thresholds[0] == 1  # the first stage says what one look says


@pytest.mark.parametrize(
    "stages", [(1000, 10_000), (1000, 2000), (1000, 2000, 4000, 10_000), (200, 5000)]
)
def test_the_error_is_within_alpha_and_each_threshold_the_largest(stages):
    plan = design(stages)
    alpha = 1.0 - plan.confidence
    assert plan.error <= alpha
    assert holds_probability(plan, plan.target) == pytest.approx(plan.error, rel=1e-12)
    for j in range(1, len(stages)):  # one more at any later stage would spend too much
        raised = list(plan.thresholds)
        raised[j] += 1
        looser = StagedDesign(
            stages=plan.stages,
            thresholds=tuple(raised),
            target=plan.target,
            confidence=plan.confidence,
            error=0.0,
        )
        assert holds_probability(looser, plan.target) > alpha


def _enumerated(stages, thresholds, target, rate):
    """P(holds) of a two-stage check by a direct sum over both stages' counts."""
    (n1, n2), (a1, a2) = stages, thresholds
    p = scistats.binom.pmf(np.arange(n1 + 1), n1, rate)
    held = p[: a1 + 1].sum()
    for c1 in range(a1 + 1, n1 + 1):
        if c1 / n1 > target:
            continue
        extra = np.arange(n2 - n1 + 1)
        total = c1 + extra
        ok = total <= a2
        held += p[c1] * scistats.binom.pmf(extra[ok], n2 - n1, rate).sum()
    return held


@pytest.mark.parametrize("rate", [0.0, 0.01, 0.03, 0.05, 0.08])
def test_holds_probability_equals_a_direct_enumeration(rate):
    plan = design((60, 400), target=0.05)
    assert holds_probability(plan, rate) == pytest.approx(
        _enumerated(plan.stages, plan.thresholds, 0.05, rate), rel=1e-10, abs=1e-15
    )


def test_holds_probability_equals_a_simulation_of_the_procedure():
    plan = design((1000, 10_000))
    rate = 0.002  # where the second stage decides about half the paths
    rng = np.random.default_rng(7)
    paths = 200_000
    first = rng.binomial(1000, rate, paths)
    total = first + rng.binomial(9000, rate, paths)
    said = [decide(plan, [int(a), int(b)]) for a, b in zip(first, total, strict=True)]
    simulated = np.mean([s == "holds" for s in said])
    exact = holds_probability(plan, rate)
    se = np.sqrt(exact * (1 - exact) / paths)
    assert abs(simulated - exact) < 4 * se
    assert exact > holds_probability(design((1000,)), rate) + 0.5  # 0.98 against 0.41


def test_holds_probability_falls_as_the_rate_rises():
    plan = design((1000, 2000, 10_000))
    rates = np.linspace(0.0, 0.01, 41)
    held = [holds_probability(plan, r) for r in rates]
    assert held[0] == pytest.approx(1.0)
    assert all(b <= a + 1e-15 for a, b in itertools.pairwise(held))


def test_a_torque_on_its_3_sigma_level_is_confirmed():
    # one look on 1000 machines confirms a rate of Φ(−3) 61 % of the time; 1000 then 10 000 do
    # 99.7 % of the time, at a risk still within 5 %
    level = scistats.norm.cdf(-3.0)
    assert holds_probability(design((1000,)), level) == pytest.approx(0.609, abs=1e-3)
    assert holds_probability(design((1000, 10_000)), level) > 0.99


@pytest.mark.parametrize(
    ("counts", "said"),
    [
        ([0], "holds"),
        ([1], "holds"),
        ([2], "next"),
        ([5], "next"),
        ([6], "fails"),
        ([2, 34], "holds"),
        ([2, 35], "unconfirmed"),
        ([3, 50], "unconfirmed"),
        ([3, 51], "fails"),
        ([1, 40], "holds"),  # decided at the first stage
    ],
)
def test_decide(counts, said):
    assert design((1000, 10_000)).thresholds == (1, 34)
    assert decide(design((1000, 10_000)), counts) == said


@pytest.mark.parametrize(
    "stages",
    [(), (0,), (1000, 1000), (2000, 1000), (1000.0,), (True,), ("1000",)],
)
def test_bad_stages(stages):
    with pytest.raises(StagedError):
        design(stages)


@pytest.mark.parametrize(("target", "confidence"), [(0.0, 0.95), (1.0, 0.95), (0.005, 1.0)])
def test_bad_levels(target, confidence):
    with pytest.raises(StagedError, match="strictly between"):
        design((1000,), target=target, confidence=confidence)


@pytest.mark.parametrize("counts", [[], [3, 2], [1001], [1, 2, 3], [-1]])
def test_bad_counts(counts):
    with pytest.raises(StagedError):
        decide(design((1000, 10_000)), counts)


def test_the_second_stage_ends_within_the_most_machines():
    from replay.config import MAX_RUNS
    from replay.rates import second_stage_end

    assert second_stage_end(1000, 9000) == 10_000
    assert second_stage_end(1000, 0) == 0
    assert second_stage_end(MAX_RUNS - 5000, 9000) == MAX_RUNS
    assert second_stage_end(MAX_RUNS, 9000) == 0


def test_bad_rate():
    with pytest.raises(StagedError, match="rate"):
        holds_probability(design((1000,)), 1.5)
