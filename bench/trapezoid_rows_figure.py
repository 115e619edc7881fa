"""docs/trapezoid_seeds.png: the paper task's robust torque on training seeds 0-9, the trapezoid
default (seeds 0-4 from bench/trapezoid.log, root 20261260; seeds 5-9 from
bench/trapezoid_rows.csv, root 20261261) beside the Euler default of session 84
(bench/default_today.csv, root 20261250): held-out machines below with the exact 95 % bound,
the cost premium, predicted / observed σ of the slider at samples 50 and 100.

    python bench/trapezoid_rows_figure.py --out docs/trapezoid_seeds.png
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from common.figures import save_figure
from replay.rates import rate_upper

BENCH = Path(__file__).resolve().parent

Rows = dict[int, dict[str, float]]
"""Per training seed, its robust row: below, runs, premium, ratio_50, ratio_100."""


def from_csv(path: Path) -> Rows:
    """Per seed, the robust row of a sweep's table."""
    rows = {}
    for row in csv.DictReader(path.open()):
        if row["profile"] != "robust":
            continue
        runs = int(row["heldout_runs"])
        rows[int(row["seed"])] = {
            "below": round(float(row["robust_heldout_rate"]) * runs),
            "runs": runs,
            "premium": 100 * float(row["premium"]),
            "ratio_50": float(row["ratio_50"]),
            "ratio_100": float(row["ratio_100"]),
        }
    return rows


def from_log(path: Path, lane: str) -> Rows:
    """Per seed, the `robust` line of bench/trapezoid_read.py's block for `lane` in its log."""
    rows, inside = {}, False
    for line in path.read_text().splitlines():
        if line and not line.startswith((" ", "seed")):  # a lane's title, or what follows
            inside = line.startswith(lane)
        fields = line.split()
        if inside and len(fields) > 8 and fields[1] == "robust":
            below, runs = (int(n) for n in fields[2].split("/"))
            r50, r100 = (float(r) for r in fields[8].split("/"))
            rows[int(fields[0])] = {
                "below": below,
                "runs": runs,
                "premium": float(fields[7].rstrip("%")),
                "ratio_50": r50,
                "ratio_100": r100,
            }
    if not rows:
        raise SystemExit(f"trapezoid_rows_figure.py: no robust row of {lane!r} in {path}")
    return rows


def draw(lanes: list[tuple[str, str, Rows]], *, title: str, out: str) -> None:
    """Per seed and lane (label, colour, rows): the rate below with its bound, the premium and
    the σ ratios, the lanes side by side at each seed."""
    fig, (top, middle, bottom) = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
    width = 0.6 / len(lanes)
    for i, (label, colour, rows) in enumerate(lanes):
        seeds = sorted(rows)
        at = [s + (i - (len(lanes) - 1) / 2) * width for s in seeds]
        rate = [100 * rows[s]["below"] / rows[s]["runs"] for s in seeds]
        bound = [100 * rate_upper(rows[s]["below"], rows[s]["runs"]) for s in seeds]
        top.plot(at, rate, "o", color=colour, label=f"{label}: rate")
        top.plot(at, bound, "_", color=colour, ms=12, mew=2, label="its 95 % upper bound")
        middle.plot(at, [rows[s]["premium"] for s in seeds], "o", color=colour, label=label)
        for sample, marker in (("50", "o"), ("100", "s")):
            ratio = [rows[s][f"ratio_{sample}"] for s in seeds]
            bottom.plot(at, ratio, marker, color=colour, label=f"{label.split(',')[0]}, {sample}")
    top.axhline(0.5, color="tab:red", ls="--", lw=1, label="target 0.5 %")
    top.set_ylabel("held-out machines below, %")
    top.set_ylim(0, 0.75)
    top.legend(fontsize=7, ncol=2, loc="upper left")
    middle.set_ylabel("robust cost premium, %")
    middle.legend(fontsize=7)
    bottom.axhspan(0.8, 1.25, color="0.9", label="0.8-1.25")
    bottom.axhline(1.0, color="0.4", lw=0.8)
    bottom.set_ylabel("predicted / observed σ,\nslider at sample 50 (o), 100 (□)")
    bottom.set_xlabel("training seed")
    bottom.set_xticks(range(10))
    bottom.legend(fontsize=7, ncol=3)
    fig.suptitle(title)
    fig.tight_layout()
    save_figure(fig, out)


def trapezoid_rows() -> Rows:
    """The trapezoid default's seeds 0-9 (sessions 88-89)."""
    return from_log(BENCH / "trapezoid.log", "trapezoid") | from_csv(BENCH / "trapezoid_rows.csv")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    lanes = [
        ("Euler, session 84 (root 20261250)", "tab:grey", from_csv(BENCH / "default_today.csv")),
        ("trapezoid, sessions 88-89 (roots 20261260-1)", "tab:blue", trapezoid_rows()),
    ]
    draw(
        lanes,
        title="The paper task's robust torque, 4000 held-out machines per seed:\n"
        "the trapezoid default beside the Euler default (bench/trapezoid_rows.md)",
        out=args.out,
    )


if __name__ == "__main__":
    main()
