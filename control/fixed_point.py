"""The robust loop's root-finder: per constraint sample, a bracketed secant (regula falsi with the
Illinois modification) on the residual F(m) = T(m) - m of the margin map m -> T(m).

The map's residual falls as the margin grows (a larger margin makes a torque that dwells nearer
top dead centre, where the slider spreads less): F(0) = T(nominal) > 0, and past the fixed point
F < 0. Measured on the seed-0 model, F at sample 100 fell monotonically over the ten margins the
earlier fixed-point iteration tried, yet its local slope jumped between -0.1 and -1.7 from one
pair of margins to the next (two coupled samples, loose draft solves): a secant on the last two
margins overshot and the loop took 9 drafts. A bracket [lo, hi] with F(lo) > 0 > F(hi) keeps
every step inside the interval known to hold the root, and regula falsi inside it converges on
any continuous monotone residual; the Illinois modification (halve the residual kept at an end
that survived twice in a row) keeps one end from sticking, which plain regula falsi does on a
curved residual. Before a bracket exists the step is the plain one, m + F(m) (the first step
from the nominal solve is T(nominal), as in the paper's iteration).

Jumps: the residual is not continuous everywhere. A draft solved on its warm start's turns
gives another torque than one whose 2 pi crossing has moved, and on the seed-0 model F at sample
100 went from +0.66 mm to -0.17 mm between margins 0.02 mm apart; regula falsi then closed in on
the jump for eight drafts, none within the tolerance. Once the bracket is narrower than the
tolerance, the high end is taken: its residual is <= 0, so the constraint slider - T >= height
holds there with slack |F(hi)|, a margin that is safe and at most that slack too large.

A point that contradicts its bracket (F > 0 at or beyond hi, F <= 0 at or below lo: the other
sample's margin moved, or a draft's looseness) drops the end it contradicts, so a stale bracket
never traps the iteration away from the root.
"""

from __future__ import annotations

import numpy as np


class Bracket:
    """Per component, the largest margin seen with F > 0 (lo) and the smallest with F <= 0 (hi),
    with their residuals, and which end moved last (for the Illinois halving)."""

    def __init__(self, margin: np.ndarray, residual: np.ndarray) -> None:
        n = len(margin)
        self.lo_m = np.full(n, np.nan)
        self.lo_f = np.full(n, np.nan)
        self.hi_m = np.full(n, np.nan)
        self.hi_f = np.full(n, np.nan)
        self.last = np.zeros(n, dtype=int)
        """+1: lo moved last, -1: hi moved last, 0: neither yet (or the bracket was reset)."""
        self.update(margin, residual)

    def update(self, margin: np.ndarray, residual: np.ndarray) -> None:
        """Take in F(margin) = residual (per component)."""
        for j, (m, f) in enumerate(zip(margin, residual, strict=True)):
            if f > 0:
                if m >= self.hi_m[j]:  # contradicts hi (False while hi is NaN)
                    self.hi_m[j] = self.hi_f[j] = np.nan
                    self.last[j] = 0
                if self.last[j] == 1:
                    self.hi_f[j] /= 2  # Illinois: hi survived twice
                self.lo_m[j], self.lo_f[j], self.last[j] = m, f, 1
            else:
                if m <= self.lo_m[j]:
                    self.lo_m[j] = self.lo_f[j] = np.nan
                    self.last[j] = 0
                if self.last[j] == -1:
                    self.lo_f[j] /= 2
                self.hi_m[j], self.hi_f[j], self.last[j] = m, f, -1

    def jumps(self, tolerance: float) -> np.ndarray:
        """Per component, whether the bracket is narrower than `tolerance`: the residual jumps
        across it (module docstring, "Jumps")."""
        closed = np.isfinite(self.lo_m) & np.isfinite(self.hi_m)
        return closed & (self.hi_m - self.lo_m < tolerance)

    def propose(
        self, margin: np.ndarray, residual: np.ndarray, *, tolerance: float = 0.0
    ) -> np.ndarray:
        """The next margin: regula falsi inside the bracket where both ends exist, the high end
        where the bracket is narrower than `tolerance` (a jump), else the plain step margin +
        residual."""
        closed = np.isfinite(self.lo_m) & np.isfinite(self.hi_m)
        with np.errstate(invalid="ignore", divide="ignore"):
            falsi = self.lo_m + self.lo_f * (self.hi_m - self.lo_m) / (self.lo_f - self.hi_f)
        step = np.where(closed, falsi, margin + residual)
        return np.where(self.jumps(tolerance), self.hi_m, step)
