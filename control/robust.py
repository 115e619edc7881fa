"""The robust OCP of paper eq. 16, by iterating OCP solve and Monte-Carlo uncertainty.

Eq. 16 tightens the slider constraint to slider_k - k sigma_k >= height, with sigma_k the
Monte-Carlo standard deviation (eq. 11) of the slider position under the torque being computed.
Beside this "gaussian" tightening, "centred" (the default since session 17) counts k sigma below the
Monte-Carlo's mean slider, plan_k - mean_k + k sigma_k: near top dead centre x(theta) is concave, so
the machines' mean slider sits below the plan's and eq. 16 reads that offset as margin
(control/tightening.py). "quantile" uses plan_k - Q_p (Q_p the Monte-Carlo's lower quantile at p =
Phi(-k)), which holds at the confidence k sigma stands for when the spread is also skewed; below, "k
sigma" stands for any of them. sigma depends on the torque: near top dead centre the slider hardly
moves with theta, so a torque that reaches the constraint far from it (the nominal one) has a far
larger sigma than one that dwells near it. The margin m (one per constraint sample) is therefore a
fixed point, m = k sigma(u*(height + m)), a root of the residual F(m) = k sigma(u*(height + m)) - m,
found per constraint sample by a bracketed secant from m = 0 (the nominal solve;
control/fixed_point.py): the first step is the nominal's k sigma, as in a plain fixed-point
iteration; once a margin with F < 0 is known, every step is regula falsi (Illinois) inside the
bracket. A proposal IPOPT cannot meet (the nominal sigma can eat the whole stroke) halves a damping
beta of the step and retries from the last solved margin; beta doubles back towards 1 after each
solve. Each proposal is capped at 95 % of the stroke left above the height. The loop stops when k
sigma of the latest solution is within `margin_tolerance` of the margin it was solved with (or,
where the map jumps, at most the margin: control/fixed_point.py), at every sample, so that slider -
k sigma >= height - margin_tolerance holds there. Each solve is warm-started from the previous one;
the Monte-Carlo reuses one seed, so the map m -> k sigma is deterministic.

Beyond the paper, the line as known from a few machines and the tightening as known from a
finite Monte-Carlo (`confidence`, ppann/confidence.py, ppann/machine.py): the machines the PPANN
was trained on are a sample of the line, so the line's spread and mean are estimates, and so is
k sigma. With confidence c > 0 and z = confidence_quantile(c) (2.13 at 0.95):
- the Monte-Carlo's machines are drawn with the likelihood-ratio upper bound of machine_sigma at
  z instead of its estimate (modes that draw machines), calibrated for the M machines the model
  learnt the line from (ppann/confidence.py spread_level: the exact chi-square bound);
- the tightening at sample k gains how far the line's mean slider can sit below the model's:
  the largest drop of the mean model's slider there when the whole line's log-factors shift by
  a delta with delta^T C^-1 delta = z_M^2 (C the covariance of the line's mean log-factors, z_M
  the Student bound from M machines, ppann/confidence.py mean_quantile: 2.82 for 8 machines,
  2.14 for 310), simulated (`population_margin`); to first order z_M sqrt(g_k^T C g_k),
  g_k = d slider_k / d delta; a model learnt from one machine bounds nothing and is refused;
- the tightening gains what makes it a one-sided upper confidence bound, at z, of the tightening
  an infinite Monte-Carlo would ask for (`sampling`, control/tightening.py: about z times the
  standard error).
  Without it, the point estimate is short half the time, and whether a task at the edge of the
  stroke had a robust torque depended on the Monte-Carlo seed (one seed in five on the edge task
  of bench/bench_tasks.py).
The three bounds hold together with probability >= c (Bonferroni), so the k-sigma promise is kept
on the line, not only on the fitted model of it and its sampled spread. c = 0 is the paper's
eq. 16 (bit-identical).

The open-loop profile finds its margins first by control/aware.py (OCPConfig.margin_scheme
"aware", the default): the tightening inside the NLP as a function of theta_k, corrected by each
solve's Monte-Carlo, under the same acceptance as below; where that does not settle, the
bracketed loop above decides from the nominal plan (its refusals are the ones reported).

Draft, then final: the iteration runs on draft solves (control/ocp.py: one loose IPOPT pass; its
torque is all the Monte-Carlo needs), which cost a fraction of a full solve. When a draft meets
the tolerance, the next proposal is solved in full (turn passes, tolerance 1e-10) and its own
Monte-Carlo must meet the tolerance too; otherwise the drafts resume from it. Only a full solve is
ever returned.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from control import aware
from control.config import OCPConfig, law_of, loop_of
from control.fixed_point import Bracket
from control.lqr import LQRWeights, tracking_gains
from control.ocp import NominalOCP, OCPError, Solution
from control.records import (
    BeyondStrokeError,
    Iteration,
    Partial,
    RobustError,
    RobustResult,
    iteration,
)
from control.tightening import Uncertainty, at_k, slider_uncertainty
from ppann.heads import FusedHeads
from ppann.model import PPANN

MIN_DAMPING = 1 / 256
STROKE_SHARE = 0.95
"""A margin asks for at most this share of the stroke left above the height: beyond the top
dead centre the OCP is infeasible by geometry, and IPOPT takes long to say so."""


def solve_robust(
    model: PPANN,
    config: OCPConfig | None = None,
    *,
    profile: str = "robust",
    ocp: NominalOCP | None = None,
    nominal: Solution | None = None,
    on_iteration: Callable[[Iteration], None] | None = None,
    heads: FusedHeads | None = None,
    start: RobustResult | None = None,
    draft_check: Callable[[Solution, Uncertainty, OCPConfig], float | None] | None = None,
) -> RobustResult:
    """Nominal solve (or `nominal`, solved before on `ocp`), its uncertainty, then the bracketed
    margin iteration of the module docstring for the robust `profile` (ROBUST_PROFILES: its
    tightening sized for the open loop, or for the closed loop under the plan's LQR or the
    fixed PD); the result carries both plans' gains of the profile's law and their open- and
    closed-loop spread. `heads`: the model's FusedHeads, if already built (~30 ms to build).
    `start`: the robust result of the same task solved before (at another k: control/profiles.py's
    raise), whose torque the aware scheme starts from, with its Monte-Carlo under `config`, in
    place of the nominal plan (where the aware scheme hands over, the bracket starts from the
    nominal; the nominal plan's gains and spreads are the start's, which k does not move).
    Where that torque is the aware scheme's own, its first solve is a full one from
    its multipliers too (they belong to the same NLP): on the ten raised pairs of session 33
    (five models, Monte-Carlo seeds 3 and 4) 1-2 full solves where three (two drafts and a full
    one) were made from its primal point, the same margins to 0.07 mm. `draft_check`: shown the
    aware scheme's first draft near its fixed point, its Monte-Carlo and the configuration, it
    may answer a larger k to go on at (control/aware.py `iterate`; the result says the k it was
    solved at).

    Raises:
      OCPError: the nominal OCP itself fails.
      RobustError: no margin within max_robust_iterations, or damping exhausted by failures.
    """
    config = config or OCPConfig()
    ocp = ocp or NominalOCP(model, config)
    loop = loop_of(profile)
    heads = FusedHeads(model) if heads is None else heads
    index = np.array(config.constraint_samples) - 1
    base = np.full(len(index), config.height)
    available = model.geometry.stroke_top - config.height
    cap = np.full(len(index), STROKE_SHARE * available)

    weights = LQRWeights.from_config(config)
    law = law_of(profile)

    def gains_of(solution: Solution) -> np.ndarray:
        """The gains (N-1, 2) of the profile's law along a plan: its LQR, or the fixed PD."""
        if law == "pd":
            return np.tile([config.pd_kp, config.pd_kd], (solution.states.shape[0] - 1, 1))
        return tracking_gains(ocp.dynamics.step_on_turn, solution.states, solution.tau, weights)

    def tube(solution: Solution) -> np.ndarray | None:
        return gains_of(solution) if loop == "closed" else None

    nominal = nominal if nominal is not None else ocp.solve()
    scheme = "aware" if loop == "open" and config.margin_scheme == "aware" else "bracket"
    if scheme == "aware":  # its NLP is built once per task, like the nominal's: not the loop's
        aware.aware_ocp(model, ocp, samples=config.mc_samples)
    # the loop's time from here: the nominal plan's own Monte-Carlo is the loop's first (before
    # session 34 the clock started after it, ~0.1 nominal solves left out of every figure)
    started = time.perf_counter()
    nominal_gains = tube(nominal)
    nominal_unc = slider_uncertainty(heads, nominal, config, gains=nominal_gains)
    # a raise (start: the same task at another k, from the same nominal plan): the nominal's
    # gains and spreads do not depend on k (the same draws), so they are the start's
    reused = None
    if start is not None and _same_plan(start.nominal, nominal):
        reused = start.nominal_gains, start.nominal_loops

    def nominal_feedback() -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The nominal plan's gains (the tube's, if already computed) and its open- and
        closed-loop spread, for the result or a failed solve's partial one."""
        if reused is not None:
            return reused
        gains = gains_of(nominal) if nominal_gains is None else nominal_gains
        return gains, _loops(heads, nominal, config, gains, nominal_unc, sized=loop)

    iterations: list[Iteration] = []
    failed: list[np.ndarray] = []

    def finish(
        solution: Solution, unc: Uncertainty, gains: np.ndarray | None, k: float
    ) -> RobustResult:
        wall_time = time.perf_counter() - started
        solved = replace(config, k_sigma=k)
        # the tube's gains and the sized-for loop's spread are known; only the rest is new
        feedback_gains, feedback_loops = nominal_feedback()
        robust_gains = gains_of(solution) if gains is None else gains
        return RobustResult(
            nominal=nominal,
            nominal_uncertainty=nominal_unc,
            robust=solution,
            robust_uncertainty=unc,
            iterations=tuple(iterations),
            failed_proposals=tuple(failed),
            wall_time=wall_time,
            nominal_gains=feedback_gains,
            robust_gains=robust_gains,
            nominal_loops=feedback_loops,
            robust_loops=_loops(heads, solution, solved, robust_gains, unc, sized=loop),
            tightening=config.tightening,
            k_sigma=k,
        )

    if scheme == "aware":

        def record(
            solution: Solution, unc: Uncertainty, kept: np.ndarray, draft: bool, k: float
        ) -> None:
            at = replace(config, k_sigma=k)  # raised at a draft (`draft_check`), or config's
            iterations.append(iteration(solution, unc, kept, at, profile, draft, "aware"))
            if on_iteration is not None:
                on_iteration(iterations[-1])

        first, first_unc, again = nominal, nominal_unc, False
        if start is not None:  # a raise: from the torque before, its Monte-Carlo at this k
            first, drawn = start.robust, start.robust_uncertainty
            if drawn.samples == config.mc_samples:  # the same draws: not drawn again
                first_unc = at_k(heads, first, drawn, config)
            else:  # the verdict drew more (control/profiles.py)
                first_unc = slider_uncertainty(heads, first, config)
            again = bool(start.iterations) and start.iterations[-1].scheme == "aware"
        try:
            found = aware.iterate(
                model,
                ocp,
                config,
                heads=heads,
                nominal=first,
                nominal_unc=first_unc,
                cap=cap,
                record=record,
                draft=not again,
                multipliers=again,
                draft_check=None if draft_check is None else lambda s, u: draft_check(s, u, config),
            )
            solution, unc, k = found
            return finish(solution, unc, None, k)
        except aware.AwareError:
            pass  # the bracket decides, from the nominal plan
    first = len(iterations)  # the aware scheme's solves, if it handed over
    margin = np.zeros(len(index))
    target = nominal_unc.tightening
    current = nominal
    bracket = Bracket(margin, target - margin)
    tolerance = config.margin_tolerance
    beta = 1.0
    draft = True
    try:
        while len(iterations) - first < config.max_robust_iterations:
            step = bracket.propose(margin, target - margin, tolerance=tolerance) - margin
            proposal = np.minimum(margin + beta * step, cap)
            try:
                solution = ocp.solve(base + proposal, warm=current, draft=draft)
            except OCPError:
                failed.append(proposal)
                beta /= 2
                if beta < MIN_DAMPING:
                    raise RobustError(
                        f"robust OCP infeasible for every margin tried; smallest failed margin "
                        f"{_mm(proposal)} (tightening of the last solution {_mm(target)})"
                    ) from None
                continue
            gains = tube(solution)
            unc = slider_uncertainty(heads, solution, config, constraints_only=draft, gains=gains)
            new_target = unc.tightening
            iterations.append(
                iteration(solution, unc, proposal, config, profile, draft, "bracket", beta)
            )
            if on_iteration is not None:
                on_iteration(iterations[-1])
            beyond = (proposal >= cap) & (new_target > cap)
            if beyond.any():
                raise _beyond_stroke(
                    config,
                    int(np.flatnonzero(beyond)[0]),
                    unc,
                    cap,
                    available=available,
                    loop=loop,
                    law=law,
                )
            residual = new_target - proposal
            bracket.update(proposal, residual)
            margin, target, current = proposal, new_target, solution
            # within the tolerance, or on the safe side of a jump (control/fixed_point.py)
            jump = bracket.jumps(tolerance) & (residual <= 0)
            settled = bool(np.all((np.abs(residual) < tolerance) | jump))
            if settled and draft:
                draft = False  # confirm with a full solve
                continue
            if settled:
                return finish(solution, unc, gains, config.k_sigma)
            beta = min(1.0, 2 * beta)  # solved: undo infeasibility damping step by step
            draft = True
        raise RobustError(
            f"robust margin not settled after {config.max_robust_iterations} iterations: "
            f"last margin {_mm(margin)}, its tightening {_mm(target)} (tolerance "
            f"{config.margin_tolerance * 1e3:g} mm)"
        )
    except RobustError as exc:
        feedback_gains, feedback_loops = nominal_feedback()
        exc.partial = Partial(
            nominal=nominal,
            nominal_uncertainty=nominal_unc,
            nominal_gains=feedback_gains,
            nominal_loops=feedback_loops,
            iterations=tuple(iterations),
            failed_proposals=tuple(failed),
            wall_time=time.perf_counter() - started,
        )
        raise


def _beyond_stroke(
    config: OCPConfig,
    k: int,
    unc: Uncertainty,
    cap: np.ndarray,
    *,
    available: float,
    loop: str,
    law: str = "lqr",
) -> BeyondStrokeError:
    """The error for constraint `k` (0-based) whose tightening `unc` asks for exceeds the cap."""
    sample = config.constraint_samples[k]
    line = ""
    if unc.population[k] > 0 or unc.sampling[k] > 0:
        line = (
            f", of which {1e3 * unc.population[k]:.1f} mm for the line's mean as known "
            f"from the training machines and {1e3 * unc.sampling[k]:.1f} mm for the "
            f"Monte-Carlo's standard error, at confidence {config.confidence:g}"
        )
    if loop == "closed":
        stiffer = "PD gains" if law == "pd" else "LQR weights"
        hint = (
            f"or give the feedback more authority, a torque limit above "
            f"{config.torque_limit:g} N·m or stiffer {stiffer}: the closed loop cannot keep "
            f"this spread"
        )
    else:
        hint = (
            "or close the loop (robust-fb; robust-pd for a fixed PD): open loop cannot keep this "
            "spread"
        )
    return BeyondStrokeError(
        f"the model's tightening of the slider at sample {sample} "
        f"({1e3 * unc.tightening[k]:.1f} mm{line}; Monte-Carlo σ there "
        f"{1e3 * unc.std[sample - 1]:.1f} mm) exceeds the stroke "
        f"above the height even for a torque that uses {1e3 * cap[k]:.1f} mm of it: no "
        f"robust profile (train on more machines, lower k_sigma or height, {hint})",
        sample=sample,
        tightening=float(unc.tightening[k]),
        se=float(unc.tightening_se[k]),
        available=float(available),
        line=float(unc.population[k]),
    )


def _same_plan(one: Solution, other: Solution) -> bool:
    """Whether two solutions are the same plan (torque and states, bit for bit)."""
    return np.array_equal(one.tau, other.tau) and np.array_equal(one.states, other.states)


def _loops(
    heads: FusedHeads,
    planned: Solution,
    config: OCPConfig,
    gains: np.ndarray,
    known: Uncertainty,
    *,
    sized: str,
) -> dict[str, np.ndarray]:
    """Monte-Carlo slider std (N,) of a plan open loop and closed under `gains`; `known` is the
    plan's full-horizon uncertainty in the loop `sized` (the tightening's; the Monte-Carlo uses
    the same draws, so it is that loop's std bit for bit)."""
    other = "open" if sized == "closed" else "closed"
    unc = slider_uncertainty(heads, planned, config, gains=gains if other == "closed" else None)
    return {sized: known.std, other: unc.std}


def _mm(values: np.ndarray) -> str:
    return "[" + ", ".join(f"{v * 1e3:.2f}" for v in values) + "] mm"
