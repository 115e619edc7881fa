"""control/raise_k.py: the k a torque whose own tail is above its target is decided again at,
against a reference computed the long way (every 0.01 of k, each shift by bisection), and its
exact refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from control import raise_k, tail
from control.config import OCPConfig
from control.tail import aim, share_below
from twin.geometry import PAPER

K = 3.0


def _draws(seed: int = 0, n: int = 20_000) -> tuple[np.ndarray, np.ndarray]:
    """Crank angles at two constraint samples: sample 1 0.6 rad before top dead centre, narrow
    (~90 mm), sample 2 0.25 rad before it and wide (~98 mm, many draws past top dead centre: the
    slider concave, its lower tail long); and the plan's."""
    rng = np.random.default_rng(seed)
    plan_angle = np.array([2 * np.pi - 0.6, 2 * np.pi - 0.25])
    angles = plan_angle + rng.normal(0.0, [0.01, 0.2], size=(n, 2))
    return angles, plan_angle


def _setup(method: str, *, slack: float = 0.0):
    """A check of `_draws` at k 3, the height where sample 2's condition binds (its draws'
    centre less k sigma and the allowances), the tightening those draws ask for (less `slack`),
    and the inputs raised_k takes."""
    angles, plan_angle = _draws()
    population, sampling = np.array([0.0004, 0.0006]), np.array([0.0003, 0.0005])
    lowered = PAPER.slider_position(angles) - population
    plan = PAPER.slider_position(plan_angle)
    first = lowered[: raise_k.TABLE_DRAWS]
    centre = plan if method == "gaussian" else first.mean(axis=0)
    tightening = plan - centre + K * first.std(axis=0) + sampling + population - slack
    config = OCPConfig(height=float(plan[1] - tightening[1] + slack))
    rate, samples = share_below(lowered, config)
    check = tail.TailCheck(
        draws=len(lowered),
        rate=rate,
        samples=samples,
        target=0.005,
        tightening=method,
        k_sigma=K,
        wall_time=0.0,
        lowered=lowered,
        angles=angles,
    )
    inputs = {
        "geometry": PAPER,
        "plan_angle": plan_angle,
        "tightening": tightening,
        "sampling": sampling,
        "population": population,
        "method": method,
    }
    return check, inputs, config


def _reference(check: tail.TailCheck, inputs: dict, method: str, config: OCPConfig) -> float | None:
    """The smallest k in steps of 0.01 whose moved draws are within the aim: each sample's shift
    the smallest (bisection to 1e-9 rad) toward top dead centre at which the first TABLE_DRAWS
    draws, moved, keep the tightening's condition at that k as they kept it at k 3."""
    first = check.angles[: raise_k.TABLE_DRAWS]
    population, sampling = inputs["population"], inputs["sampling"]
    plan = PAPER.slider_position(inputs["plan_angle"])
    slack = np.clip(plan - config.height - inputs["tightening"], 0.0, None)

    def kept(j: int, shift: float, k: float) -> float:
        moved = PAPER.slider_position(first[:, j] + shift) - population[j]
        if method == "gaussian":
            centre = PAPER.slider_position(inputs["plan_angle"][j] + shift)
            before = PAPER.slider_position(inputs["plan_angle"][j])
        else:
            centre, before = moved.mean(), (PAPER.slider_position(first[:, j]) - population[j])
            before = before.mean()
        sigma0 = (PAPER.slider_position(first[:, j]) - population[j]).std()
        return (
            centre - k * moved.std() - (before - K * sigma0) - sampling[j] * (k / K - 1) + slack[j]
        )

    for step in range(1, 1001):
        k = K + step / 100
        moved = np.empty_like(check.lowered)
        for j in range(2):
            distance = abs(math.remainder(inputs["plan_angle"][j], 2 * math.pi))
            if kept(j, 0.0, k) >= 0:
                shift = 0.0
            elif kept(j, distance, k) < 0:
                return None
            else:
                low, high = 0.0, distance
                while high - low > 1e-9:
                    middle = 0.5 * (low + high)
                    low, high = (middle, high) if kept(j, middle, k) < 0 else (low, middle)
                shift = high
            moved[:, j] = PAPER.slider_position(check.angles[:, j] + shift) - population[j]
        if share_below(moved, config)[0] <= aim(check):
            return k
    return None


@pytest.mark.parametrize("method", ["centred", "gaussian"])
def test_the_raise_is_the_reference_k(method) -> None:
    """The draws at k 3 go below the height on ~1 % (the concave sample); the predicted k is the
    reference's (computed every 0.01 of k with each shift bisected, not tabulated), to the 0.01
    a tabulated shift may move it across; and it is a raise the slider alone would under-size:
    moved up in the slider by the tightening's growth at the old sigma, the draws would reach the
    aim at a smaller k than they do moved in angle (the spread of the concave sample shrinks as
    its plan nears top dead centre, so the plan need rise less)."""
    check, inputs, config = _setup(method)
    assert check.rate > 0.008  # the test would say nothing otherwise
    predicted = raise_k.raised_k(check, config, **inputs)
    reference = _reference(check, inputs, method, config)
    assert predicted is not None and reference is not None
    assert abs(predicted - reference) <= 0.01 + 1e-12
    first = check.lowered[: raise_k.TABLE_DRAWS]
    per_k = first.std(axis=0) + inputs["sampling"] / K
    by_slider = next(
        K + step / 100
        for step in range(1, 1001)
        if share_below(check.lowered + per_k * step / 100, config)[0] <= aim(check)
    )
    assert K < by_slider < predicted


def test_a_raise_the_slack_absorbs_never_moves_the_draws() -> None:
    """With a metre of slack the tightening's condition holds at any k without the plan moving,
    so the draws never move and their rate (~1 %) never reaches the aim: no k."""
    check, inputs, config = _setup("centred", slack=1.0)
    assert check.rate > 0.008
    assert raise_k.raised_k(check, config, **inputs) is None


def test_a_plan_at_top_dead_centre_cannot_rise() -> None:
    """A plan at top dead centre has nowhere to go: its condition at a larger k (the same draws,
    a larger k sigma) cannot hold: no k."""
    check, inputs, config = _setup("centred")
    inputs["plan_angle"] = np.array([inputs["plan_angle"][0], 2 * np.pi])
    assert raise_k.raised_k(check, config, **inputs) is None


def test_diverged_draws_beyond_the_aim_leave_no_k() -> None:
    """A draw that diverged (NaN) stays below at any k: with 1 % of them no k reaches the aim."""
    check, inputs, config = _setup("centred")
    assert raise_k.raised_k(check, config, **inputs) is not None
    angles = check.angles.copy()
    angles[:200, 1] = np.nan
    lowered = PAPER.slider_position(angles) - inputs["population"]
    diverged = tail.TailCheck(**{**check.__dict__, "angles": angles, "lowered": lowered})
    assert raise_k.raised_k(diverged, config, **inputs) is None


def test_only_the_centred_and_gaussian_tightenings_are_predicted() -> None:
    check, inputs, config = _setup("centred")
    with pytest.raises(ValueError, match="centred or gaussian tightening, not 'quantile'"):
        raise_k.raised_k(check, config, **{**inputs, "method": "quantile"})
