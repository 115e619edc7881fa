"""Every robust profile of a task on one nominal plan, each with a verdict that does not hang on
the Monte-Carlo's draws.

A robust torque exists where the tightening, allowances included, fits under the share of the
stroke a margin may take (control/robust.py STROKE_SHARE). The tightening is a Monte-Carlo
estimate with a standard error se (control/tightening.py), so where it sits within a few se of
that cap, whether a torque comes back depends on the draws. Measured on training seed 1 of the
paper line, task horizon 200 / samples 70, 130 (docs/history.md, *Early stopping on every
machine*): a torque on three of five Monte-Carlo seeds at 1000 trajectories (18.5-18.9 mm asked
against 19.0, se ~0.55 mm), on all five at 4000 (se 0.26-0.29 mm). A verdict that close, a torque
or a refusal, is therefore decided again with ESCALATION times the trajectories, at most
MAX_ESCALATIONS times: the band where the draws decide narrows like 1/sqrt(n), and only the
tasks inside it pay for the precision. It cannot vanish: a tightening exactly at the cap stays
a coin toss at any finite count.

Then its own tail (OCPConfig.tail_check, control/tail.py): k sigma stands for Φ(−k) only where
the slider's spread is normal; where the decided torque's own Monte-Carlo, with the
tightening's allowances, puts more than the target rate below the height, the profile is
decided again (OCPConfig.tail_remedy): at the k the check predicts, at most TAIL_STEPS times,
each from the torque before it (the aware scheme's first solve warm from it, with its
Monte-Carlo at the raised k, and a full solve from its multipliers where it was the aware
scheme's own: control/robust.py `solve_robust`; the same margins to the loop's tolerance as from
the nominal, in fewer solves), then with the quantile tightening; the last torque is returned.

Before the returned solve (session 47, `_draft_raise`; bench/draft_check.md): where that raise would
follow, it is made inside the open-loop aware scheme, from its draft near the fixed point, so that
the loop settles once, at the raised k (16-17 of 25 default models × Monte-Carlo seeds within 3
nominal solves, from 8); the returned torque's check starts from that draft's lines."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from control import tail, tail_lines
from control.config import MAX_MC_SAMPLES, OCPConfig, loop_of
from control.ocp import NominalOCP, Solution
from control.raise_k import PREDICTED, prediction, raised_k, smallest_k
from control.robust import (
    STROKE_SHARE,
    BeyondStrokeError,
    Iteration,
    RobustError,
    RobustResult,
    solve_robust,
)
from control.tail import TAIL_BAND, TailCheck, tail_check
from control.tightening import Uncertainty
from ppann.heads import FusedHeads
from ppann.model import PPANN

DECISION_BAND = 2.0
"""A verdict whose tightening is within this many standard errors of the cap is decided again
with more trajectories."""
ESCALATION = 4
"""Each re-decision draws this many times the trajectories (the se halves)."""
MAX_ESCALATIONS = 2
"""At most this many re-decisions: up to 16x the configured trajectories, and never more than
control/config.py MAX_MC_SAMPLES (the quantile tightening's 14 816 at k = 3 escalate once, to
59 264, then to the cap)."""

TAIL_STEPS = 2
"""At most this many re-decisions at a raised k (raise_k.py `raised_k`) before the quantile."""
DRAFT_LINES = tail_lines.LINE_STAGES[0]
"""Lines of the draft's check (`_draft_raise`): the returned torque's first stage, whose
crossings then start that stage's secants (control/tail.py, a warm check)."""


@dataclass(frozen=True)
class Solved:
    """The robust profiles of config.profiles on one nominal plan: those solved and, for those
    refused, why (a solved profile not in config.profiles is config.fallback's)."""

    results: dict[str, RobustResult]
    refused: dict[str, RobustError]


def undecided(tightening: np.ndarray, se: np.ndarray, cap: float) -> bool:
    """Whether a tightening (per constraint sample, m) is within DECISION_BAND standard errors
    of the cap at any sample."""
    return bool(np.any(np.abs(np.asarray(tightening) - cap) < DECISION_BAND * np.asarray(se)))


def solve_decided(
    model: PPANN,
    config: OCPConfig,
    *,
    profile: str,
    ocp: NominalOCP,
    nominal: Solution,
    on_iteration: Callable[[Iteration], None] | None = None,
    heads: FusedHeads | None = None,
) -> RobustResult:
    """`decide` (its open-loop aware loop's draft checked before the returned solve, and k raised
    there where that check is clear: `_draft_raise`), then (OCPConfig.tail_check) the torque's
    own tail (`own_tail`, warm from the draft's check): where its own violation rate is above
    the target, the profile is decided again at the k its check's own trajectories predict to
    bring it to the target (control/raise_k.py `raised_k`), and checked again, at most
    TAIL_STEPS times; where no raised k passes (or none exists, or it is refused), with the
    quantile tightening at the configured k (unless that was the tightening). The torque
    returned is the last one, its checks after the ones before it (the draft's first,
    `TailCheck.draft`); the wall time is all of it: every decision's loop (the draft's check
    inside it), every check and every raise's prediction (each decided torque's spreads for
    the reports, control/robust.py `_loops`, are not the loop's). `heads`: the model's
    FusedHeads, if already built (every decision and check shares one).

    Raises:
      RobustError: no robust torque; or, where the tail sent the profile to the quantile
        tightening, none with that one (its error, saying why it was tried).
    """
    heads = FusedHeads(model) if heads is None else heads
    arguments = {
        "profile": profile,
        "ocp": ocp,
        "nominal": nominal,
        "on_iteration": on_iteration,
        "heads": heads,
    }
    drafts: list[TailCheck] = []
    early = _draft_raise(heads, config, profile=profile, seen=drafts)
    result = decide(model, config, draft_check=early, **arguments)
    if not config.tail_check:
        return result
    # the last decision's draft check, if its torque is the aware scheme's (not the bracket's)
    aware = bool(result.iterations) and result.iterations[-1].scheme == "aware"
    ahead = tuple(drafts[-1:]) if aware else ()
    checks = [own_tail(heads, result, config, profile=profile, warm=ahead[0] if ahead else None)]
    spent = result.wall_time + checks[0].wall_time
    if checks[0].passed or config.tightening == "quantile":  # nothing sounder to send it to
        return replace(result, tail_checks=(*ahead, checks[0]), wall_time=spent)
    tried = []
    for _ in range(TAIL_STEPS if config.tail_remedy == "raise-k" else 0):
        predicting = time.perf_counter()
        inputs = _raise_inputs(
            heads, result.robust, result.robust_uncertainty, config, result.tightening
        )
        k = raised_k(checks[-1], config, **inputs)
        spent += time.perf_counter() - predicting  # the decision's too (before session 45 not)
        if k is None:
            tried.append("no k reaches the target")
            break
        try:
            result = decide(model, replace(config, k_sigma=k), start=result, **arguments)
        except RobustError as exc:
            spent += exc.partial.wall_time if exc.partial is not None else 0.0
            if isinstance(exc, BeyondStrokeError):  # the quantile's error will say the rest
                tried.append(
                    f"at k {k:g} its tightening at sample {exc.sample} "
                    f"({1e3 * exc.tightening:.1f} mm) was beyond the stroke"
                )
            else:
                tried.append(f"at k {k:g} refused ({exc})")
            break
        checks.append(own_tail(heads, result, config, profile=profile))
        spent += result.wall_time + checks[-1].wall_time
        if checks[-1].passed:
            return replace(result, tail_checks=(*ahead, *checks), wall_time=spent)
        tried.append(f"at k {k:g} {100 * checks[-1].rate:.2f} %")
    first = checks[0]
    why = (
        f"its {config.tightening} torque's own Monte-Carlo went below the height on "
        f"{100 * first.rate:.2f} % {_of(first)} (target {100 * first.target:g} %)"
        + "".join(f"; {step}" for step in tried)
    )
    try:
        quantile = solve_decided(
            model, replace(config, tightening="quantile", mc_samples=0), **arguments
        )
    except RobustError as exc:
        bare = _bare(heads, result, checks[-1], config, profile=profile)
        exc.args = (f"{why}{bare}; and with the quantile tightening: {exc}",)
        exc.tail_checked = True
        raise
    return replace(
        quantile,
        tail_checks=(*ahead, *checks, *quantile.tail_checks),
        wall_time=spent + quantile.wall_time,
    )


def _draft_raise(
    heads: FusedHeads, config: OCPConfig, *, profile: str, seen: list[TailCheck]
) -> Callable[[Solution, Uncertainty, OCPConfig], float | None] | None:
    """The open-loop aware scheme's draft near its fixed point checked before its full solve
    (session 47; control/aware.py `iterate`'s `draft_check`), where its own tail would be checked
    and raised afterwards: on DRAFT_LINES lines; their rate moved to where the loop would settle at
    this k (control/raise_k.py `prediction`, `short`: the draft's margin is up to aware.NEAR
    tolerances short of its tightening) and, where that is TAIL_BAND of the lines' standard errors
    above the target (the returned torque's check would raise it), the k predicted to bring it to
    the aim, so that the loop settles once, at that k. `seen` collects each check; None where there
    is none to make (a tube, the bracketed loop, plain sampling, the quantile tightening, no check
    or no raise)."""
    if not (
        config.tail_check
        and config.tail_remedy == "raise-k"
        and config.tail_sampling == "lines"
        and config.margin_scheme == "aware"
        and config.tightening in PREDICTED
        and loop_of(profile) == "open"
    ):
        return None
    goal = tail.target(config)
    own = heads.clone()  # the check may run beside the loop's solves (control/beside.py)

    def raised(solution: Solution, unc: Uncertainty, solving: OCPConfig) -> float | None:
        check = tail_check(
            own,
            solution,
            solving,
            tightening=solving.tightening,
            population=unc.population,
            goal=goal,
            draws=DRAFT_LINES,
        )
        seen.append(replace(check, draft=True))
        if check.sampling != "lines":
            return None
        inputs = _raise_inputs(own, solution, unc, solving, solving.tightening)
        rate = prediction(check, solving, short=True, **inputs)
        if rate(0.0) - TAIL_BAND * check.standard_error <= goal:
            return None
        return smallest_k(rate, k=solving.k_sigma, goal=tail.aim(check))

    return raised


def _of(check: TailCheck) -> str:
    """What a check's rate was read from, in words."""
    lines = check.sampling == "lines"
    return f"by line sampling on {check.draws} lines" if lines else f"of {check.draws} trajectories"


def _raise_inputs(
    heads: FusedHeads, solution: Solution, unc: Uncertainty, config: OCPConfig, method: str
) -> dict[str, Any]:
    """What control/raise_k.py predicts from: a torque's mean-model crank angle, its tightening
    and its parts for the Monte-Carlo's sample and the line's mean (`unc`), the mechanism."""
    index = np.array(config.constraint_samples) - 1
    return {
        "geometry": heads.geometry,
        "plan_angle": solution.states[index, 0],
        "tightening": unc.tightening,
        "sampling": unc.sampling,
        "population": unc.population,
        "method": method,
    }


def own_tail(
    heads: FusedHeads,
    result: RobustResult,
    config: OCPConfig,
    *,
    profile: str,
    allowances: bool = True,
    draws: int | None = None,
    warm: TailCheck | None = None,
) -> TailCheck:
    """control/tail.py's check of a decided torque: its Monte-Carlo with the allowances its
    tightening used (or, without `allowances`, the model's own), open loop or, for a tube,
    under the profile's law along it, at the k it was solved with, judged by the configured k's
    target (`config`'s: a raised k does not move it); sequential, or exactly `draws`; `warm`:
    control/tail.py's (the same task and configuration)."""
    return tail_check(
        heads,
        result.robust,
        replace(config, k_sigma=result.k_sigma),
        tightening=result.tightening,
        population=result.robust_uncertainty.population,
        gains=result.robust_gains if loop_of(profile) == "closed" else None,
        goal=tail.target(config),
        allowances=allowances,
        draws=draws,
        warm=warm,
    )


def _bare(
    heads: FusedHeads, result: RobustResult, last: TailCheck, config: OCPConfig, *, profile: str
) -> str:
    """What a refusal adds about its last checked torque (`result`, checked by `last`): its
    rate on the same draws without config.confidence's allowances, the model's alone
    (bench/refused_h200.md: two refused torques held on the twin, 11 of 4000, where the model
    alone said 0.37-0.40 % and the check 0.57-0.61 %). Nothing at a confidence of 0."""
    if config.confidence <= 0:
        return ""
    bare = own_tail(heads, result, config, profile=profile, allowances=False, draws=last.draws)
    return (
        f"; the last torque checked (k {last.k_sigma:g}) {100 * bare.rate:.2f} % without the "
        f"allowances for confidence {config.confidence:g} (the model's own machine spread and "
        f"mean), {100 * last.rate:.2f} % with them"
    )


def decide(
    model: PPANN,
    config: OCPConfig,
    *,
    profile: str,
    ocp: NominalOCP,
    nominal: Solution,
    on_iteration: Callable[[Iteration], None] | None = None,
    heads: FusedHeads | None = None,
    start: RobustResult | None = None,
    draft_check: Callable[[Solution, Uncertainty, OCPConfig], float | None] | None = None,
) -> RobustResult:
    """solve_robust with `config.mc_samples` trajectories, decided again with ESCALATION times
    as many while its verdict is undecided (module docstring); `start`, `draft_check`:
    solve_robust's. The result's uncertainties say how many trajectories the last decision drew
    (`Uncertainty.samples`), its iterations are the last decision's, its wall time is all of
    them.

    Raises:
      RobustError: no robust torque (or none confirmed) at the last trajectory count tried.
    """
    cap = STROKE_SHARE * (model.geometry.stroke_top - config.height)
    counts = [config.mc_samples]
    for _ in range(MAX_ESCALATIONS):
        if counts[-1] < MAX_MC_SAMPLES:
            counts.append(min(counts[-1] * ESCALATION, MAX_MC_SAMPLES))
    spent = 0.0
    for attempt, samples in enumerate(counts):
        trial = replace(config, mc_samples=samples)
        final = attempt == len(counts) - 1
        try:
            result = solve_robust(
                model,
                trial,
                profile=profile,
                ocp=ocp,
                nominal=nominal,
                on_iteration=on_iteration,
                heads=heads,
                start=start,
                draft_check=draft_check,
            )
        except BeyondStrokeError as exc:
            if final or not undecided(np.array([exc.tightening]), np.array([exc.se]), cap):
                raise
            spent += exc.partial.wall_time if exc.partial is not None else 0.0
        else:
            unc = result.robust_uncertainty
            if final or not undecided(unc.tightening, unc.tightening_se, cap):
                # the loop's time is every decision's, not only the last one's
                return replace(result, wall_time=spent + result.wall_time)
            spent += result.wall_time
    raise AssertionError("unreachable: the last attempt returns or raises")


def solve_profiles(
    model: PPANN,
    config: OCPConfig,
    *,
    ocp: NominalOCP | None = None,
    on_iteration: Callable[[Iteration], None] | None = None,
    on_fallback: Callable[[str], None] | None = None,
) -> Solved:
    """The nominal plan once, then each robust profile of `config.profiles` from it
    (solve_decided). A profile that has no robust torque is refused and the others go on; where
    every one is refused, the profiles of `config.fallback` not asked for are solved the same
    way (on a wide line, the LQR tube beside the open loop's refusal), after
    `on_fallback` is told so in words.

    Raises:
      OCPError: the nominal OCP itself fails.
      RobustError: every profile, fallback included, was refused: the first one's error, naming
        the others', with `partials` (each profile's Partial).
    """
    ocp = ocp or NominalOCP(model, config)
    nominal = ocp.solve()
    results: dict[str, RobustResult] = {}
    refused: dict[str, RobustError] = {}

    def attempt(profile: str) -> None:
        try:
            results[profile] = solve_decided(
                model, config, profile=profile, ocp=ocp, nominal=nominal, on_iteration=on_iteration
            )
        except RobustError as exc:
            refused[profile] = exc

    for profile in config.profiles:
        attempt(profile)
    fallback = () if results else config.fallback_profiles
    if fallback and on_fallback is not None:
        on_fallback(f"{', '.join(refused)} refused: solving the fallback {', '.join(fallback)}")
    for profile in fallback:
        attempt(profile)
    if not results:
        first = next(iter(refused.values()))
        if len(refused) > 1:
            first.args = ("; ".join(f"{name}: {exc}" for name, exc in refused.items()),)
        first.partials = {name: exc.partial for name, exc in refused.items() if exc.partial}
        first.tail_checked = any(exc.tail_checked for exc in refused.values())
        raise first
    return Solved(results=results, refused=refused)
