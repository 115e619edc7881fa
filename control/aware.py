"""The open-loop robust profile's margins with the tightening inside the NLP, as a function of
theta_k ("aware", OCPConfig.margin_scheme; the default), corrected by the Monte-Carlo.

The bracketed loop of control/robust.py solves the NLP for a margin m per constraint sample and
asks the Monte-Carlo for the tightening T(m) of the torque found; its root takes ~8 draft solves
on a trained model, because T falls steeply with m (a torque that keeps the slider nearer top
dead centre spreads it less) and jumps where the 2 pi crossing moves a sample. Most of that
dependence is one of theta_k alone: the slider at sample k is x(theta_k + e) for the drawn angle
deviations e from the plan, and near top dead centre x hardly moves with e. This scheme puts it
in the NLP:

    x(theta_k) - s_k std_i x(theta_k + e_ik) >= height + p_k

with e_ik the first SURROGATE angle deviations (transmission included) of the last solve's
Monte-Carlo from its plan at sample k, p_k its line allowance for the mean (`population`), and
s_k the factor that makes the term equal that Monte-Carlo's tightening less p_k at the last
solution (it carries k, the other trajectories, the sampling allowance and, for quantile
tightening, the quantile's shape). All are frozen per solve and refreshed from each solve's own
Monte-Carlo; the NLP places theta_k itself against the cost. At the fixed point the margin a
solution keeps, slider - height, equals its own Monte-Carlo's tightening: the residual
tightening - margin is the bracketed loop's, and so is the acceptance.

The first solve starts from the nominal's primal point alone (its multipliers belong to the
nominal's constraint function: 15 IPOPT iterations with them, 8 without, on the seed-0 model; 5
since that point is not pushed off its bounds, control/solvers.py PRIMAL_BOUND_PUSH).
Drafts follow while any residual is outside the tolerance. A draft that settles with its
states its torque's own (it kept its warm start's 2 pi crossing: `exact`) is returned (since
session 52: on 22 of the bench's 25 model-seed pairs, one full solve and its Monte-Carlo fewer,
the same fixed point to IPOPT's draft tolerance); one that settles where its crossing moved is
followed once by a draft bounded to its torque's turns, returned if it settles (the three
other pairs: 6-9 IPOPT iterations where the full solve took 13-14); otherwise full solves
follow until one is within it at every sample, or sits on the safe side of a jump there
(`Acceptance`, in control/acceptance.py; control/fixed_point.py's "Jumps"): residual <= 0 where
some solve, draft or full, at a margin within the tolerance had a residual more than the
tolerance above it and above -tolerance, i.e. the map rose by more than the tolerance into the
tolerance's band (or across it) within less than the tolerance of margin.
On the seed-3 and seed-4 models of session 27 the last draft settled (residual -0.009 and -0.024
mm at sample 100) and the full solve from it, 0.004-0.009 mm of margin away on the plan's other
2 pi crossing, kept 0.13-0.17 mm of slack: it is returned at once (until session 29 the rise
had to cross zero, and a probe draft, or a probe and a second full solve, followed, to return
the same torque). A full solve on the safe side everywhere but with more slack than the
tolerance and no such rise is held, and a draft from it probes for one: where the draft shows it,
the held solve is returned; otherwise a full solve follows from the held one, as without the
probe. (Drafts going on from a probe that showed no jump cycled on the seed-4 model at
Monte-Carlo seed 1: its drafts settled on one crossing, its full solves on another 0.12 mm
safer, draft and full in turn until MAX_SOLVES.)

Drafts: a draft (control/ocp.py) is solved on its warm start's turns; where its 2 pi crossing
moved, the NLP's states follow the stiffness term extrapolated across 2 pi for a step or more,
not where its torque takes the machine (4-20 mrad of theta on the session-27 models, 0.85 mm of
slider on the test suite's constant model, tests/test_aware.py). The scheme takes instead the
torque's own states (`torque_states`, the mean model's rollout, ~2 ms), so that a draft's
margin, its Monte-Carlo (whose centred part is the plan less the draws' mean) and the angles
frozen from it belong to its torque, and its residual foretells the full solve's. With the
NLP's states, the full solve after a settled draft missed by 0.12-0.17 mm on the seed-1 and
seed-3 models of session 27 (a second full solve followed), and on that test model the scheme
did not settle in MAX_SOLVES. The bracketed loop keeps the NLP's states: its abscissa is the
margin it asks, which they keep.

A solve that fails, a margin beyond the stroke share a margin may take
(control/robust.py STROKE_SHARE), a solve that repeats one before the last within the tolerance
(a cycle, `repeats`: on the suite's constant model at Monte-Carlo seed 5 the drafts went
6.49/7.10 mm of margin in turn, +0.34/-0.33 mm of residual, 10 solves until session 33, handed
over after 4 since), or MAX_SOLVES without settling raise AwareError; the bracketed
loop then decides from the nominal plan, with its own refusals (a tightening above that share is
no reason to stop: the first solve from the nominal often asks more than the next ones; on the
tasks at the stroke's edge that are refused, three solves passed before a margin did). Before
the first solve, `reachable` checks that some crank angle keeps each frozen row above its
floor; where none does (a spread wider than the stroke, e.g. the open loop on line-15) the
bracket decides at once: IPOPT took 14 s to call that NLP infeasible on a line-15 model, and
each aware solve is capped at MAX_IPOPT iterations for the same reason. The tubes (closed-loop
profiles) keep the bracket: they settle in one draft and one full solve.

Measured with bench/bench_aware.py (docs/history.md): the same margins to 0.1 mm and cost to
0.25 % as the bracket on three trained models and four tasks, in 4-7 solves against 6-9, the
loop 1.25-2x faster.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext
from dataclasses import replace

import casadi as ca
import numpy as np

from common.errors import CrankError
from control.acceptance import Acceptance
from control.beside import Pending, wanted
from control.config import OCPConfig
from control.ocp import FEASIBILITY_TOLERANCE, NominalOCP, OCPError, Solution
from control.tightening import Uncertainty, at_k, slider_uncertainty
from ppann.heads import FusedHeads
from ppann.model import PPANN

SURROGATE = 200
"""Angle deviations per constraint sample in the NLP's tightening term (the Monte-Carlo's
first ones; its other trajectories enter through s_k). 50, 200 and 1000 took the same solves
on the seed-0 model; 200 keeps an IPOPT iteration within ~5 % of the nominal's."""
MAX_SOLVES = 10
"""Solves before the scheme hands over to the bracket (it settled in 3-7 in the benchmark)."""
MAX_IPOPT = 100
"""IPOPT iterations of one aware solve before it counts as failed (one took 21 at most in the
benchmark; an infeasible one ran 14 s on a line-15 model before IPOPT said so)."""
NEAR = 3.0
"""`iterate`'s `draft_check` sees the first draft whose residual is within this many tolerances at
every sample: the second on all 25 model-seed pairs of bench/bench_solve.py (0.14-0.26 mm, the
third 0.03-0.19 mm; session 47, bench/draft_check.md), so that a raised k's drafts replace the
third instead of following it."""
ANGLES = 720
"""Crank angles over one turn on which `reachable` looks for one that keeps a row up."""


class AwareError(CrankError, RuntimeError):
    """The aware scheme did not settle; control/robust.py falls back to the bracket (never
    reaches a user)."""


class AwareOCP(NominalOCP):
    """The OCP whose constraint rows are the slider less its theta-dependent tightening
    (module docstring), with `surrogate` frozen deviations per constraint sample."""

    def __init__(self, model: PPANN, config: OCPConfig, *, surrogate: int) -> None:
        self.surrogate = surrogate
        capped = min(config.max_ipopt_iterations, MAX_IPOPT)
        super().__init__(model, replace(config, max_ipopt_iterations=capped))
        self._frozen = (np.zeros(0), np.zeros((surrogate, 0)), np.zeros(0))

    def _slider_rows(self, x: ca.MX, index: list[int]) -> tuple[ca.MX, ca.MX]:
        n, k = self.surrogate, len(index)
        deviation, scale = ca.MX.sym("deviation", n, k), ca.MX.sym("scale", k)
        rows = []
        for j, i in enumerate(index):
            drawn = self.geometry.slider_position(x[0, i] + deviation[:, j], lib=ca)
            spread = ca.sqrt(ca.sumsqr(drawn - ca.sum1(drawn) / n) / (n - 1))
            rows.append(self.geometry.slider_position(x[0, i], lib=ca) - scale[j] * spread)
        return ca.vertcat(*rows), ca.vertcat(ca.vec(deviation), scale)

    def freeze(self, solution: Solution, unc: Uncertainty) -> None:
        """Take the deviations and scale of `solution`'s Monte-Carlo `unc` for the next solve:
        at `solution`, the tightening term then equals unc.tightening - unc.population."""
        plan = solution.states[np.array(self.config.constraint_samples) - 1, 0]
        deviation = unc.angles[: self.surrogate] - plan
        scale = (unc.tightening - unc.population) / self.spread(plan, deviation)
        self._frozen = (plan, deviation, scale)
        self._extra = np.concatenate([deviation.T.ravel(), scale])

    def reachable(self, floor: np.ndarray) -> np.ndarray:
        """Per constraint sample, whether some crank angle (of ANGLES over a turn) keeps the
        frozen row at or above `floor` (m): where none does, the NLP is infeasible by the
        geometry alone, whatever the torque."""
        plan, deviation, scale = self._frozen
        turn = np.linspace(-np.pi, np.pi, ANGLES, endpoint=False)
        best = np.empty(len(plan))
        for j in range(len(plan)):
            theta = plan[j] + turn
            drawn = self.geometry.slider_position(theta[:, None] + deviation[None, :, j])
            rows = self.geometry.slider_position(theta) - scale[j] * drawn.std(axis=1, ddof=1)
            best[j] = rows.max()
        return best >= floor

    def spread(self, plan: np.ndarray, deviation: np.ndarray) -> np.ndarray:
        """The NLP's std_i x(theta_k + e_ik) per constraint sample, for plan angles (K,) and
        deviations (surrogate, K)."""
        return self.geometry.slider_position(plan + deviation).std(axis=0, ddof=1)


_BUILT: weakref.WeakKeyDictionary[NominalOCP, dict[int, AwareOCP]] = weakref.WeakKeyDictionary()


def aware_ocp(model: PPANN, ocp: NominalOCP, *, samples: int) -> AwareOCP:
    """The aware NLP of `ocp`'s task for a Monte-Carlo of `samples` trajectories, built once per
    `ocp` (a second IPOPT build: 1.6 s on the seed-0 model, as long as the nominal's)."""
    surrogate = min(SURROGATE, samples)
    built = _BUILT.setdefault(ocp, {})
    if surrogate not in built:
        built[surrogate] = AwareOCP(model, ocp.config, surrogate=surrogate)
    return built[surrogate]


def torque_states(ocp: NominalOCP, draft: Solution, *, warm: Solution) -> Solution:
    """`draft` (solved on `warm`'s turns) with the states its torque gives, the mean model's
    rollout from x_1 (CasadiPPANN.rollout), where its 2 pi crossing moved (module docstring,
    "Drafts"); as it is where it did not."""
    n = len(draft.tau)

    def turns(solution: Solution) -> np.ndarray:
        return np.floor(solution.states[: n - 1, 0] / (2 * np.pi))

    if np.array_equal(turns(draft), turns(warm)):
        return draft
    return replace(draft, states=ocp.dynamics.rollout(draft.states[0], draft.tau[: n - 1]))


def exact(ocp: NominalOCP, draft: Solution) -> bool:
    """Whether `draft`'s states are its torque's own: the mean model's rollout from x_1 (with
    theta wrapped at every step) within FEASIBILITY_TOLERANCE of them at every sample. True of
    a draft that kept its warm start's turns and sits clear of the turns' edges (~1e-13 on the
    bench's models), false of one whose crossing moved (0.1-0.6 rad)."""
    n = len(draft.tau)
    own = ocp.dynamics.rollout(draft.states[0], draft.tau[: n - 1])
    return bool(np.max(np.abs(own - draft.states)) <= FEASIBILITY_TOLERANCE)


def iterate(
    model: PPANN,
    ocp: NominalOCP,
    config: OCPConfig,
    *,
    heads: FusedHeads,
    nominal: Solution,
    nominal_unc: Uncertainty,
    cap: np.ndarray,
    record: Callable[[Solution, Uncertainty, np.ndarray, bool, float], None],
    draft: bool = True,
    multipliers: bool = False,
    draft_check: Callable[[Solution, Uncertainty], float | None] | None = None,
    beside: bool | None = None,
) -> tuple[Solution, Uncertainty, float]:
    """The scheme of the module docstring from the nominal plan and its Monte-Carlo; `record`
    sees each solve, its Monte-Carlo, the margin its slider keeps, whether it was a draft and
    the k its Monte-Carlo's tightening is at.
    `draft`: whether the first solve is a draft; `multipliers`: whether it starts from
    `nominal`'s multipliers too (where `nominal` is this NLP's own solution, e.g. at another
    k: control/robust.py's `start`). `draft_check`: sees the first draft within NEAR tolerances of
    its Monte-Carlo's tightening at every sample, with that Monte-Carlo, and may answer a
    larger k: the scheme then goes on at that k from that draft, drafts first
    (control/profiles.py: its own tail checked before the returned solve). `beside`: whether that
    check runs on a thread of its own while the scheme goes on (control/beside.py; None: where
    the process has more than one core for it); the same solves, records and result either way.
    Returns the accepted solve (a full solve, or a draft whose states are its torque's own:
    `Acceptance`), its `heights` the height plus that margin (the bounds under which the
    bracketed loop's NLP has this solution), its Monte-Carlo at every sample and the k it was
    solved at.

    Raises:
      AwareError: a solve failed, a margin passed `cap`, a solve repeated an earlier one
        (`repeats`), or MAX_SOLVES passed.
    """
    aware = aware_ocp(model, ocp, samples=config.mc_samples)
    index = np.array(config.constraint_samples) - 1
    base = np.full(len(index), config.height)
    current, unc, fresh = nominal, nominal_unc, not multipliers
    # a payload: the solve, its Monte-Carlo, and whether that stops at the last constraint
    # sample (a draft's)
    acceptance: Acceptance[tuple[Solution, Uncertainty, bool]] = Acceptance(
        config.margin_tolerance, draft=draft
    )
    tolerance = config.margin_tolerance
    pending: Pending | None = None
    solves = 0

    def at_draft(solution: Solution, its: Uncertainty, k: float) -> None:
        """The scheme from the checked draft `solution` (its Monte-Carlo `its`) at the raised
        k, drafts first: the same draws at that k, so its Monte-Carlo is not drawn again."""
        nonlocal config, unc, acceptance, current, fresh
        config = replace(config, k_sigma=k)
        unc = at_k(heads, solution, its, config)
        acceptance = Acceptance(config.margin_tolerance, draft=True)
        current, fresh = solution, False

    def settle() -> bool:
        """The pending check's answer: the held solves recorded where k stays (False); where
        it is raised, they are dropped and the scheme goes back to the draft (True)."""
        nonlocal pending, solves
        assert pending is not None
        checked, pending = pending, None
        raised = checked.answer()
        if raised is not None and raised > config.k_sigma:
            solves = checked.solves
            at_draft(*checked.draft, raised)
            return True
        for held in checked.held:
            record(*held)
        return False

    with ThreadPoolExecutor(1) if draft_check and wanted(beside) else nullcontext() as pool:
        while True:
            due = pending is not None and (not acceptance.draft or solves >= MAX_SOLVES)
            if due and settle():  # a draft goes on beside the check, a full solve does not
                continue
            if solves >= MAX_SOLVES:
                raise AwareError(f"not settled in {MAX_SOLVES} solves")
            try:
                aware.freeze(current, unc)
                if solves == 0 and not aware.reachable(base + unc.population).all():
                    raise AwareError(
                        "no crank angle keeps the slider above the height with this spread"
                    )
                draft = acceptance.draft
                try:
                    solution = aware.solve(
                        base + unc.population,
                        warm=current,
                        draft=draft,
                        multipliers=not fresh,
                        bounded=acceptance.bounded,
                    )
                except OCPError as exc:
                    raise AwareError(f"solve failed: {exc}") from None
                solves += 1
                own = solution
                if draft:
                    solution = torque_states(aware, solution, warm=current)
                unc = slider_uncertainty(heads, solution, config, constraints_only=draft)
                margin = solution.slider[index] - config.height
                made = (solution, unc, margin, draft, config.k_sigma)
                if pending is None:
                    record(*made)
                else:
                    pending.held.append(made)
                if np.any(margin > cap):
                    raise AwareError("beyond the stroke share a margin may take")
                # the bounds a margin solve of this torque would have had (constraint active)
                kept = (replace(solution, heights=config.height + margin), unc, draft)
                residual = unc.tightening - margin
                final = draft and solution is own and acceptance.settled(margin, residual)
                final = final and exact(aware, solution)  # the rollout only where it decides
                moved = draft and solution is not own
                accepted = acceptance.take(margin, residual, kept, exact=final, moved=moved)
                if accepted is None and acceptance.cycling():
                    raise AwareError(f"cycling: solve {solves} repeats an earlier one, unsettled")
            except AwareError:
                if pending is not None and settle():
                    continue
                raise
            if pending is not None and settle():  # the draft beside it made: wait for it
                continue
            if accepted is not None:
                returned, its, partial = accepted
                if partial:  # a draft's: its Monte-Carlo at every sample, as a full solve's
                    its = slider_uncertainty(heads, returned, config)
                return returned, its, config.k_sigma
            current, fresh = solution, False
            if acceptance.start is not None:
                current, unc, _ = acceptance.start
            elif draft and draft_check is not None and np.all(np.abs(residual) < NEAR * tolerance):
                check, draft_check = draft_check, None
                if pool is not None:
                    pending = Pending(pool, check, (solution, unc), solves=solves)
                    continue
                raised = check(solution, unc)
                if raised is not None and raised > config.k_sigma:
                    at_draft(solution, unc, raised)
