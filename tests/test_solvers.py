"""control/solvers.py: an OCP whose NLP was built before in this process takes the kept solvers
and gives a fresh build's numbers to the last bit; the key is the NLP's content (one ulp of one
weight is another NLP); the oldest is dropped past the count kept; nothing is kept by default; no
gradient of the Lagrangian is built, and one built changes no number."""

from __future__ import annotations

import copy
from collections import OrderedDict
from dataclasses import fields

import casadi as ca
import numpy as np
import pytest
import torch

from control import solvers as solvers_module
from control.aware import aware_ocp
from control.config import OCPConfig
from control.dynamics import CasadiPPANN
from control.ocp import NominalOCP, Solution
from control.records import RobustResult
from control.robust import solve_robust
from control.solvers import keep_solvers, nlp_key, solvers
from ppann.model import PPANN, constant_ppann

OPTIONS = {"expand": True, "print_time": False, "ipopt": {"print_level": 0, "sb": "yes"}}


@pytest.fixture
def kept(monkeypatch: pytest.MonkeyPatch) -> None:
    """This test's own store (the worker's, if the suite keeps any, is put back after it)."""
    monkeypatch.setattr(solvers_module, "_kept", OrderedDict())
    monkeypatch.setattr(solvers_module, "_capacity", 0)


def _model() -> PPANN:
    return constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))


def _step_nlp(model: PPANN) -> dict[str, ca.MX]:
    """A one-step NLP on the model's CasADi step: where to go from x with torque u."""
    x, u, turn = ca.MX.sym("x", 2), ca.MX.sym("u"), ca.MX.sym("turn")
    after = CasadiPPANN(model).step_on_turn(x, u, turn)
    return {"x": ca.vertcat(x, u), "p": turn, "f": ca.sumsqr(after) + u**2, "g": x}


def _same(a: Solution, b: Solution) -> None:
    for name in ("tau", "states", "heights", "lam_g", "lam_x"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert (a.cost, a.iterations, a.turn_passes) == (b.cost, b.iterations, b.turn_passes)


def _same_robust(a: RobustResult, b: RobustResult) -> None:
    _same(a.nominal, b.nominal)
    _same(a.robust, b.robust)
    assert len(a.iterations) == len(b.iterations)
    for one, other in zip(a.iterations, b.iterations, strict=True):
        for field in fields(one):
            if field.name not in ("solve_time", "monte_carlo_time"):
                left, right = getattr(one, field.name), getattr(other, field.name)
                assert np.array_equal(np.asarray(left), np.asarray(right)), field.name


@pytest.mark.usefixtures("kept")
def test_a_kept_solver_gives_a_fresh_builds_numbers_to_the_last_bit() -> None:
    model, config = _model(), OCPConfig()
    fresh = NominalOCP(model, config)
    expected = solve_robust(model, config, ocp=fresh)
    keep_solvers(4)
    first = NominalOCP(model, config)
    assert first._solver is not fresh._solver  # nothing was kept before keep_solvers
    solve_robust(model, config, ocp=first)
    again = NominalOCP(model, config)
    assert again._solver is first._solver and again._draft_solver is first._draft_solver
    assert again is not first and again.engine == first.engine == "vm"
    # the aware NLP of the second OCP is another object, with its own frozen deviations, on the
    # solvers the first one's built
    aware = aware_ocp(model, again, samples=config.mc_samples)
    assert aware is not aware_ocp(model, first, samples=config.mc_samples)
    assert aware._solver is aware_ocp(model, first, samples=config.mc_samples)._solver
    _same_robust(solve_robust(model, config, ocp=again), expected)
    # another task is another NLP
    other = NominalOCP(model, OCPConfig(constraint_samples=(60, 90)))
    assert other._solver is not first._solver


def test_the_key_is_the_nlps_content_to_the_last_bit() -> None:
    """One ulp of a mean network's bias is another NLP; the sigma networks, which the step does
    not see (the aware NLP takes their spread as parameters), are not part of it."""
    model = _model()
    key = nlp_key(_step_nlp(model), OPTIONS)
    assert nlp_key(_step_nlp(copy.deepcopy(model)), OPTIONS) == key
    for net, seen in (("mean_nets", True), ("sigma_nets", False)):
        nudged = copy.deepcopy(model)
        bias = getattr(nudged, net)["J"][2].bias
        with torch.no_grad():
            bias[0] = torch.nextafter(bias[0], torch.tensor(np.inf, dtype=bias.dtype))
        assert (nlp_key(_step_nlp(nudged), OPTIONS) != key) == seen, net
    tighter = {**OPTIONS, "ipopt": {**OPTIONS["ipopt"], "tol": 1e-12}}
    assert nlp_key(_step_nlp(model), tighter) != key


@pytest.mark.usefixtures("kept")
def test_the_oldest_is_dropped_past_the_count_kept_and_none_by_default() -> None:
    models = [_model(), constant_ppann(z_mean=(0.1, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))]
    a, b = (_step_nlp(m) for m in models)
    assert solvers(a, OPTIONS, compiled=False) is not solvers(a, OPTIONS, compiled=False)
    keep_solvers(2)
    first = solvers(a, OPTIONS, compiled=False)
    solvers(b, OPTIONS, compiled=False)
    assert solvers(a, OPTIONS, compiled=False) is first  # a, then b: both kept
    keep_solvers(1)  # drops the oldest: b
    assert solvers(a, OPTIONS, compiled=False) is first
    solvers(b, OPTIONS, compiled=False)  # drops a
    assert solvers(a, OPTIONS, compiled=False) is not first
    keep_solvers(0)
    assert len(solvers_module._kept) == 0
    with pytest.raises(ValueError, match="negative"):
        keep_solvers(-1)


@pytest.mark.usefixtures("kept")
def test_no_gradient_of_the_lagrangian_is_built_and_one_built_changes_no_number(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The OCPs' solvers lack CasADi's `nlp_grad` (control/ocp.py's options: it serves only the
    parameters' multipliers, which they do not ask for); solvers built with it give the same
    robust solve, nominal and aware NLPs alike, to the last bit."""
    model, config = _model(), OCPConfig()
    ocp = NominalOCP(model, config)
    result = solve_robust(model, config, ocp=ocp)
    for solver in (ocp._solver, aware_ocp(model, ocp, samples=config.mc_samples)._solver):
        assert "nlp_grad" not in solver.get_function()
        assert {"nlp_jac_g", "nlp_hess_l"} <= set(solver.get_function())
    built = solvers_module.build

    def with_gradient(nlp: dict, options: dict, *, compiled: bool) -> solvers_module.Solvers:
        return built(nlp, {**options, "no_nlp_grad": False}, compiled=compiled)

    monkeypatch.setattr(solvers_module, "build", with_gradient)
    reference = NominalOCP(model, config)
    assert "nlp_grad" in reference._solver.get_function()
    _same_robust(solve_robust(model, config, ocp=reference), result)
