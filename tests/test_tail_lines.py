"""The own-tail check by line sampling (control/tail_lines.py): exact on a one-dimensional
spread, the plain check's rate within their standard errors elsewhere at far less variance,
nested stages, the raise's moved crossings, and the plain check where the direction fails."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import optimize, special

import control.profiles as profiles
import control.tail as tail
import control.tail_lines as lines
from control.config import OCPConfig, OCPConfigError
from control.ocp import NominalOCP
from control.raise_k import raised_k
from control.tail import tail_check
from ppann.heads import FusedHeads
from ppann.model import constant_ppann

NARROW = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))
CONFIG = OCPConfig(mc_samples=100, confidence=0.0, tail_check=False, tail_sampling="plain")
LINES = replace(CONFIG, tail_sampling="lines")
LOWERED = np.array([0.5e-3, 1.5e-3])
"""A population drop that puts the centred torque's own rate near 1.4 % (tests/test_tail.py)."""


@pytest.fixture(scope="module")
def centred():
    ocp = NominalOCP(NARROW, CONFIG)
    nominal = ocp.solve()
    result = profiles.solve_decided(NARROW, CONFIG, profile="robust", ocp=ocp, nominal=nominal)
    return ocp, nominal, result


def _damping_only(result) -> lines.Simulator:
    """The centred torque on machines that differ in damping alone (log-factor sigma 0.05), no
    white noise, no transmission: the crank angle is a function of one normal."""
    heads = FusedHeads(NARROW)
    index = np.array(CONFIG.constraint_samples) - 1
    return lines.Simulator(
        heads,
        np.asarray(result.robust.states[0]),
        np.asarray(result.robust.tau),
        lines.layout(heads, "machine", int(index.max())),
        np.array([0.0, 0.05, 0.0]),
        index,
        None,
    )


def test_on_a_one_dimensional_spread_every_line_is_the_exact_probability(centred) -> None:
    """Only the damping normal moves the crank: the direction is that normal, every line the
    same, and its probability Φ(c_lo) + Φ(-c_hi) with the edges found by Brent's method on the
    simulated angle, to what ROOT_TOLERANCE allows (φ(c) times it per edge)."""
    _, _, result = centred
    simulator = _damping_only(result)
    found = lines.direction(simulator)
    assert found.usable
    assert abs(found.direction[1]) == pytest.approx(1.0, abs=1e-12)  # the damping normal alone

    def angle(c: float, j: int) -> float:
        u = np.zeros((1, simulator.layout.size))
        u[0, 1] = c * found.direction[1]
        return float(simulator.angles(u)[0, j] - found.centre[j])

    # edges where sample 50's crank is 2.3 standard normals behind, sample 100's 2.6 ahead
    reach = np.array([-angle(-2.3, 0), angle(2.6, 1)])
    assert np.all(reach > 0)  # the test would say nothing otherwise

    def edge(j: int, side: float) -> float:
        """Where sample j's angle is at side * reach_j, by Brent's method; inf beyond +-10."""
        f = lambda c: angle(c, j) - side * reach[j]  # noqa: E731
        if f(-10) * f(10) > 0:
            return -np.inf if f(0) > 0 else np.inf  # the whole range on one side of it
        return optimize.brentq(f, -10, 10, xtol=1e-12)

    edges = [(edge(j, -1.0), edge(j, 1.0)) for j in range(2)]
    lower, upper = max(e[0] for e in edges), min(e[1] for e in edges)
    exact = special.ndtr(lower) + special.ndtr(-upper)
    u = np.random.default_rng(0).standard_normal((50, simulator.layout.size))
    found_lines = lines.crossings(simulator, found, u, reach)
    p = found_lines.probabilities()
    bound = lines.ROOT_TOLERANCE * (np.exp(-(lower**2) / 2) + np.exp(-(upper**2) / 2))
    assert np.max(np.abs(p - exact)) <= bound / np.sqrt(2 * np.pi)
    assert 0.005 < exact < 0.02 and found_lines.unsettled == 0
    # each line's own draw is its plain trajectory
    np.testing.assert_array_equal(found_lines.plain, simulator.angles(u))


def test_the_lines_read_the_plain_checks_rate_with_less_variance(centred) -> None:
    """On the centred torque lowered to an own rate near 1.4 % (white noise every step): 4000
    lines against the plain check's 80 000 trajectories agree within three standard errors of
    their difference, and the lines' standard error is below the plain one's (measured 0.027
    against 0.043 points, in about half the time; on this model of constant networks the white
    noise of each step carries most of the tail, so the direction explains less of it than on a
    trained model's torque: 0.006 against 0.025 points there, control/tail_lines.py)."""
    _, _, result = centred
    heads = FusedHeads(NARROW)
    arguments = {"tightening": "centred", "population": LOWERED}
    plain = tail_check(heads, result.robust, CONFIG, draws=80_000, **arguments)
    lined = tail_check(heads, result.robust, LINES, draws=4000, **arguments)
    assert lined.sampling == "lines" and plain.sampling == "plain"
    assert 0.005 < plain.rate < 0.03
    gap = abs(lined.rate - plain.rate)
    assert gap <= 3 * np.hypot(lined.standard_error, plain.standard_error)
    assert lined.standard_error < plain.standard_error
    assert lined.as_dict()["sampling"] == "lines" and lined.as_dict()["lines_diverged"] == 0


def test_the_line_stages_are_nested_and_decide_by_their_own_error(centred) -> None:
    """Each stage's lines are the first ones of the next, to the bit; a stage decides at two of
    the lines' own standard errors from the target, on either side, at any stage: a target of
    5 % stops at the first stage a pass, one of 0.5 % at the first a failure, one at the rate
    of 1000 lines draws the last stage and is decided there by its rate alone."""
    _, _, result = centred
    heads = FusedHeads(NARROW)
    arguments = {"tightening": "centred", "population": LOWERED}
    first, last = lines.LINE_STAGES
    fixed = {
        n: tail_check(heads, result.robust, LINES, draws=n, **arguments) for n in lines.LINE_STAGES
    }
    small, large = (fixed[n].lines for n in lines.LINE_STAGES)
    np.testing.assert_array_equal(small.lower, large.lower[:first])
    np.testing.assert_array_equal(small.upper, large.upper[:first])
    np.testing.assert_array_equal(small.plain, large.plain[:first])
    passed = tail_check(heads, result.robust, LINES, goal=0.05, **arguments)
    assert passed.stages == (first,) and passed.passed and passed.rate == fixed[first].rate
    failed = tail_check(heads, result.robust, LINES, goal=0.005, **arguments)
    assert failed.stages == (first,) and not failed.passed
    at = tail_check(heads, result.robust, LINES, goal=fixed[first].rate, **arguments)
    assert at.stages == lines.LINE_STAGES and at.rate == fixed[last].rate
    assert tail.decides(0.0049, 0.005, 1000, se=0.00004) and tail.decides(0.0051, 0.005, 1, se=5e-5)
    assert not tail.decides(0.0049, 0.005, 80_000, se=0.0001)


def test_the_same_seed_gives_the_same_lines_and_another_seed_others(centred) -> None:
    _, _, result = centred
    heads = FusedHeads(NARROW)
    arguments = {"tightening": "centred", "population": LOWERED, "draws": 1000}
    one = tail_check(heads, result.robust, LINES, **arguments)
    again = tail_check(heads, result.robust, LINES, **arguments)
    other = tail_check(heads, result.robust, replace(LINES, mc_seed=1), **arguments)
    np.testing.assert_array_equal(one.lines.lower, again.lines.lower)
    assert one.rate == again.rate and other.rate != one.rate


def test_where_the_direction_does_not_suit_a_sample_the_check_draws_plain(
    centred, monkeypatch
) -> None:
    """A sample whose gradient is further from the direction than MIN_ALIGNMENT allows: the plain
    check, to the bit."""
    _, _, result = centred
    heads = FusedHeads(NARROW)
    arguments = {"tightening": "centred", "population": LOWERED, "draws": 5000}
    monkeypatch.setattr(lines, "MIN_ALIGNMENT", 1.01)
    fell_back = tail_check(heads, result.robust, LINES, **arguments)
    plain = tail_check(heads, result.robust, CONFIG, **arguments)
    assert fell_back.sampling == "plain" and fell_back.lines is None
    assert (fell_back.rate, fell_back.samples) == (plain.rate, plain.samples)


def test_a_line_is_below_on_the_union_of_its_samples_edges_and_a_shift_moves_them() -> None:
    """Φ(max lower) + Φ(-min upper); wholly below where the edges cross; a shift of sample j's
    angle by s moves its edges by -s over their slopes; a diverged line is below."""
    crossings = lines.Crossings(
        lower=np.array([[-2.0, -3.0], [-1.0, 0.5], [np.inf, np.inf]]),
        upper=np.array([[3.0, 2.5], [0.4, 4.0], [-np.inf, -np.inf]]),
        lower_slope=np.full((3, 2), 0.1),
        upper_slope=np.full((3, 2), 0.2),
        plain=np.zeros((3, 2)),
        unsettled=0,
        diverged=1,
    )
    p = crossings.probabilities()
    assert p[0] == pytest.approx(special.ndtr(-2.0) + special.ndtr(-2.5), rel=1e-15)
    assert p[1] == 1.0 and p[2] == 1.0
    moved = crossings.probabilities(np.array([0.05, -0.1]))
    # sample 50 ahead by 0.05 rad: its edges -2 - 0.5 = -2.5, 3 - 0.25 = 2.75; sample 100
    # behind by 0.1: -3 + 1 = -2, 2.5 + 0.5 = 3; the union's edges -2 and 2.75
    assert moved[0] == pytest.approx(special.ndtr(-2.0) + special.ndtr(-2.75), rel=1e-15)


def test_a_raise_from_lines_is_predicted_from_their_moved_crossings(centred) -> None:
    """A lines check above its target: raised_k's k is the smallest (to 0.01) whose moved lines
    read at most the aim, and the torque decided at it passes a new check."""
    ocp, nominal, result = centred
    heads = FusedHeads(NARROW)
    check = tail_check(
        heads, result.robust, LINES, tightening="centred", population=LOWERED, goal=0.005
    )
    assert not check.passed  # the test would say nothing otherwise
    unc = result.robust_uncertainty
    index = np.array(CONFIG.constraint_samples) - 1
    inputs = {
        "geometry": heads.geometry,
        "plan_angle": result.robust.states[index, 0],
        "tightening": unc.tightening,
        "sampling": unc.sampling,
        "population": LOWERED,
    }
    k = raised_k(check, LINES, **inputs)
    assert k is not None and k > 3.0
    lower = raised_k(check, replace(LINES, k_sigma=3.0), **inputs)
    assert lower == k  # deterministic
    raised = profiles.decide(
        NARROW, replace(CONFIG, k_sigma=k), profile="robust", ocp=ocp, nominal=nominal
    )
    again = tail_check(
        heads,
        raised.robust,
        replace(LINES, k_sigma=k),
        tightening="centred",
        population=LOWERED,
        goal=0.005,
    )
    assert again.rate < check.rate and again.passed


def test_an_unknown_tail_sampling_is_refused() -> None:
    with pytest.raises(OCPConfigError, match="tail_sampling"):
        OCPConfig(tail_sampling="importance")


def test_a_rate_read_by_lines_says_so(centred) -> None:
    """A refusal and the report name lines, not trajectories, where the rate was read by them."""
    _, _, result = centred
    heads = FusedHeads(NARROW)
    arguments = {"tightening": "centred", "population": LOWERED, "draws": 1000}
    lined = tail_check(heads, result.robust, LINES, **arguments)
    plain = tail_check(heads, result.robust, CONFIG, **arguments)
    assert profiles._of(lined) == "by line sampling on 1000 lines"
    assert profiles._of(plain) == "of 1000 trajectories"


def test_lines_come_in_mirrored_pairs_drawn_in_one_run() -> None:
    """Rows 2i + 1 are rows 2i mirrored; stages drawn in turn from one generator are the lines of
    one draw of their total, to the bit; an odd count is refused, as is an odd set of lines."""
    first = lines.mirrored(np.random.default_rng(3), 500, 7)
    np.testing.assert_array_equal(first[1::2], -first[0::2])
    rng = np.random.default_rng(3)
    staged = np.concatenate([lines.mirrored(rng, 500, 7), lines.mirrored(rng, 1500, 7)])
    np.testing.assert_array_equal(staged, lines.mirrored(np.random.default_rng(3), 2000, 7))
    np.testing.assert_array_equal(staged[:500], first)
    with pytest.raises(ValueError, match="mirrored pairs: an even count, not 501"):
        lines.mirrored(rng, 501, 7)
    with pytest.raises(ValueError, match="3 lines are not whole mirrored pairs"):
        lines.mean_and_error(np.zeros(3))


def test_the_standard_error_is_the_pairs_means_spread() -> None:
    """Two pairs of each kind: perfectly anticorrelated pairs (a line and its mirror summing to
    the same) read no error; the formula is the pair means' sample deviation over √pairs."""
    rate, se = lines.mean_and_error(np.array([0.01, 0.03, 0.0, 0.04]))
    assert rate == pytest.approx(0.02, rel=1e-15) and se == 0.0
    rate, se = lines.mean_and_error(np.array([0.01, 0.03, 0.0, 0.0]))
    assert rate == pytest.approx(0.01, rel=1e-15)
    assert se == pytest.approx(np.std([0.02, 0.0], ddof=1) / np.sqrt(2), rel=1e-15)


def test_the_pairs_error_is_the_spread_of_the_checks_rate_over_seeds(centred) -> None:
    """On the lowered centred torque, 500-line checks on Monte-Carlo seeds 0-23: the rates'
    spread over the seeds matches the standard error each check reports (their ratio within
    0.6-1.5, about three standard errors of a deviation of 24), and it is below the error of
    as many independent lines (their own spread's over √n)."""
    _, _, result = centred
    heads = FusedHeads(NARROW)
    arguments = {"tightening": "centred", "population": LOWERED, "draws": 500}
    checks = [
        tail_check(heads, result.robust, replace(LINES, mc_seed=seed), **arguments)
        for seed in range(24)
    ]
    rates = np.array([c.rate for c in checks])
    reported = np.array([c.standard_error for c in checks])
    assert 0.6 < rates.std(ddof=1) / reported.mean() < 1.5
    independent = np.mean([c.lines.probabilities().std(ddof=1) / np.sqrt(500) for c in checks])
    assert reported.mean() < independent
