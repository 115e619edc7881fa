"""docs/calibrated_coverage.png: how often the calibrated bounds (ppann/inversion.py, the default
for 2-32 machines) and the exact levels missed on the same simulated lines, per mix of
machines, from the rows of bench/calibrated_coverage.py (bench/calibrated_coverage.md).

    python bench/calibrated_coverage_figure.py
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib
import numpy as np
from calibrated_coverage import read_rows

matplotlib.use("Agg")
import matplotlib.pyplot as plt

HERE = Path(__file__).parent
MIXES = (
    ((("m2",),), "2 machines\n1 short, 1 long"),
    ((("m3",), ("m3b",)), "3 machines\n1 short, 2 long\n(two seeds)"),
    ((("m5",),), "5 machines\n3 short, 2 long"),
    ((("m8", "m8_again"),), "8 machines, unalike\n(today's rule)"),
)
"""Each mix's runs, pooled (their lines are different lines), each run's row files (a later
file's line replaces an earlier one's), and its label."""
BOUNDS = (
    ("spread_miss", "spread, calibrated", 1),
    ("exact_spread_miss", "spread, exact level", 1),
    ("mean_miss", "line mean, calibrated", 2),
    ("exact_mean_miss", "line mean, exact level", 2),
)
"""Row key, label, and how many chances a line has to miss (the mean: either side)."""
MISS = 0.05 / 3


def rates(runs: tuple[tuple[str, ...], ...], key: str, chances: int) -> tuple[np.ndarray, int]:
    """The miss rate of each component (3,) over the mix's lines, and their count."""
    pooled = [
        row
        for files in runs
        for row in read_rows([HERE / f"calibrated_coverage_{f}.jsonl" for f in files]).values()
    ]
    misses = np.sum([r[key] for r in pooled], axis=0)
    return misses / (chances * len(pooled)), len(pooled)


def main() -> None:
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.8), sharey=True)
    width = 0.2
    for component, axis in enumerate(axes):
        for j, (key, label, chances) in enumerate(BOUNDS):
            xs, ys = [], []
            for i, (runs, _) in enumerate(MIXES):
                rate, _ = rates(runs, key, chances)
                xs.append(i + (j - 1.5) * width)
                ys.append(100 * rate[component])
            hatch = "//" if "exact" in key else None
            color = f"C{j // 2}"
            axis.bar(xs, ys, width=0.9 * width, label=label, color=color, hatch=hatch, alpha=0.85)
        axis.axhline(100 * MISS, color="k", ls="--", lw=1, label="what each bound stands for")
        bar = 100 * (MISS + 2 * math.sqrt(MISS * (1 - MISS) / 800))
        axis.axhline(bar, color="0.5", ls=":", lw=1, label="the rule's bar at 800 lines")
        axis.set_title(("inertia J", "damping B", "stiffness K")[component])
        axis.set_xticks(range(len(MIXES)), [m[1] for m in MIXES], fontsize=8)
    axes[0].set_ylabel("lines the bound missed, % (confidence 0.95)")
    axes[0].legend(fontsize=7, loc="upper left")
    fig.suptitle(
        "The line's bounds calibrated by simulation against the exact levels, on the same "
        "simulated lines (800-1609 a mix; one short-run machine is one seen through the plan "
        "round; no bar: no line missed)",
        fontsize=10,
    )
    fig.tight_layout()
    out = HERE.parent / "docs" / "calibrated_coverage.png"
    fig.savefig(out, dpi=110)
    print(out)


if __name__ == "__main__":
    main()
