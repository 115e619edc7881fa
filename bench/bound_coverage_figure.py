"""docs/bound_coverage.png: how often each of the line's bounds missed, per model, from the JSONs
`bench/bound_coverage.py --out` wrote (bench/bound_coverage_*.json; bench/bound_coverage.md).

    python bench/bound_coverage_figure.py
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

HERE = Path(__file__).parent
MODELS = (
    ("round0", "round 0\n70 alike"),
    ("lab9", "lab 8 × 9\n8 alike"),
    ("final", "final, 310:\n70 long, 240 short"),
    ("m8", "8 of the\nfinal's, unalike"),
)
BOUNDS = (
    (
        "phase 2.mean exact, likelihood se, about pooled",
        "line mean, before (likelihood's covariance)",
    ),
    ("phase 2.mean exact, pooled se, about pooled", "line mean, now (pooled covariance)"),
    ("phase 2.spread exact", "spread, exact level"),
)
MISS = 0.05 / 3


def main() -> None:
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.6), sharey=True)
    for axis, component in zip(axes, range(3), strict=True):
        for j, (key, label) in enumerate(BOUNDS):
            xs, ys, errs = [], [], []
            for i, (name, _) in enumerate(MODELS):
                data = json.loads((HERE / f"bound_coverage_{name}.json").read_text())
                rate = data["rates"][key][component]
                lines = data["lines"] * (2 if key.split(".")[1].startswith("mean") else 1)
                xs.append(i + (j - 1) * 0.26)
                ys.append(100 * rate)
                errs.append(200 * math.sqrt(rate * (1 - rate) / lines))
            axis.bar(xs, ys, width=0.24, label=label, color=f"C{j}")
            axis.errorbar(xs, ys, yerr=errs, fmt="none", ecolor="k", lw=0.8, capsize=2)
        axis.axhline(100 * MISS, color="k", ls="--", lw=1, label="what each bound stands for")
        axis.set_title(("inertia J", "damping B", "stiffness K")[component])
        axis.set_xticks(range(len(MODELS)), [m[1] for m in MODELS], fontsize=8)
    axes[0].set_ylabel("lines the bound missed, % (confidence 0.95)")
    axes[0].legend(fontsize=7, loc="upper left")
    fig.suptitle(
        "How often the line's bounds missed, through phase 2's own fit (simulated lines; "
        "whiskers: ±2 binomial se of each rate)",
        fontsize=10,
    )
    fig.tight_layout()
    out = HERE.parent / "docs" / "bound_coverage.png"
    fig.savefig(out, dpi=110)
    print(out)


if __name__ == "__main__":
    main()
