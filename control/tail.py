"""The robust torque's own tail, checked after its loop (beyond the paper).

k sigma stands for Φ(−k) below the height at each constraint sample (0.135 % at k = 3) only
where the slider's spread there is normal. Near top dead centre it is not: the slider is a
concave function of the crank angle, and the angle's own spread is skewed, so the slider's lower
tail is longer than k sigma says. Measured on session 27's five default models (docs/history.md,
*The torque's own tail, checked after its loop*): this check put 0.80-1.09 % of the centred torques'
own trajectories below the height on the horizon-200 task (samples 70, 130), where such torques
went below on up to 0.75 % of 4000 held-out machines; 0.41-0.66 % on the paper's task over
Monte-Carlo seeds 0-4.

So after the loop, the returned torque's Monte-Carlo is drawn again, in stages (below) about
TAIL_DRAWS trajectories, from a stream of its own ("tail_check"; its white normals
counter-based, ppann/counter.py, generated inside the kernel where they are used), with the
same allowances as its tightening:
the line's spread at its upper confidence bound (`line_allowance`) and the line's mean at its
drop (`Uncertainty.population`, subtracted from every draw). The share of trajectories below the
height at any constraint sample is the torque's own violation rate. Above its target (`target`:
TARGET_RATE, the rate held-out machines judge a robust torque by, or the rate k itself stands
for where that is looser: a k of 0.5 asks for no better than 31 % per sample) the profile is
solved again (control/profiles.py, OCPConfig.tail_remedy):
- "raise-k" (the default since session 31): with its own tightening at the k that the check's
  own trajectories predict to bring its rate to the target (control/raise_k.py `raised_k`: the
  draws moved in crank angle until the tightening's condition holds on them), then checked
  again, the same draws; where no raised k passes, as "quantile". A
  raise is sized for its need: on development solves (no machines drawn; session 27's seed-3
  model, the horizon-200 task, Monte-Carlo seeds 0-4) k 3.22-3.51, own rates 0.44-0.48 %,
  premiums 1.6-3.5 points above the centred torques' (23.6-24.8 %) in 5-8 s, where the quantile
  tightening's cost 5.9-7.7 points and 8.8-79.5 s. On held-out machines (docs/history.md, *The tail
  check's remedy sized for its need*): 20 of 25 task-model pairs returned as with "quantile",
  at most 11 of 4000 below, 2.5-6.3 points of premium less.
- "quantile" (session 30's): the quantile tightening at the configured k, whose own rate is at
  most the number of constraint samples times Φ(−k) by construction.
Sequential (session 43, bench/sequential_tail_check.md): the rate is a Monte-Carlo estimate,
standard error sqrt(t (1 - t) / n) at the target t (0.05 points at 20 000 draws and 0.5 %), so
a torque whose own rate sits within a few of them of the target passes or not by the draws.
The check therefore draws in TAIL_STAGES, each stage's trajectories the first ones of the next
(the same streams: counter-based white normals, the machines and angles filled in order), and
stops at the first stage whose rate is TAIL_BAND standard errors from the target: at the first
(a quarter of TAIL_DRAWS) only on a pass, since a refused torque's trajectories size its raise
(`raised_k`, which wants the tail resolved); at TAIL_DRAWS on either side; the last stage
decides by its rate alone. A clear pass costs a quarter of the check; a rate within 0.40-0.60 %
at TAIL_DRAWS is decided again on four times the trajectories (se 0.025 points), which narrows
the band where the draws decide, and cannot remove it. Measured (bench/sequential_tail_check.md):
the pair's horizon-200 refusals were such draws (every model now returns and holds); the
defaults' own rates sit in the band, so most of their checks draw 80 000 (their checks took a
median 2.3 nominal solves per profile on the paper task; each stage draws only its new
trajectories, `first`).

By line sampling (the default since session 46, OCPConfig.tail_sampling = "lines",
control/tail_lines.py, `_lines` below): the same rate from 1000-4000 lines along the direction
the crank runs ahead or behind, to ±0.006-0.012 points (one standard error), in a median 0.7
nominal solves where the plain stages took 2.3 (bench/tail_lines.md); since session 48 from
500-2000 lines in mirrored pairs, to about the same error (bench/antithetic_lines.md); the
plain trajectories where the direction does not suit a constraint sample, or with
tail_sampling = "plain". A warm check (session 47, `warm`) reads a torque near one checked
before on the same lines: that check's direction (its slopes and origin simulated again) and
its crossings as the secants' starts (control/profiles.py: the returned torque after its
draft's check).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from common.streams import stream
from control import tail_lines as lines
from control.config import TARGET_RATE, OCPConfig, lower_tail
from control.ocp import Solution
from control.tail_lines import Crossings, Direction
from control.tightening import line_allowance
from ppann.heads import FusedHeads
from ppann.montecarlo import Feedback, monte_carlo
from ppann.transmission import draw
from twin.geometry import Geometry

TAIL_DRAWS = 20_000
"""Trajectories of the check's decision stage: 100 expected below at the target rate, a relative
standard error of 10 % (replay/heldout.py's model_rate draws as many); a raise is sized for its
standard error (`aim`)."""
TAIL_STAGES = (TAIL_DRAWS // 4, TAIL_DRAWS, 4 * TAIL_DRAWS)
"""The check's sequential stages (module docstring), each nested in the next."""
TAIL_BAND = 2.0
"""A stage decides where its rate is this many standard errors (at the target) from it
(control/profiles.py DECISION_BAND's convention)."""


@dataclass(frozen=True)
class TailCheck:
    """The share of a torque's own Monte-Carlo (with its tightening's allowances) below the
    height: at any constraint sample (`rate`) and at each."""

    draws: int
    """Trajectories of the stage that decided (the last one drawn)."""
    rate: float
    samples: dict[int, float]
    """Per 1-based constraint sample."""
    target: float
    tightening: str
    """The tightening the checked torque was solved with."""
    k_sigma: float
    """The k the checked torque was solved with (the configured one, or raised by the check:
    `raised_k`)."""
    wall_time: float
    stages: tuple[int, ...] = ()
    """Every stage drawn, in order (`stages[-1] == draws`); one for a fixed count."""
    lowered: np.ndarray = field(repr=False, compare=False, default_factory=lambda: np.zeros(0))
    """Each trajectory's slider at each constraint sample, lowered by the population margin,
    (draws, constraint samples), m (NaN where a draw diverged)."""
    angles: np.ndarray = field(repr=False, compare=False, default_factory=lambda: np.zeros(0))
    """The crank angle (theta + delta) under each of `lowered`'s sliders, rad: what
    control/raise_k.py moves (with lines: each line's own draw, a plain trajectory)."""
    sampling: str = "plain"
    """How it drew (OCPConfig.tail_sampling): "plain" trajectories or "lines"."""
    standard_error: float = math.nan
    """Of `rate`: binomial at the rate for plain draws, the lines' spread for lines."""
    lines: Crossings | None = field(repr=False, compare=False, default=None)
    """With line sampling: every line's crossings (control/raise_k.py moves them)."""
    direction: Direction | None = field(repr=False, compare=False, default=None)
    """With line sampling: the lines' direction (a warm check's start)."""
    draft: bool = False
    """A check of the robust loop's draft near its fixed point, which chose the k its full solve
    was made at (control/profiles.py `_draft_raise`), not of a returned torque."""

    @property
    def passed(self) -> bool:
        return self.rate <= self.target

    def as_dict(self) -> dict[str, Any]:
        return {
            "draws": self.draws,
            "stages": list(self.stages),
            "rate": self.rate,
            "samples": {str(k): v for k, v in self.samples.items()},
            "target": self.target,
            "tightening": self.tightening,
            "k_sigma": self.k_sigma,
            "passed": self.passed,
            "wall_time_s": self.wall_time,
            "sampling": self.sampling,
            "standard_error": self.standard_error,
            "draft": self.draft,
            **({} if self.lines is None else self.lines.summary()),
        }


def target(config: OCPConfig) -> float:
    """The largest own rate a torque passes the check with: TARGET_RATE, or the share of
    trajectories below at any of the constraint samples that k sigma stands for on independent
    normal samples, 1 - (1 - Φ(-k))^m, where that is larger (module docstring)."""
    stands_for = 1 - (1 - lower_tail(config.k_sigma)) ** len(config.constraint_samples)
    return max(TARGET_RATE, stands_for)


def tail_check(
    heads: FusedHeads,
    solution: Solution,
    config: OCPConfig,
    *,
    tightening: str,
    population: np.ndarray,
    gains: np.ndarray | None = None,
    draws: int | None = None,
    goal: float | None = None,
    allowances: bool = True,
    warm: TailCheck | None = None,
) -> TailCheck:
    """The torque's own violation rate (module docstring): trajectories under `solution`'s
    torque (solved with `tightening` at config.k_sigma), open loop or (with `gains`, (N-1, 2))
    under the tracking law along it, each slider lowered by `population` (per constraint sample,
    m), drawn in TAIL_STAGES until one decides (`decides`), or exactly `draws` of them. `goal`:
    the target it is judged by (default `target(config)`; a torque whose k the check raised
    keeps the configured k's). Without `allowances`, the same draws with the model's own machine
    spread and no population drop: the rate the model alone predicts, which a refusal reports
    beside the check's (what the confidence adds). `warm`: a check by line sampling of a torque
    near this one, on the same task and configuration (module docstring)."""
    started = time.perf_counter()
    goal = target(config) if goal is None else goal
    if allowances:
        spread, _ = line_allowance(heads, config)
    else:
        spread, population = None, np.zeros(len(config.constraint_samples))
    feedback = None
    if gains is not None:
        feedback = Feedback(solution.states, gains, config.torque_limit)
    if config.tail_sampling == "lines":
        lined = _lines(
            heads,
            solution,
            config,
            spread=spread,
            population=population,
            feedback=feedback,
            draws=draws,
            goal=goal,
            tightening=tightening,
            started=started,
            warm=warm,
        )
        if lined is not None:
            return lined
    stages = TAIL_STAGES if draws is None else (draws,)
    crank = np.zeros((0, len(config.constraint_samples)))
    lowered = crank
    for count in stages:
        # fresh each stage: a SeedSequence's spawn() counts its children
        paths, angles = stream(config.mc_seed, "tail_check").spawn(2)
        new = crank_angles(
            heads,
            solution.states[0],
            solution.tau,
            config,
            draws=count - len(crank),  # only the stage's new trajectories
            paths=paths,
            angles=angles,
            machine_sigma=spread,
            feedback=feedback,
            normals="counter",
            first=len(crank),
        )
        crank = np.concatenate([crank, new])
        lowered = np.concatenate([lowered, lowered_sliders(heads.geometry, new, population)])
        rate, samples = share_below(lowered, config)
        if count == stages[-1] or decides(rate, goal, count):
            break
    return TailCheck(
        draws=count,
        rate=rate,
        samples=samples,
        target=goal,
        tightening=tightening,
        k_sigma=config.k_sigma,
        wall_time=time.perf_counter() - started,
        stages=stages[: stages.index(count) + 1],
        lowered=lowered,
        angles=crank,
        standard_error=standard_error(rate, count),
    )


def _lines(
    heads: FusedHeads,
    solution: Solution,
    config: OCPConfig,
    *,
    spread: np.ndarray | None,
    population: np.ndarray,
    feedback: Feedback | None,
    draws: int | None,
    goal: float,
    tightening: str,
    started: float,
    warm: TailCheck | None,
) -> TailCheck | None:
    """`tail_check` by line sampling (control/tail_lines.py): its direction (`warm`'s, if given),
    then LINE_STAGES of lines (or exactly `draws`) until one decides by the lines' own standard
    error, the lines `warm` crossed started from its crossings, the check's time counted from
    `started`; None where the direction does not suit every constraint sample (the plain check
    then)."""
    index = np.array(config.constraint_samples) - 1
    simulator = lines.Simulator(
        heads,
        np.asarray(solution.states[0], dtype=float),
        np.asarray(solution.tau, dtype=float),
        lines.layout(heads, config.mc_mode, int(index.max())),
        heads.machine_sigma if spread is None else np.asarray(spread),
        index,
        feedback,
    )
    before = warm.direction if warm is not None else None
    found = lines.direction(simulator) if before is None else lines.redirected(simulator, before)
    if not found.usable:
        return None
    reach = heads.geometry.crank_reach(config.height + np.asarray(population))
    rng = np.random.default_rng(stream(config.mc_seed, "tail_lines"))
    stages = lines.LINE_STAGES if draws is None else (draws,)
    parts: list[lines.Crossings] = []
    for count in stages:
        u = lines.mirrored(rng, count - sum(len(p.lower) for p in parts), simulator.layout.size)
        start, done = None, count - len(u)
        if before is not None and warm.lines is not None and len(warm.lines.lower) >= count:
            start = warm.lines.rows(done, count)  # the same lines: the same stream, in order
        shift = None if start is None else found.origin - before.origin
        parts.append(lines.crossings(simulator, found, u, reach, warm=start, shift=shift))
        found_lines = lines.Crossings.joined(parts)
        rate, se = lines.mean_and_error(found_lines.probabilities())
        if count == stages[-1] or decides(rate, goal, count, se=se):
            break
    each = found_lines.per_sample()
    return TailCheck(
        draws=count,
        rate=rate,
        samples={k: each[j] for j, k in enumerate(config.constraint_samples)},
        target=goal,
        tightening=tightening,
        k_sigma=config.k_sigma,
        wall_time=time.perf_counter() - started,
        stages=stages[: stages.index(count) + 1],
        lowered=lowered_sliders(heads.geometry, found_lines.plain, population),
        angles=found_lines.plain,
        sampling="lines",
        standard_error=se,
        lines=found_lines,
        direction=found,
    )


def decides(rate: float, goal: float, draws: int, *, se: float | None = None) -> bool:
    """Whether a stage of the sequential check (module docstring) of `draws` trajectories at
    `rate` stops: TAIL_BAND standard errors (at the target) below the target, or, from
    TAIL_DRAWS on, as far above it. At a target of 0 or 1 (no error) any gap decides. With
    `se` (line sampling: the lines' own standard error, and crossings that size a raise at any
    stage) that many of it on either side, at any stage."""
    if se is not None:
        gap = rate - goal
        return abs(gap) >= TAIL_BAND * se if se > 0 else gap != 0
    gap, se = rate - goal, standard_error(goal, draws)
    distance = gap / se if se > 0 else math.copysign(math.inf, gap) if gap else 0.0
    return distance <= -TAIL_BAND or (draws >= TAIL_DRAWS and distance >= TAIL_BAND)


def standard_error(rate: float, draws: int) -> float:
    """The standard error of a share `rate` estimated from `draws` trajectories (binomial)."""
    return math.sqrt(rate * (1 - rate) / draws)


def lowered_sliders(
    geometry: Geometry, crank: npt.ArrayLike, population: npt.ArrayLike = 0.0
) -> np.ndarray:
    """The slider at crank angles `crank` (`crank_angles`'), lowered by `population` (per
    constraint sample, m), m; NaN where a draw diverged. The check's, control/raise_k.py's moved
    draws, and replay/heldout.py's model_rate (the model alone, its own streams, the calibration
    Monte-Carlo's draws)."""
    with np.errstate(over="ignore", invalid="ignore"):
        return geometry.slider_position(crank) - np.asarray(population)


def crank_angles(
    heads: FusedHeads,
    x0: np.ndarray,
    tau: np.ndarray,
    config: OCPConfig,
    *,
    draws: int,
    paths: np.random.SeedSequence,
    angles: np.random.SeedSequence,
    machine_sigma: np.ndarray | None = None,
    feedback: Feedback | None = None,
    normals: str = "stream",
    first: int = 0,
) -> np.ndarray:
    """The crank angle theta + delta of `draws` Monte-Carlo trajectories (config.mc_mode, from
    `paths`; the transmission's delta from `angles`) under `tau` from x0, simulated to the last
    constraint sample only, at each constraint sample, (draws, constraint samples), rad.
    `normals`: ppann/montecarlo.py's source of white normals. Only the constraint samples'
    states are kept (ppann/montecarlo.py `at`: at 20 000 draws, 32 MB less to write and fault
    in, ~30 ms of the first check in a process). `first`: trajectories first..first + draws - 1
    of the run of first + draws, the same numbers (counter normals)."""
    index = np.array(config.constraint_samples) - 1
    kept = np.unique(index)  # distinct (OCPConfig), in any order
    bands = monte_carlo(
        heads,
        x0,
        np.asarray(tau)[: index.max()],
        n_samples=draws,
        mode=config.mc_mode,
        seed=paths,
        machine_sigma=machine_sigma,
        feedback=feedback,
        normals=normals,
        at=kept,
        first=first,
    )
    delta = draw(heads.transmission, (first + draws,), np.random.default_rng(angles))[first:]
    return bands.samples[:, np.searchsorted(kept, index), 0] + delta[:, None]


def share_below(lowered: np.ndarray, config: OCPConfig) -> tuple[float, dict[int, float]]:
    """The share of `lowered_sliders`' trajectories below the height at any constraint sample,
    and at each (1-based). A diverged draw (NaN) counts below."""
    below = ~(lowered >= config.height)
    samples = {k: float(below[:, j].mean()) for j, k in enumerate(config.constraint_samples)}
    return float(below.any(axis=1).mean()), samples


def aim(check: TailCheck) -> float:
    """The own rate a raised k is sized for: the target less TAIL_BAND standard errors of the
    decision stage (TAIL_DRAWS) at the target, so that the check of the torque it gives decides
    there, a pass, unless the prediction was wrong (at 0.5 %: 0.40 %)."""
    return check.target - TAIL_BAND * standard_error(check.target, TAIL_DRAWS)
