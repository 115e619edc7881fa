"""robust-pd: a tube sized for the fixed PD the machine already runs, against exact answers."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from common.errors import ConfigError
from control.config import PD_GAINS, OCPConfig, OCPConfigError, law_of, loop_of
from control.robust import solve_robust
from control.tightening import slider_uncertainty
from crank.chain import RunConfig
from ppann.heads import FusedHeads
from ppann.model import PPANN, constant_ppann
from replay.config import ReplayConfig
from replay.laws import closed_loop_gains, plays_own_law


@pytest.fixture(scope="module")
def model() -> PPANN:
    return constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))


def test_one_source_for_the_fixed_pd() -> None:
    assert (OCPConfig().pd_kp, OCPConfig().pd_kd) == PD_GAINS
    assert (ReplayConfig().kp, ReplayConfig().kd) == PD_GAINS
    assert (loop_of("robust-pd"), law_of("robust-pd")) == ("closed", "pd")
    assert (law_of("robust-fb"), law_of("robust"), law_of("nominal")) == ("lqr",) * 3


def test_pd_tube_is_sized_for_the_pd_spread(model: PPANN) -> None:
    """The loop settles on margins equal to the closed-loop Monte-Carlo's tightening under the
    constant PD gains (bit for bit the same draws), carries those gains, and its margins lie
    between the LQR tube's and the open loop's on this model (the PD tracks less tightly than
    the LQR, far more than no feedback)."""
    config = OCPConfig(profiles=("robust-pd",))
    tube = solve_robust(model, config, profile="robust-pd")
    pd = np.tile(PD_GAINS, (config.horizon - 1, 1))
    np.testing.assert_array_equal(tube.robust_gains, pd)
    np.testing.assert_array_equal(tube.nominal_gains, pd)
    last = tube.iterations[-1]
    assert not last.draft and all(it.profile == "robust-pd" for it in tube.iterations)
    np.testing.assert_array_less(np.abs(last.tightening - last.margin), config.margin_tolerance)
    again = slider_uncertainty(FusedHeads(model), tube.robust, config, gains=pd)
    np.testing.assert_allclose(again.tightening, last.tightening, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(tube.robust_loops["closed"], again.std)
    lqr = solve_robust(model, config, profile="robust-fb").iterations[-1].margin
    open_loop = solve_robust(model, config, profile="robust").iterations[-1].margin
    assert np.all(lqr < last.margin) and np.all(last.margin < 0.5 * open_loop)


def test_pd_tube_with_zero_gains_is_the_open_loop_profile(model: PPANN) -> None:
    """A PD of zero gains is no feedback: the closed-loop Monte-Carlo is the open loop's bit for
    bit, so the tube is the open-loop robust torque to the last bit."""
    config = OCPConfig(pd_kp=0.0, pd_kd=0.0, margin_scheme="bracket")  # the tubes' scheme
    zero = solve_robust(model, config, profile="robust-pd")
    open_loop = solve_robust(model, config, profile="robust")
    np.testing.assert_array_equal(zero.robust.tau, open_loop.robust.tau)
    np.testing.assert_array_equal(
        zero.robust_uncertainty.tightening, open_loop.robust_uncertainty.tightening
    )


@pytest.mark.parametrize("field", ["pd_kp", "pd_kd"])
@pytest.mark.parametrize("value", [-1.0, float("nan"), float("inf")])
def test_pd_gains_must_be_finite_and_nonnegative(field: str, value: float) -> None:
    with pytest.raises(OCPConfigError, match=field):
        OCPConfig(**{field: value})


def test_a_run_plays_robust_pd_under_the_pd_it_was_sized_for() -> None:
    RunConfig.for_seed(0, ocp={"profiles": ["robust-pd"], "pd_kp": 30.0}, replay={"kp": 30.0})
    with pytest.raises(ConfigError, match=r"sized for the PD Kp 30, Kd 0\.5 .* is Kp 20, Kd 0\.5"):
        RunConfig.for_seed(0, ocp={"profiles": ["robust-pd"], "pd_kp": 30.0})
    # other profiles do not care which PD the replays use
    RunConfig.for_seed(0, ocp={"profiles": ["robust-fb"], "pd_kp": 30.0})


class _Profile:
    def __init__(self, gains: np.ndarray) -> None:
        self.gain_theta, self.gain_omega = gains[:, 0], gains[:, 1]


def test_own_law_is_the_gains_the_tube_was_sized_with() -> None:
    pd_profile = _Profile(np.tile(PD_GAINS, (149, 1)))
    lqr_profile = _Profile(np.column_stack([np.linspace(25, 40, 149), np.full(149, 0.7)]))
    own, pd = ReplayConfig(), ReplayConfig(feedback="pd")
    assert plays_own_law(pd_profile, own) and plays_own_law(pd_profile, pd)
    assert not plays_own_law(pd_profile, replace(pd, kp=21.0))
    assert plays_own_law(lqr_profile, own) and not plays_own_law(lqr_profile, pd)
    np.testing.assert_array_equal(
        closed_loop_gains(pd_profile, pd), closed_loop_gains(pd_profile, own)
    )


def test_one_flag_sets_the_pd_of_the_replays_and_of_the_tube() -> None:
    """`crank run --pd 30,0.8` sets the PD of robust-pd and of the replays alike, so the run's
    own consistency check holds."""
    from crank.cli_chain import flag_values
    from crank.config_file import build, defaults, merge

    values = merge(defaults(), flag_values({"pd": "30,0.8", "profiles": "robust-pd"}), source="t")
    config = build(values, source="t")
    assert (config.ocp.pd_kp, config.ocp.pd_kd) == (config.replay.kp, config.replay.kd)
    assert (config.replay.kp, config.replay.kd) == (30.0, 0.8)
    assert config.ocp.profiles == ("robust-pd",)
