"""docs/trapezoid_tasks.png: the four tasks nobody tuned on training seeds 0-4, the trapezoid
default (seeds 0-1 from bench/trapezoid_rows_tasks.csv, root 20261263; seeds 2-4 from
bench/trapezoid_rest_tasks.csv, root 20261268) beside the Euler default of session 84
(bench/default_today_tasks.csv, root 20261252): per task a column, held-out machines below of
1000 with the exact 95 % bound, the cost premium, and predicted / observed σ of the slider at
the task's two constraint samples.

    python bench/trapezoid_tasks_figure.py --out docs/trapezoid_tasks.png
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from bench_tasks import TASKS as BENCH_TASKS  # the script's folder is on the path

from common.figures import save_figure
from control.config import OCPConfig
from replay.rates import rate_upper

BENCH = Path(__file__).resolve().parent
# the sweep's case name (bench_tasks' task name) -> its constraint samples; the paper task (no
# options) is not a case of the tasks' sweep
TASKS = {
    name: OCPConfig(**options).constraint_samples
    for name, options in BENCH_TASKS.items()
    if options
}


def read(*paths: Path) -> dict[tuple[str, int], dict[str, float]]:
    """(case, seed) -> the robust row's figures, from sweep tables."""
    rows = {}
    for path in paths:
        for row in csv.DictReader(path.open()):
            if row["profile"] != "robust":
                continue
            runs = int(row["heldout_runs"])
            early, late = TASKS[row["case"]]
            rows[row["case"], int(row["seed"])] = {
                "below": round(float(row["robust_heldout_rate"]) * runs),
                "runs": runs,
                "premium": 100 * float(row["premium"]),
                "early": float(row[f"ratio_{early}"]),
                "late": float(row[f"ratio_{late}"]),
            }
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    lanes = (
        ("Euler, session 84 (root 20261252)", "tab:grey", read(BENCH / "default_today_tasks.csv")),
        (
            "trapezoid, sessions 89-90 (roots 20261263, 20261268)",
            "tab:blue",
            read(BENCH / "trapezoid_rows_tasks.csv", BENCH / "trapezoid_rest_tasks.csv"),
        ),
    )
    fig, axes = plt.subplots(3, len(TASKS), figsize=(13, 8.5), sharex=True, sharey="row")
    for column, (case, (early, late)) in enumerate(TASKS.items()):
        top, middle, bottom = axes[:, column]
        for i, (label, colour, rows) in enumerate(lanes):
            seeds = sorted(s for c, s in rows if c == case)
            at = [s + (i - 0.5) * 0.3 for s in seeds]
            got = [rows[case, s] for s in seeds]
            top.plot(
                at,
                [100 * g["below"] / g["runs"] for g in got],
                "o",
                color=colour,
                label=f"{label}: rate",
            )
            top.plot(
                at,
                [100 * rate_upper(g["below"], g["runs"]) for g in got],
                "_",
                color=colour,
                ms=10,
                mew=2,
                label="its 95 % upper bound",
            )
            middle.plot(at, [g["premium"] for g in got], "o", color=colour, label=label)
            bottom.plot(
                at,
                [g["early"] for g in got],
                "o",
                color=colour,
                label=f"{label.split(',')[0]}, sample {early} (o)",
            )
            bottom.plot(
                at,
                [g["late"] for g in got],
                "s",
                color=colour,
                mfc="none",
                label=f"{label.split(',')[0]}, sample {late} (□)",
            )
        top.axhline(0.5, color="tab:red", ls="--", lw=1, label="target 0.5 %")
        top.set_title(f"{case}\n(constraint samples {early}, {late})", fontsize=9)
        bottom.axhspan(0.8, 1.25, color="0.9")
        bottom.axhline(1.0, color="0.4", lw=0.8)
        bottom.set_xlabel("training seed")
        bottom.set_xticks(range(5))
        bottom.legend(fontsize=6, loc="lower right")
    axes[0, 0].set_ylabel("held-out machines below, %")
    axes[0, 0].set_ylim(0, 0.8)
    axes[1, 0].set_ylabel("robust cost premium, %")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=5, fontsize=8)
    axes[2, 0].set_ylabel("predicted / observed σ of the slider\n(grey band 0.8-1.25)")
    fig.suptitle(
        "The four tasks nobody tuned, 1000 held-out machines per torque: the trapezoid default "
        "beside the Euler default\n(bench/trapezoid_rows.md, bench/trapezoid_rows_rest.md)"
    )
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    save_figure(fig, args.out)


if __name__ == "__main__":
    main()
