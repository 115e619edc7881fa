"""docs/random_tasks.png: the robust torque of each task drawn by bench/random_tasks.py (its sweep's
sweep.csv, bench/random_tasks.csv): held-out machines below with the exact 95 % bound against
0.5 %, the cost premium over the nominal torque, and predicted / observed σ of the slider at each
of the task's constraint samples against issue 11's 0.8-1.25.

    python bench/random_tasks_figure.py --csv bench/random_tasks.csv --out docs/random_tasks.png
"""

from __future__ import annotations

import argparse
import csv
import re
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from random_tasks import task_index, task_of  # the script's folder is on the path

TARGET = 0.005
BAND = (0.8, 1.25)


def _number(text: str | None) -> float:
    return float(text) if text not in (None, "") else float("nan")


def read(path: Path) -> list[tuple[str, dict | None, bool]]:
    """Per task drawn, in task order (a case named "task i: ..."): its case, the row of the
    torque it ended with (the open-loop `robust`, or the fallback tube where that was refused;
    None where no torque came out) and whether the open loop was refused."""
    with path.open() as handle:
        rows = list(csv.DictReader(handle))
    cases = sorted({r["case"] for r in rows}, key=task_index)
    out = []
    for case in cases:
        mine = [r for r in rows if r["case"] == case]
        refused = any(r["profile"] == "robust" and r["error"] for r in mine)
        torque = next((r for r in mine if not r["error"]), None)
        out.append((case, torque, refused))
    return out


def _label(case: str) -> str:
    """ "task 3: horizon 213, samples 68, height 0.0751" as three short lines."""
    i, task = task_of(case)
    samples = ", ".join(str(k) for k in task["constraint_samples"])
    return f"task {i}\nN {task['horizon']}, h {task['height']}\nat {samples}"


def draw(tasks: list[tuple[str, dict | None, bool]], *, out: Path) -> None:
    """The three panels, one column of marks per task."""
    fig = Figure(figsize=(11, 9), layout="constrained")
    rate, premium, ratio = fig.subplots(3, 1, sharex=True)
    x = np.arange(len(tasks))
    labels = [_label(case) for case, _, _ in tasks]
    for i, (_, row, refused) in enumerate(tasks):
        if row is None:
            for axes in (rate, premium, ratio):
                axes.annotate(
                    "no torque",
                    (i, 0.5),
                    xycoords=("data", "axes fraction"),
                    ha="center",
                    color="tab:red",
                )
            continue
        color, marker = ("tab:green", "s") if refused else ("tab:orange", "o")
        value, upper = _number(row["robust_heldout_rate"]), _number(row["robust_heldout_upper_95"])
        rate.errorbar(
            i, 100 * value, yerr=[[0], [100 * (upper - value)]], fmt=marker, color=color, capsize=4
        )
        rate.annotate(
            f"{round(value * int(row['heldout_runs']))} of {row['heldout_runs']}",
            (i, 100 * value),
            textcoords="offset points",
            xytext=(6, 0),
            ha="left",
            va="center",
            fontsize=8,
        )
        premium.plot(i, 100 * _number(row["premium"]), marker, color=color)
        ks = sorted(
            int(k[len("ratio_") :])
            for k in row
            if re.fullmatch(r"ratio_\d+", k) and row[k] not in (None, "")
        )
        for j, k in enumerate(ks):
            at = i + 0.12 * (j - (len(ks) - 1) / 2)
            mid = _number(row[f"ratio_{k}"])
            low, high = _number(row.get(f"ratio_{k}_low")), _number(row.get(f"ratio_{k}_high"))
            ratio.errorbar(
                at, mid, yerr=[[mid - low], [high - mid]], fmt=marker, color=color, capsize=3
            )
            ratio.annotate(
                str(k),
                (at, high),
                textcoords="offset points",
                xytext=(0, 3),
                ha="center",
                fontsize=7,
            )
    rate.axhline(100 * TARGET, color="tab:red", ls="--", label="target: 0.5 %")
    rate.plot([], [], "o", color="tab:orange", label="open-loop robust")
    rate.plot([], [], "s", color="tab:green", label="robust-fb tube (the open loop refused)")
    rate.set_ylabel("held-out machines below\n(%, with the exact 95 % bound)")
    top = max([100 * TARGET, *rate.get_ylim()[1:]])
    rate.set_ylim(0, 1.45 * top)  # the legend above the target's line
    rate.legend(loc="upper center", ncols=3, fontsize=8)
    premium.set_ylabel("cost premium over\nthe nominal torque (%)")
    premium.set_ylim(bottom=0)
    for edge in BAND:
        ratio.axhline(edge, color="grey", ls=":")
    ratio.axhline(1.0, color="grey", lw=0.5)
    ratio.set_ylabel("predicted / observed σ\nof the slider (each sample)")
    ratio.set_xticks(x, labels, fontsize=8)
    ratio.set_xlim(-0.5, len(tasks) - 0.2)  # room for the last count
    fig.suptitle(
        "Tasks drawn by a seed (root 20261284), each on its own training seed: the "
        "shipped default's robust torque\non held-out machines of root 20261285 "
        "(bench/random_tasks.md)"
    )
    fig.savefig(out, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--csv", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    draw(read(args.csv), out=args.out)


if __name__ == "__main__":
    main()
