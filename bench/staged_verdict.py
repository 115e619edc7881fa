"""What the held-out verdict can confirm, one look against two stages (replay/staged.py):
P("holds") and the machines played on average, against the torque's true rate below the height.

Exact binomial arithmetic, no simulation: each line is the design's own operating curve. The
reference is one look on the same first stage (crank run's 1000 machines before session 93).

    python bench/staged_verdict.py [--figure bench/staged_verdict.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from scipy import stats as scistats

from replay.rates import SECOND_STAGE, TARGET_RATE
from replay.staged import StagedDesign, design, holds_probability, most_within

FIRST = 1000
LEVEL = float(scistats.norm.cdf(-3.0))
RATES = (0.0, 0.0001, 0.00025, 0.0005, LEVEL, 0.002, 0.003, 0.004, TARGET_RATE, 0.007, 0.01)


def expected_machines(plan: StagedDesign, rate: float) -> float:
    """Machines played on average: the second stage's only where the first did not decide."""
    if len(plan.stages) == 1:
        return float(plan.stages[0])
    a, most = plan.thresholds[0], most_within(plan.stages[0], plan.target)
    undecided = scistats.binom.cdf(most, FIRST, rate) - scistats.binom.cdf(a, FIRST, rate)
    return plan.stages[0] + (plan.stages[1] - plan.stages[0]) * float(undecided)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--figure", type=Path, default=None)
    args = parser.parse_args()
    plans = {
        f"one look, {FIRST}": design((FIRST,)),
        f"one look, {FIRST + SECOND_STAGE}": design((FIRST + SECOND_STAGE,)),
        f"staged, {FIRST} then {SECOND_STAGE} more": design((FIRST, FIRST + SECOND_STAGE)),
    }
    for name, plan in plans.items():
        print(
            f"{name}: thresholds {plan.thresholds}, P(holds | {100 * plan.target:g} %) = "
            f"{plan.error:.4f}"
        )
    print()
    print("| true rate % | " + " | ".join(f"P(holds) {n}" for n in plans) + " | machines, staged |")
    print("|---" * (len(plans) + 2) + "|")
    staged = plans[f"staged, {FIRST} then {SECOND_STAGE} more"]
    for rate in RATES:
        held = " | ".join(f"{holds_probability(p, rate):.3f}" for p in plans.values())
        mark = " (Φ(−3))" if rate == LEVEL else ""
        print(f"| {100 * rate:.3f}{mark} | {held} | {expected_machines(staged, rate):.0f} |")
    if args.figure is not None:
        _figure(args.figure, plans, staged)
        print(f"\nwrote {args.figure}")


def _figure(path: Path, plans: dict[str, StagedDesign], staged: StagedDesign) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    rates = np.linspace(0.0, 0.008, 161)
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    for name, plan in plans.items():
        left.plot(100 * rates, [holds_probability(plan, r) for r in rates], label=name)
    for ax in (left, right):
        ax.axvline(100 * LEVEL, color="grey", ls=":", lw=1)
        ax.axvline(100 * TARGET_RATE, color="k", ls="--", lw=1)
        ax.set_xlabel("the torque's true rate below the height, %")
        ax.grid(alpha=0.3)
    left.axhline(0.05, color="k", lw=0.6)
    left.text(100 * LEVEL, 0.25, " Φ(−3), the 3σ level", color="grey", rotation=90, va="center")
    left.text(0.62, 0.07, "5 % risk", fontsize=8)
    left.text(100 * TARGET_RATE, 0.5, " target 0.5 %", rotation=90, va="center")
    left.set_ylabel('P(the check says "holds")')
    left.set_title("what the held-out verdict confirms")
    left.legend(loc="upper right", fontsize=8)
    right.plot(100 * rates, [expected_machines(staged, r) for r in rates], color="C2")
    right.set_ylabel("machines played on average")
    right.set_title(
        f"what the staged check costs ({staged.stages[0]} then up to {staged.stages[1]})"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
