"""The torque's own tail by line sampling (beyond the paper; session 46).

control/tail.py estimates a robust torque's own rate below the height from plain Monte-Carlo
trajectories: near the 0.5 % target that takes 80 000 of them to tell 0.45 % from 0.5 %, about
2.3 nominal solves, which kept bench/bench_solve.py's ratio above 3 (bench/raise_k.md).

Line sampling (Koutsourelakis, Pradlwarter and Schuëller, *Reliability of structures in high
dimensions*, Prob. Eng. Mech. 19, 2004) reads the same probability with far fewer trajectories
where failure lies along one direction of the standard normals. Here every random number of a
trajectory is a standard normal u (`Layout`: the machine's three, the white z of every
step, the slider force's, the transmission's angle by its normal score), and the crank angle at
each constraint sample is close to linear in u (R² 0.94-0.97 on a default model's torque: the
slider's tail is non-normal through the slider's curve near top dead centre, not through the
angle). So:
1. the direction: the gradient of the crank angle at each constraint sample in u, by central
   differences at u = 0 (DIFFERENCE_STEP), each scaled to unit length and summed (the samples'
   gradients point the same way, cosine 0.93 on that model: the crank running ahead or behind);
2. each line is a draw u, simulated as it is (a plain trajectory, kept for control/raise_k.py),
   then moved along the direction: the crank angle at sample j crosses the edges of its window
   around top dead centre (the slider at the height, `Geometry.crank_reach`) at c_lo and c_hi,
   found by secant steps (SECANT_STEPS, from the direction's slope), and the line's probability
   below the height at any sample is Φ(max_j c_lo) + Φ(−min_j c_hi) (the union, exactly, on
   the line);
3. the lines come in mirrored pairs (u, -u: `mirrored`, session 48); the rate is the lines'
   mean, its standard error the pairs' means' spread over √pairs, and the check stops
   in LINE_STAGES as control/tail.py's plain one does, by that standard error (on either side
   at any stage: a raise reads the lines' crossings, each moved by the shift over its slope),
   the last by its rate alone.

The estimate is unbiased whatever the direction (a poor one only costs variance) as long as
each line crosses each edge once. Measured on the k-3 torques of the seed-3 default model
(session 46, development, Monte-Carlo seeds 0-3): 1000 lines read 0.37-0.60 % with a standard
error of 0.008-0.012 points in 0.06-0.07 s (about half a nominal solve), where 320 000 plain
trajectories read 0.37-0.58 % ± 0.011-0.013 in 2.2 s and the plain check drew 80 000 on three of
the four (0.53-0.55 s, se 0.023-0.027). Two secant steps a line left the rate 0.005 points low
(a standard error of 4000 lines), three 0.002, four within 0.0001 of eight. A sample whose
gradient points away from the direction (alignment below MIN_ALIGNMENT) could cross its edges
twice or never: there the check draws plain trajectories as before.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import special

from ppann.heads import FusedHeads
from ppann.modes import MONTE_CARLO_MODES
from ppann.montecarlo import Feedback, rollout
from ppann.transmission import at_levels

DIFFERENCE_STEP = 1.0
"""Each normal's move in the central differences that give the direction: one standard normal
(a secant over the spread, not a tangent; 0.3 read the same rate with 1.1-1.4x the variance, a
pilot's regression with 1.1-1.2x, on two torques of a default model)."""
LINE_STAGES = (500, 2000)
"""Lines of the check's sequential stages, in mirrored pairs (`mirrored`), each nested in the
next. The last decides by its rate alone, to about ±0.006 points (one standard error at 0.5 % on
a default torque), four times the precision of the plain check's last stage of 80 000
trajectories. Before session 48 the lines were independent and the stages (1000, 4000), of the
same precision at twice the cost (the pairs' probabilities correlate at -0.52..-0.57 on three
default torques: bench/antithetic_lines.md); a third stage of 16 000 independent lines (±0.003)
cost 0.7-1.1 s, 5.7-7.9 nominal solves, on the two of 25 bench_solve pairs whose rate sat within
0.012 points of the target (0.48 % and 0.50 %; bench/tail_lines.md A)."""
SECANT_STEPS = 4
"""Evaluations per edge at most (ROOT_TOLERANCE): on 4000 lines of a default torque about 2450
and 600 of the ~8000 simulated edges were still moving after three and four; the rate after four
was within 0.0001 points of eight's."""
ROOT_TOLERANCE = 1e-2
"""A crossing has settled when a secant step moves it less than this, in standard normals."""
FAR = 5.0
"""An edge predicted this far along the line (Φ(−5) = 2.9e-7 a line) is taken at its linear
prediction, not simulated."""
SLOPE_RANGE = (0.5, 2.0)
"""A secant's slope is kept within these multiples of the direction's."""
MIN_ALIGNMENT = 0.5
"""The least cosine between a constraint sample's gradient and the direction for line sampling."""


@dataclass(frozen=True)
class Layout:
    """Where each random number of a trajectory sits in its standard normal vector u."""

    machine: int
    """3 with machine draws (mixed, machine), else 0."""
    white: int
    """Rows of white z (steps, 1 for one per trajectory, 0 for none), 3 normals each."""
    lever: bool
    """The slider force's normal per white row."""

    @property
    def size(self) -> int:
        return self.machine + self.white * (3 + self.lever) + 1

    def split(
        self, u: np.ndarray, spread: np.ndarray, quantiles: np.ndarray
    ) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None, np.ndarray]:
        """The rollout's inputs from u (n, size): machine factors, eps (rows, n, 3), the force's
        normals (rows, n) and the transmission's angle (n,)."""
        n, at = len(u), 0
        with np.errstate(over="ignore"):  # a line carried far (its draw then diverges: below)
            factors = np.exp(spread * u[:, :3]) if self.machine else None
        at += self.machine
        eps = lever = None
        if self.white:
            eps = u[:, at : at + 3 * self.white].reshape(n, self.white, 3).transpose(1, 0, 2)
            at += 3 * self.white
            if self.lever:
                lever = u[:, at : at + self.white].T
                at += self.white
        # the transmission's angle at its normal score's level (ppann/transmission.py `draw`'s)
        return factors, eps, lever, at_levels(quantiles, special.ndtr(u[:, at]))


def layout(heads: FusedHeads, mode: str, steps: int) -> Layout:
    """The normals of `mode`'s trajectories of `steps` steps on `heads` (ppann/modes.py)."""
    draw = MONTE_CARLO_MODES[mode]
    rows = {"step": steps, "held": 1, None: 0}[draw.white]
    return Layout(3 * draw.machine, rows, heads.has_lever and rows > 0)


@dataclass(frozen=True)
class Simulator:
    """The crank angle at the constraint samples as a function of u (`angles`)."""

    heads: FusedHeads
    x0: np.ndarray
    tau: np.ndarray
    layout: Layout
    spread: np.ndarray
    index: np.ndarray
    """0-based state index of each constraint sample."""
    feedback: Feedback | None

    def angles(self, u: np.ndarray, samples: np.ndarray | None = None) -> np.ndarray:
        """theta + delta at the constraint samples `samples` (default all), (n, len), rad."""
        chosen = np.arange(len(self.index)) if samples is None else np.asarray(samples)
        at = self.index[chosen]
        kept = np.unique(at)
        steps = int(kept.max())
        factors, eps, lever, delta = self.layout.split(u, self.spread, self.heads.transmission)
        if eps is not None and len(eps) > 1:
            eps, lever = eps[:steps], None if lever is None else lever[:steps]
        states = rollout(
            self.heads,
            self.x0,
            self.tau[:steps],
            n_samples=len(u),
            eps=None if eps is None else np.ascontiguousarray(eps),
            factors=factors,
            feedback=self.feedback,
            lever_eps=None if lever is None else np.ascontiguousarray(lever),
            at=kept,
        )
        return states[:, np.searchsorted(kept, at), 0] + delta[:, None]


@dataclass(frozen=True)
class Direction:
    """The lines' direction in u and the crank's slope along it."""

    direction: np.ndarray
    """Unit vector in u, (size,)."""
    slopes: np.ndarray
    """d(angle)/dc along it at each constraint sample, rad (the gradients' projections)."""
    alignment: np.ndarray
    """Cosine between each sample's gradient and the direction."""
    centre: np.ndarray
    """The top dead centre nearest the mean trajectory's angle at each sample, rad."""
    origin: np.ndarray
    """The crank angle at u = 0 at each sample, rad (a warm check's shift: `redirected`)."""

    @property
    def usable(self) -> bool:
        return bool(np.all(self.alignment >= MIN_ALIGNMENT) and np.all(self.slopes > 0))


def direction(simulator: Simulator) -> Direction:
    """The direction (module docstring, 1): the crank angle's gradient at each constraint sample
    by central differences at u = 0, every normal moved by +-DIFFERENCE_STEP (2 size + 1
    trajectories), each scaled to unit length, summed."""
    size, step = simulator.layout.size, DIFFERENCE_STEP
    u = np.concatenate([np.zeros((1, size)), step * np.eye(size), -step * np.eye(size)])
    angle = simulator.angles(u)
    centre = nearest_centre(angle[0])
    gradients = ((angle[1 : size + 1] - angle[size + 1 :]) / (2 * step)).T
    lengths = np.linalg.norm(gradients, axis=1)
    total = (gradients / np.where(lengths > 0, lengths, 1.0)[:, None]).sum(axis=0)
    unit = total / max(float(np.linalg.norm(total)), 1e-300)
    slopes = gradients @ unit
    alignment = slopes / np.where(lengths > 0, lengths, np.inf)
    return Direction(unit, slopes, alignment, centre, angle[0])


def nearest_centre(angle: np.ndarray) -> np.ndarray:
    """The top dead centre (a multiple of 2 pi) nearest each crank angle, rad."""
    return 2 * np.pi * np.round(angle / (2 * np.pi))


def redirected(simulator: Simulator, found: Direction) -> Direction:
    """`found`'s direction for another torque of the same task (a warm check: control/tail.py),
    its slopes by central differences along it and its origin and centre at u = 0 (3
    trajectories, where `direction` draws 2 size + 1); the alignment is `found`'s. Any
    direction keeps line sampling unbiased: this one only saves the gradients."""
    step = DIFFERENCE_STEP * found.direction
    angle = simulator.angles(np.stack([np.zeros_like(step), step, -step]))
    centre = nearest_centre(angle[0])
    slopes = (angle[1] - angle[2]) / (2 * DIFFERENCE_STEP)
    return Direction(found.direction, slopes, found.alignment, centre, angle[0])


@dataclass(frozen=True)
class Crossings:
    """Where each line's crank angle crosses each sample's window edges."""

    lower: np.ndarray
    """c where sample j's angle is at -reach_j from its top dead centre (crank behind), (n, m)."""
    upper: np.ndarray
    """c at which it is at +reach_j (run past), (n, m)."""
    lower_slope: np.ndarray
    """d(angle)/dc there, rad, (n, m)."""
    upper_slope: np.ndarray
    plain: np.ndarray
    """Each line's own draw's crank angle at the constraint samples, (n, m), rad: plain
    Monte-Carlo trajectories (control/raise_k.py's table)."""
    unsettled: int
    """Edges whose last secant step still moved more than ROOT_TOLERANCE."""
    diverged: int
    """Lines whose own draw's angle was not finite (counted wholly below; so is a line whose
    angle diverged during its secant steps, its crossing then NaN)."""

    @classmethod
    def joined(cls, parts: list[Crossings]) -> Crossings:
        """The lines of several stages as one."""
        if len(parts) == 1:
            return parts[0]
        arrays = {
            name: np.concatenate([getattr(p, name) for p in parts])
            for name in ("lower", "upper", "lower_slope", "upper_slope", "plain")
        }
        return cls(
            **arrays,
            unsettled=sum(p.unsettled for p in parts),
            diverged=sum(p.diverged for p in parts),
        )

    def rows(self, start: int, stop: int) -> Crossings:
        """Lines start..stop - 1 (their edges, slopes and draws; the counts are the whole's)."""
        arrays = {
            name: getattr(self, name)[start:stop]
            for name in ("lower", "upper", "lower_slope", "upper_slope", "plain")
        }
        return Crossings(**arrays, unsettled=self.unsettled, diverged=self.diverged)

    def edges(self, side: str) -> np.ndarray:
        """`lower` or `upper`, by name."""
        return self.lower if side == "lower" else self.upper

    def slopes(self, side: str) -> np.ndarray:
        """`lower_slope` or `upper_slope`, by name."""
        return self.lower_slope if side == "lower" else self.upper_slope

    def per_sample(self) -> dict[int, float]:
        """Each constraint sample's own rate, by column (control/tail.py names the samples)."""
        p = special.ndtr(self.lower) + special.ndtr(-self.upper)
        return {j: float(np.minimum(p[:, j], 1.0).mean()) for j in range(p.shape[1])}

    def summary(self) -> dict[str, int]:
        """What a check's record adds (ocp.json's `tail_checks`)."""
        return {"lines_unsettled": self.unsettled, "lines_diverged": self.diverged}

    def probabilities(self, shift: np.ndarray | None = None) -> np.ndarray:
        """Each line's probability below the height at any constraint sample, (n,), with every
        angle at sample j moved by shift[j] rad (control/raise_k.py; default none)."""
        lower, upper = self.lower, self.upper
        if shift is not None:
            lower = lower - shift / self.lower_slope
            upper = upper - shift / self.upper_slope
        left, right = lower.max(axis=1), upper.min(axis=1)
        p = special.ndtr(left) + special.ndtr(-right)
        p = np.where(left >= right, 1.0, np.minimum(p, 1.0))
        return np.where(np.isfinite(p), p, 1.0)


def crossings(
    simulator: Simulator,
    found: Direction,
    u: np.ndarray,
    reach: np.ndarray,
    *,
    warm: Crossings | None = None,
    shift: np.ndarray | None = None,
) -> Crossings:
    """Each line's crossings (module docstring, 2): the draws u (n, size) simulated as they are
    (each line's own plain trajectory, kept: `plain`), each edge started from there at the
    direction's slope and refined by secant steps along the line (only the edges within FAR,
    only the lines not settled). `warm`: the same lines' crossings for a torque nearby, whose
    angles at u = 0 were `shift` (rad, per sample) behind these: each edge then starts at its
    crossing there moved by the shift over its slope, its first secant through the own draw as
    a cold start's (one or two steps where three or four are taken cold; before session 48 that
    first step was taken at the warm slope, which read 0.005-0.028 points above the converged
    rate on six checks of tests/test_draft_check.py's torque, where the cold start reads
    0.002-0.010 above it, and a default torque's 0.0001)."""
    if warm is not None and warm.lower.shape != (len(u), len(reach)):
        raise ValueError(f"a warm start of {warm.lower.shape} crossings for {len(u)} lines")
    unit = found.direction
    along = u @ unit
    base = u - np.outer(along, unit)
    plain = simulator.angles(u)
    diverged = ~np.all(np.isfinite(plain), axis=1)
    n, m = plain.shape
    edges, slopes, unsettled = {}, {}, 0
    for side, sign in (("lower", -1.0), ("upper", 1.0)):
        edge, slope = np.empty((n, m)), np.empty((n, m))
        for j in range(m):
            target = sign * reach[j]
            f0 = np.where(diverged, target, plain[:, j] - found.centre[j])
            b = np.full(n, found.slopes[j])
            c = along + (target - f0) / b
            if warm is not None:  # started near its crossing; the secant still from the own draw
                b = np.where(np.isfinite(warm.slopes(side)[:, j]), warm.slopes(side)[:, j], b)
                moved = warm.edges(side)[:, j] - (0.0 if shift is None else shift[j]) / b
                c = np.where(np.isfinite(moved), moved, c)
            near = np.flatnonzero(np.abs(c) < FAR)
            prev_c = along[near]
            prev_f = f0[near]
            for _ in range(SECANT_STEPS):
                if len(near) == 0:
                    break
                f = simulator.angles(base[near] + np.outer(c[near], unit), [j])[:, 0]
                f = f - found.centre[j]
                step_b = (f - prev_f) / np.where(c[near] != prev_c, c[near] - prev_c, np.nan)
                # a secant across one of the model's small jumps (its stiffness term where theta
                # crosses 2 pi) is no slope: kept within SLOPE_RANGE of the direction's
                low, high = SLOPE_RANGE[0] * found.slopes[j], SLOPE_RANGE[1] * found.slopes[j]
                good = np.isfinite(step_b)
                b[near] = np.where(good, np.clip(step_b, low, high), b[near])
                new = c[near] + (target - f) / b[near]
                # settled, or carried beyond FAR (its linear place is as good there)
                keep = (np.abs(new - c[near]) > ROOT_TOLERANCE) & (np.abs(new) < FAR)
                prev_c, prev_f = c[near][keep], f[keep]
                c[near] = new
                near = near[keep]
            unsettled += len(near)
            edge[:, j], slope[:, j] = c, b
        edges[side], slopes[side] = edge, slope
    lower = np.where(diverged[:, None], np.inf, edges["lower"])
    upper = np.where(diverged[:, None], -np.inf, edges["upper"])
    return Crossings(
        lower, upper, slopes["lower"], slopes["upper"], plain, unsettled, int(diverged.sum())
    )


def mirrored(rng: np.random.Generator, count: int, size: int) -> np.ndarray:
    """`count` lines' draws u, (count, size), in antithetic pairs (session 48): rows 2i and 2i + 1
    are a standard normal draw and its mirror -u, the one's line the other's reflected through
    the origin (the same direction: a line running behind where the other runs ahead). Each row
    is a standard normal draw, so the lines' mean stays unbiased; the pair's probabilities are
    anticorrelated where the tail lies mostly on one side of the mean (-0.52..-0.57 on three
    default torques, bench/antithetic_lines.md), which `mean_and_error` counts. Drawn `count` // 2
    rows at a time from `rng`, so that stages drawn in turn are one run of pairs."""
    if count % 2:
        raise ValueError(f"line sampling draws lines in mirrored pairs: an even count, not {count}")
    half = rng.standard_normal((count // 2, size))
    u = np.empty((count, size))
    u[0::2], u[1::2] = half, -half
    return u


def mean_and_error(p: np.ndarray) -> tuple[float, float]:
    """The rate the lines (`mirrored` pairs, in order) read and its standard error: the spread of
    the pairs' means over √pairs."""
    if len(p) % 2:
        raise ValueError(f"{len(p)} lines are not whole mirrored pairs")
    pairs = p.reshape(-1, 2).mean(axis=1)
    if len(pairs) < 2:
        return float(p.mean()), math.inf
    return float(p.mean()), float(pairs.std(ddof=1) / math.sqrt(len(pairs)))
