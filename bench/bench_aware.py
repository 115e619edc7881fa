"""Experiment: the open-loop robust OCP with the slider's spread as a function of theta_k inside
the NLP, against the product's bracketed margin loop (control/robust.py), on the same models,
tasks, Monte-Carlo and acceptance, timed in the same run against the nominal solve.

    python bench/bench_aware.py --model M [--model M2 ...] [--tasks paper,height,...]
        [--repeat 3] [--surrogate 200]

Why: the product's loop solves the NLP for a margin m per constraint sample and asks its
Monte-Carlo for the tightening T(m) of the torque found; the root of T(m) - m takes a bracketed
secant of ~8 draft solves, because T falls steeply with m near top dead centre (a torque that
dwells there spreads the slider less) and jumps where the 2 pi crossing moves a sample. Most of
that dependence is one of theta_k alone: the slider is x(theta_k + e) for the drawn angle
deviations e, and near top dead centre x hardly moves with e. This scheme puts it in the NLP:

    x(theta_k) - s_k k std_i x(theta_k + e_ik) >= height + p_k

with e_ik the Monte-Carlo's angle deviations from the plan at sample k (the first `surrogate`
of them, with the transmission's angle), s_k the factor that makes the term equal the whole
Monte-Carlo's tightening less its line allowance p_k at the last solution (it carries the
sampling allowance, the other draws and, for quantile tightening, the quantile's shape), all
frozen per solve and refreshed from each solve's Monte-Carlo. The NLP then trades the cost
against where theta_k sits itself. The first solve starts from the nominal's primal point alone
(its multipliers belong to another constraint function: 15 IPOPT iterations with them, 8
without, on the seed-0 model); drafts run until every sample's residual (the Monte-Carlo's
tightening less the margin the solution keeps) is within the tolerance, then full solves until
one is, or sits on the safe side of a jump (residual <= 0 where the solve before had residual
> 0 at a margin within the tolerance): the product's acceptance, so the returned torque keeps
slider - tightening >= height - tolerance by its own Monte-Carlo, as the product's does.

Timing as bench/bench_solve.py: the loop from after the nominal's Monte-Carlo, against a cold
nominal solve, median of `repeat`.
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import dataclass, replace

import casadi as ca
import numpy as np

from control.config import OCPConfig
from control.ocp import NominalOCP, OCPError, Solution
from control.robust import RobustError, solve_robust
from control.tightening import Uncertainty, slider_uncertainty
from ppann.checkpoint import load
from ppann.model import PPANN, FusedHeads

TASKS: dict[str, dict] = {
    "paper": {},
    "height": {"height": 0.085},
    "samples": {"constraint_samples": (60, 90)},
    "horizon": {"horizon": 200, "constraint_samples": (70, 130)},
    "edge": {"height": 0.075, "constraint_samples": (40, 120)},
}
"""bench/bench_tasks.py's tasks, by a short name."""


class AwareOCP(NominalOCP):
    """The OCP with the tightening of each constraint sample a function of its theta_k: the
    Monte-Carlo's slider spread around the plan, from frozen angle deviations (module
    docstring)."""

    def __init__(self, model: PPANN, config: OCPConfig, *, surrogate: int) -> None:
        self.surrogate = surrogate
        super().__init__(model, config)

    def _slider_rows(self, x: ca.MX, index: list[int]) -> tuple[ca.MX, ca.MX]:
        n, k = self.surrogate, len(index)
        deviation, scale = ca.MX.sym("deviation", n, k), ca.MX.sym("scale", k)
        rows = []
        for j, i in enumerate(index):
            drawn = self.geometry.slider_position(x[0, i] + deviation[:, j], lib=ca)
            spread = ca.sqrt(ca.sumsqr(drawn - ca.sum1(drawn) / n) / (n - 1))
            plan = self.geometry.slider_position(x[0, i], lib=ca)
            rows.append(plan - scale[j] * self.config.k_sigma * spread)
        return ca.vertcat(*rows), ca.vertcat(ca.vec(deviation), scale)

    def freeze(self, solution: Solution, unc: Uncertainty) -> None:
        """Take the deviations and scale of `solution`'s Monte-Carlo `unc` for the next solve."""
        index = np.array(self.config.constraint_samples) - 1
        plan = solution.states[index, 0]
        deviation = unc.angles[: self.surrogate] - plan
        drawn = self.geometry.slider_position(plan + deviation)
        spread = self.config.k_sigma * drawn.std(axis=0, ddof=1)
        scale = (unc.tightening - unc.population) / spread
        self._extra = np.concatenate([deviation.T.ravel(), scale])


@dataclass(frozen=True)
class Loop:
    solution: Solution
    uncertainty: Uncertainty
    wall_time: float
    solves: int
    drafts: int
    ipopt: int


def aware_loop(model: PPANN, config: OCPConfig, ocp: AwareOCP, nominal: Solution) -> Loop:
    """The scheme of the module docstring from a solved nominal plan."""
    heads = FusedHeads(model)
    index = np.array(config.constraint_samples) - 1
    base = np.full(len(index), config.height)
    tolerance = config.margin_tolerance
    unc = slider_uncertainty(heads, nominal, config, constraints_only=True)
    started = time.perf_counter()
    # heights marked unknown: the first solve starts from the nominal's primal point alone
    current = replace(nominal, heights=np.full(len(index), -np.inf))
    draft, solves, drafts, ipopt = True, 0, 0, 0
    previous: tuple[np.ndarray, np.ndarray] | None = None
    while solves < config.max_robust_iterations:
        ocp.freeze(current, unc)
        solution = ocp.solve(base + unc.population, warm=current, draft=draft)
        solves, drafts, ipopt = solves + 1, drafts + draft, ipopt + solution.iterations
        unc = slider_uncertainty(heads, solution, config, constraints_only=draft)
        margin = solution.slider[index] - config.height
        residual = unc.tightening - margin
        near = np.abs(residual) < tolerance
        if previous is not None:
            jump = (residual <= 0) & (previous[1] > 0) & (np.abs(margin - previous[0]) < tolerance)
            near |= jump
        previous, current = (margin, residual), solution
        if near.all() and not draft:
            return Loop(solution, unc, time.perf_counter() - started, solves, drafts, ipopt)
        draft = draft and not bool(np.all(np.abs(residual) < tolerance))
    raise RobustError(f"the aware loop did not settle in {config.max_robust_iterations} solves")


def _row(model_path: str, task: str, *, repeat: int, surrogate: int) -> None:
    model, _ = load(model_path)
    config = OCPConfig(**TASKS[task])
    index = np.array(config.constraint_samples) - 1
    plain = NominalOCP(model, config)
    aware = AwareOCP(model, config, surrogate=surrogate)
    nominal_times, ref_times, aware_times = [], [], []
    for _ in range(repeat):
        started = time.perf_counter()
        nominal = plain.solve()
        nominal_times.append(time.perf_counter() - started)
        try:
            ref = solve_robust(model, config, ocp=plain, nominal=nominal)
        except RobustError as exc:
            print(f"{task:8} {model_path}: the product's loop refused: {exc}")
            return
        ref_times.append(ref.wall_time)
        try:
            loop = aware_loop(model, config, aware, nominal)
        except (RobustError, OCPError) as exc:
            print(f"{task:8} {model_path}: the aware loop failed: {exc}")
            return
        aware_times.append(loop.wall_time)
    t_nom = statistics.median(nominal_times)
    t_ref, t_aware = statistics.median(ref_times), statistics.median(aware_times)
    ref_margin = ref.robust.slider[index] - config.height
    aware_margin = loop.solution.slider[index] - config.height
    ref_drafts = sum(it.draft for it in ref.iterations)
    ref_ipopt = sum(it.ipopt_iterations for it in ref.iterations)
    print(
        f"| {task} | {t_nom * 1e3:.0f} | {t_ref * 1e3:.0f} ({ref_drafts}+"
        f"{len(ref.iterations) - ref_drafts}, {ref_ipopt}) | {t_aware * 1e3:.0f} "
        f"({loop.drafts}+{loop.solves - loop.drafts}, {loop.ipopt}) | "
        f"{t_ref / t_nom:.2f} | **{t_aware / t_nom:.2f}** | "
        f"{ref.robust.cost / nominal.cost - 1:+.2%} / "
        f"{loop.solution.cost / nominal.cost - 1:+.2%} | "
        f"{_mm(ref_margin)} / {_mm(aware_margin)} | "
        f"{_mm(ref_margin - ref.robust_uncertainty.tightening)} / "
        f"{_mm(aware_margin - loop.uncertainty.tightening)} |",
        flush=True,
    )


def _mm(values: np.ndarray) -> str:
    return ", ".join(f"{1e3 * v:.2f}" for v in values)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", action="append", required=True, help="PPANN checkpoint(s)")
    parser.add_argument("--tasks", default=",".join(TASKS), help=f"of {', '.join(TASKS)}")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--surrogate", type=int, default=200, help="deviations in the NLP")
    args = parser.parse_args()
    tasks = [t.strip() for t in args.tasks.split(",")]
    unknown = [t for t in tasks if t not in TASKS]
    if unknown:
        parser.error(f"unknown task(s) {', '.join(unknown)}; known: {', '.join(TASKS)}")
    print(
        "| task | nominal ms | product loop ms (drafts+full, IPOPT it.) | aware loop ms | "
        "ratio, product | ratio, aware | premium, product / aware | margins mm | "
        "slack (margin - tightening) mm |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for path in args.model:
        print(f"| {path} | | | | | | | | |", flush=True)
        for task in tasks:
            _row(path, task, repeat=args.repeat, surrogate=args.surrogate)


if __name__ == "__main__":
    main()
