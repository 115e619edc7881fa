"""The aware margin scheme (control/aware.py): its NLP rows against NumPy, the nominal NLP it
reduces to, the fixed point it settles on against the bracketed loop's, and its hand-over to the
bracket where it cannot settle."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from control.aware import MAX_SOLVES, AwareOCP
from control.config import OCPConfig, OCPConfigError
from control.ocp import NominalOCP
from control.robust import BeyondStrokeError, solve_robust
from control.tightening import slider_uncertainty
from ppann.model import PPANN, FusedHeads, constant_ppann

CONFIG = OCPConfig()
INDEX = np.array(CONFIG.constraint_samples) - 1


@pytest.fixture(scope="module")
def model() -> PPANN:
    """tests/test_ocp.py's: the stiffness torque jumps by 0.63 N·m where theta crosses 2 pi."""
    return constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))


@pytest.fixture(scope="module")
def aware(model: PPANN) -> AwareOCP:
    return AwareOCP(model, CONFIG, surrogate=50)


def _rows(aware: AwareOCP, states: np.ndarray) -> np.ndarray:
    """The NLP's constraint rows at `states` (N, 2), with the frozen parameters."""
    x = ca.MX.sym("x", 2, CONFIG.horizon)
    rows, parameters = aware._slider_rows(x, list(INDEX))
    function = ca.Function("rows", [x, parameters], [rows])
    return function(states.T, aware._extra).full().ravel()


def test_the_nlp_row_is_the_slider_less_its_frozen_spread(model: PPANN, aware: AwareOCP) -> None:
    """Frozen at a plan, the row is that plan's slider less its Monte-Carlo's tightening (line
    allowance for the mean apart); at other angles it is x(theta) - s std_i x(theta + e_i) in
    NumPy, with the same deviations and scale."""
    nominal = NominalOCP(model, CONFIG).solve()
    unc = slider_uncertainty(FusedHeads(model), nominal, CONFIG)
    aware.freeze(nominal, unc)
    expected = nominal.slider[INDEX] - (unc.tightening - unc.population)
    np.testing.assert_allclose(_rows(aware, nominal.states), expected, rtol=0, atol=1e-13)
    moved = nominal.states.copy()
    moved[INDEX, 0] += np.array([0.05, -0.08])
    theta = moved[INDEX, 0]
    deviation = unc.angles[: aware.surrogate] - nominal.states[INDEX, 0]
    drawn = nominal.geometry.slider_position(theta + deviation)
    scale = (unc.tightening - unc.population) / aware.spread(nominal.states[INDEX, 0], deviation)
    numpy = nominal.geometry.slider_position(theta) - scale * drawn.std(axis=0, ddof=1)
    np.testing.assert_allclose(_rows(aware, moved), numpy, rtol=0, atol=1e-13)


def test_reachable_finds_an_angle_where_one_exists(model: PPANN, aware: AwareOCP) -> None:
    """Frozen at a plan, the plan's own row value is reachable (its angle is on the grid) and a
    floor above the stroke is not; the wide line of the hand-over test below is refused here,
    before IPOPT (which took 14 s to call such an NLP infeasible on a line-15 model)."""
    nominal = NominalOCP(model, CONFIG).solve()
    unc = slider_uncertainty(FusedHeads(model), nominal, CONFIG)
    aware.freeze(nominal, unc)
    row = nominal.slider[INDEX] - (unc.tightening - unc.population)
    assert aware.reachable(row - 1e-12).all()
    top = nominal.geometry.stroke_top
    np.testing.assert_array_equal(aware.reachable(np.array([top + 1e-3, row[1]])), [False, True])


def test_with_a_zero_scale_it_is_the_nominal_ocp(model: PPANN, aware: AwareOCP) -> None:
    """Scale 0 leaves the slider alone in the rows: the nominal NLP's solution, from the same
    start, to the solver's tolerance."""
    nominal = NominalOCP(model, CONFIG).solve()
    unc = slider_uncertainty(FusedHeads(model), nominal, CONFIG)
    aware.freeze(nominal, unc)
    aware._extra[-len(INDEX) :] = 0.0
    solution = aware.solve()
    np.testing.assert_allclose(solution.tau, nominal.tau, rtol=0, atol=1e-7)
    assert solution.cost == pytest.approx(nominal.cost, rel=1e-10)


def test_aware_settles_on_the_brackets_fixed_point(model: PPANN) -> None:
    """Both schemes accept a full solve whose own Monte-Carlo tightening is within the tolerance
    of the margin it keeps; they find the same torque to that tolerance, the aware one in no
    more solves (bench/bench_aware.py: 3-7 against 6-9 on trained models)."""
    tolerance = CONFIG.margin_tolerance
    gaussian = OCPConfig(tightening="gaussian")
    aware = solve_robust(model, gaussian)
    bracket = solve_robust(model, OCPConfig(tightening="gaussian", margin_scheme="bracket"))
    assert {it.scheme for it in aware.iterations} == {"aware"}
    assert {it.scheme for it in bracket.iterations} == {"bracket"}
    last = aware.iterations[-1]
    assert not last.draft and aware.iterations[0].draft
    np.testing.assert_array_equal(last.margin, aware.robust.slider[INDEX] - CONFIG.height)
    np.testing.assert_array_equal(aware.robust.heights, CONFIG.height + last.margin)
    assert np.all(last.tightening - last.margin < tolerance)
    unc = aware.robust_uncertainty
    assert np.all(aware.robust.slider[INDEX] - unc.tightening >= CONFIG.height - tolerance)
    np.testing.assert_allclose(last.margin, bracket.iterations[-1].margin, rtol=0, atol=tolerance)
    assert aware.robust.cost == pytest.approx(bracket.robust.cost, rel=1e-3)
    assert len(aware.iterations) <= len(bracket.iterations)  # 4 each here; fewer on trained models


def test_where_the_map_falls_steeply_the_bracket_settles(model: PPANN) -> None:
    """The centred tightening on this model: at sample 100 the tightening falls 1.2 mm per mm of
    margin (the machines' mean sinks further below the plan as it leaves top dead centre), so
    the aware scheme's fixed-point steps oscillate; it hands over after MAX_SOLVES and the
    bracket settles within the tolerance."""
    result = solve_robust(model, CONFIG)
    schemes = [it.scheme for it in result.iterations]
    assert schemes[0] == "aware" and schemes[-1] == "bracket"
    assert schemes.count("aware") == MAX_SOLVES
    last = result.iterations[-1]
    assert not last.draft and np.all(last.tightening - last.margin < CONFIG.margin_tolerance)


def test_where_it_cannot_settle_the_bracket_decides() -> None:
    """A line far wider than the stroke: the aware scheme hands over and the refusal is the
    bracketed loop's, word for word, its iterations after the aware scheme's."""
    wide = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.3, 0.5, 0.5))
    errors = {}
    for scheme in ("aware", "bracket"):
        with pytest.raises(BeyondStrokeError) as caught:
            solve_robust(wide, OCPConfig(confidence=0.0, margin_scheme=scheme))
        errors[scheme] = caught.value
    assert str(errors["aware"]) == str(errors["bracket"])
    handed = [it for it in errors["aware"].partial.iterations if it.scheme == "bracket"]
    alone = errors["bracket"].partial.iterations
    assert [it.margin.tolist() for it in handed] == [it.margin.tolist() for it in alone]


def test_an_unknown_scheme_is_refused() -> None:
    with pytest.raises(OCPConfigError, match="margin_scheme must be one of aware, bracket"):
        OCPConfig(margin_scheme="fast")
