"""docs/trapezoid.png: bench/trapezoid.md's two lanes per seed — held-out machines below per
profile, and the model's mean motor angle less the twin's at the constraint samples.

    python bench/trapezoid_figure.py EULER_STUDY TRAPEZOID_STUDY --out docs/trapezoid.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from trapezoid_read import PROFILES, count, lane

from common.figures import save_figure

LANES = (("Euler (eq. 4)", "tab:grey"), ("trapezoid", "tab:blue"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("euler", type=Path)
    parser.add_argument("trapezoid", type=Path)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    lanes = [lane(args.euler), lane(args.trapezoid)]
    seeds = sorted({s for s, _ in lanes[0]} & {s for s, _ in lanes[1]})
    if not seeds:
        raise SystemExit("trapezoid_figure.py: no seed finished in both lanes")
    fig, axes = plt.subplots(2, 3, figsize=(13, 6.5), sharex=True)
    width = 0.38
    for col, profile in enumerate(PROFILES):
        top, bottom = axes[0, col], axes[1, col]
        for i, ((label, colour), rows) in enumerate(zip(LANES, lanes, strict=True)):
            at = [s + (i - 0.5) * width for s in seeds]
            below = [count(rows[(s, profile)]) for s in seeds]
            top.bar(at, below, width, color=colour, label=label)
            for x, b in zip(at, below, strict=True):  # the count, a zero too
                top.text(x, b + 0.3, str(b), ha="center", va="bottom", fontsize=8, color=colour)
            runs = rows[(seeds[0], profile)]["heldout_runs"]
            for sample, marker in (("50", "o"), ("100", "s")):
                offset = [rows[(s, profile)]["samples"][sample]["theta_offset_mrad"] for s in seeds]
                bottom.plot(at, offset, marker, color=colour, label=f"{label}, sample {sample}")
        top.axhline(0.005 * runs, color="tab:red", lw=1, ls="--", label="0.5 %")
        top.set_title(f"{profile} ({'open loop' if profile == 'robust' else 'its own loop'})")
        top.set_ylabel(f"held-out machines below, of {runs}")
        bottom.axhline(0, color="0.5", lw=0.8)
        bottom.set_ylabel("model − twin mean θ, mrad")
        bottom.set_xlabel("training seed")
        bottom.set_xticks(seeds)
    axes[0, 0].legend(fontsize=8)
    axes[1, 0].legend(fontsize=7)
    fig.suptitle(
        "The model's angle update on held-out machines (bench/trapezoid.md): machines below (top),"
        "\nand the model's mean motor angle less the twin's at samples 50 (o) and 100 (□) (bottom)"
    )
    fig.tight_layout()
    save_figure(fig, args.out)


if __name__ == "__main__":
    main()
