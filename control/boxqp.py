"""A small dense QP with box bounds, solved by a primal active set: the MPC's QP (control/mpc.py);
and the same QP with a few general rows (`solve_with_limits`, the MPC's slider limit) by its dual.

    minimise 1/2 v^T H v + g^T v   subject to   lo <= v <= hi,   H symmetric positive definite.

Why not a QP library: the MPC's QP has a few dozen variables, no constraint but the torque's box,
and a warm start that is feasible by construction (the shifted previous torque within the
limits); when no bound is active, as on most samples, this is one Cholesky solve. The working set
holds the variables pinned to a bound; each iteration solves the free variables' Newton step,
stops at the first bound it meets (adding it to the set), and once the step is zero releases the
pinned variable whose multiplier has the wrong sign. This terminates in finitely many iterations
for a strictly convex H (Nocedal & Wright, Algorithm 16.3); `max_iterations` only guards it.
"""

from __future__ import annotations

import numpy as np

from common.errors import CrankError


class BoxQPError(CrankError, RuntimeError):
    """The active set did not settle within its iteration budget (an ill-posed QP)."""


def solve_box_qp(
    h: np.ndarray,
    g: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    *,
    start: np.ndarray | None = None,
    tol: float = 1e-12,
    max_iterations: int | None = None,
) -> tuple[np.ndarray, int]:
    """The minimiser v and the number of active-set iterations taken.

    Args:
      h: (n, n) symmetric positive definite.
      g: (n,).
      lo, hi: (n,) bounds, lo <= hi.
      start: a feasible point to start from (clipped into the box); default the box's point
        nearest 0.
      tol: multipliers above -tol count as having the right sign.
    """
    n = g.shape[0]
    v = np.clip(np.zeros(n) if start is None else start, lo, hi)
    pinned = np.zeros(n, dtype=bool)
    budget = max_iterations if max_iterations is not None else 4 * n + 10
    on_minimum = False  # v minimises the QP with the pinned variables held
    for iteration in range(1, budget + 1):
        grad = h @ v + g
        if not on_minimum:
            free = ~pinned
            step = np.zeros(n)
            if free.any():
                step[free] = np.linalg.solve(h[np.ix_(free, free)], -grad[free])
            blocking, alpha = -1, 1.0
            with np.errstate(divide="ignore", invalid="ignore"):
                room = np.where(step < 0, (lo - v) / step, np.where(step > 0, (hi - v) / step, 1))
            room[pinned] = np.inf
            if room.size and room.min() < 1.0:
                blocking = int(np.argmin(room))
                alpha = max(float(room[blocking]), 0.0)
            v = v + alpha * step
            if blocking >= 0:
                v[blocking] = lo[blocking] if step[blocking] < 0 else hi[blocking]
                pinned[blocking] = True
                continue
            on_minimum = True
            grad = h @ v + g
        at_lo = pinned & (v <= lo)
        multiplier = np.where(at_lo, grad, -grad)  # >= 0 where a bound rightly holds v
        multiplier[~pinned] = np.inf
        worst = int(np.argmin(multiplier)) if n else 0
        if n == 0 or multiplier[worst] >= -tol:
            return v, iteration
        pinned[worst] = False
        on_minimum = False
    raise BoxQPError(f"the box QP of {n} variables did not settle in {budget} active-set steps")


def solve_with_limits(
    hess: np.ndarray,
    grad: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    rows: np.ndarray,
    rhs: np.ndarray,
    *,
    tol: float = 1e-10,
) -> tuple[np.ndarray, int]:
    """The box QP with rows @ v >= rhs as well (a few rows), by its dual: for multipliers
    lam >= 0 the box QP of grad - rows^T lam is solved, and each lam_i is found by regula falsi
    (Illinois) on the slack rows_i @ v(lam) - rhs_i, which is nondecreasing in lam_i (one sweep
    for one row, a few for more). A row the box cannot meet gets the largest multiplier tried:
    the torque then goes as far towards it as the limit lets. Returns v and the box QPs solved."""
    solves = 0

    def box(lam: np.ndarray) -> np.ndarray:
        nonlocal solves
        solves += 1
        return solve_box_qp(hess, grad - rows.T @ lam, lo, hi)[0]

    lam = np.zeros(len(rhs))
    v = box(lam)
    for _ in range(1 if len(rhs) == 1 else 6):
        for i in range(len(rhs)):

            def slack(li: float, i: int = i) -> tuple[float, np.ndarray]:
                trial = lam.copy()
                trial[i] = li
                w = box(trial)
                return float(rows[i] @ w - rhs[i]), w

            a = 0.0
            fa, va = slack(a)
            if fa >= -tol:  # not binding at lam_i = 0
                lam[i], v = 0.0, va
                continue
            b, (fb, vb) = 1.0, slack(1.0)
            while fb < -tol and b < 1e12:
                a, fa, b = b, fb, 10.0 * b
                fb, vb = slack(b)
            if fb < -tol:  # out of the box's reach
                lam[i], v = b, vb
                continue
            side = 0
            for _ in range(60):
                c = b - fb * (b - a) / (fb - fa)
                fc, vc = slack(c)
                if abs(fc) <= tol:
                    b, fb, vb = c, fc, vc
                    break
                if fc < 0:
                    a, fa = c, fc
                    fb = fb / 2 if side == -1 else fb
                    side = -1
                else:
                    b, fb, vb = c, fc, vc
                    fa = fa / 2 if side == 1 else fa
                    side = 1
            lam[i], v = b, vb
    return v, solves
