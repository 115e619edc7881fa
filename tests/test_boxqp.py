"""The MPC's box QP (control/boxqp.py) against exact answers: the enumeration of active sets, and
with slider rows SciPy's SLSQP."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.optimize import minimize

from control.boxqp import solve_box_qp, solve_with_limits


def _brute_force_box_qp(h, g, lo, hi):
    """The minimiser by enumerating which bound (or none) each variable sits on."""
    best, best_value = None, np.inf
    n = g.shape[0]
    for pattern in itertools.product((None, "lo", "hi"), repeat=n):
        v = np.zeros(n)
        fixed = np.array([p is not None for p in pattern])
        for i, p in enumerate(pattern):
            if p is not None:
                v[i] = lo[i] if p == "lo" else hi[i]
        free = ~fixed
        if free.any():
            rhs = -(g[free] + h[np.ix_(free, fixed)] @ v[fixed])
            v[free] = np.linalg.solve(h[np.ix_(free, free)], rhs)
        if np.any(v < lo - 1e-12) or np.any(v > hi + 1e-12):
            continue
        value = 0.5 * v @ h @ v + g @ v
        if value < best_value:
            best, best_value = v, value
    return best


def _positive_definite(rng: np.random.Generator, n: int) -> np.ndarray:
    m = rng.normal(size=(n, n))
    return m @ m.T + 0.1 * np.eye(n)


def test_box_qp_equals_the_enumeration_of_active_sets() -> None:
    rng = np.random.default_rng(0)
    active = 0
    for _ in range(40):
        n = 5
        h = _positive_definite(rng, n)
        g = rng.normal(scale=3.0, size=n)
        lo, hi = -rng.uniform(0.1, 1.0, n), rng.uniform(0.1, 1.0, n)
        v, _ = solve_box_qp(h, g, lo, hi, start=rng.uniform(lo, hi))
        exact = _brute_force_box_qp(h, g, lo, hi)
        np.testing.assert_allclose(v, exact, atol=1e-9)
        active += int(np.sum(np.isclose(v, lo) | np.isclose(v, hi)))
    assert active > 40  # the bounds mattered, not only the Newton step


def test_limited_box_qp_meets_its_rows_or_goes_as_far_as_the_box_lets() -> None:
    rng = np.random.default_rng(3)
    reachable = 0
    for _ in range(30):
        n = 6
        h = _positive_definite(rng, n)
        g = rng.normal(size=n)
        lo, hi = -np.ones(n), np.ones(n)
        row = rng.normal(size=(1, n))
        free, _ = solve_box_qp(h, g, lo, hi)
        rhs = np.array([row[0] @ free + 0.5])  # binding by construction
        v, _ = solve_with_limits(h, g, lo, hi, row, rhs)
        best = float(np.abs(row[0]) @ np.ones(n))  # the most the box allows
        if rhs[0] <= best - 1e-6:
            reachable += 1
            assert row[0] @ v == pytest.approx(rhs[0], abs=1e-8)
        assert np.all(v >= lo - 1e-12) and np.all(v <= hi + 1e-12)
        # the constrained optimum costs more than the free one, never less, and is SciPy's
        assert 0.5 * v @ h @ v + g @ v >= 0.5 * free @ h @ free + g @ free - 1e-12
        if rhs[0] <= best - 1e-6:
            reference = minimize(
                lambda w, h=h, g=g: 0.5 * w @ h @ w + g @ w,
                free,
                jac=lambda w, h=h, g=g: h @ w + g,
                bounds=list(zip(lo, hi, strict=True)),
                constraints=[{"type": "ineq", "fun": lambda w, a=row[0], b=rhs[0]: a @ w - b}],
                method="SLSQP",
                options={"ftol": 1e-14, "maxiter": 500},
            )
            np.testing.assert_allclose(v, reference.x, atol=1e-6)
    assert reachable >= 20  # the comparisons above did run
