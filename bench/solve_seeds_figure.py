"""The robust loop's ratio per model and Monte-Carlo seed, from bench/bench_solve.py's output
(its "the default on Monte-Carlo seeds" section), one colour per labelled set of runs.

    python bench/solve_seeds_figure.py --out docs/bench_solve_seeds.png \
        "session 27's code=b27_*.log" "today's=b28_*.log" [--names "seed 0,seed 1,..."] \
        [--decided]

Each glob is one set (logs of one or more models each, one after the other); the models are
those of the first set, in its order, named by the folder of their "model:" lines or by
--names, and matched by that line in the other sets. --decided: the ratio as `crank solve`
decides (the own-tail checks and raises included), not the loop's alone.
"""

from __future__ import annotations

import argparse
import glob
import re
import statistics
from pathlib import Path

from matplotlib.figure import Figure

SEED = re.compile(r"^seed \d+: .*, ratio ([0-9.]+)")
DECIDED = re.compile(r"^seed \d+: .*; as crank solve decides it ([0-9.]+)")


def read(path: str, *, decided: bool = False) -> list[tuple[str, list[float]]]:
    """Each model's folder and its ratio per Monte-Carlo seed, in the order of the log."""
    pattern = DECIDED if decided else SEED
    found: list[tuple[str, list[float]]] = []
    for line in Path(path).read_text().splitlines():
        if line.startswith("model:"):
            model = line.split("model:")[1].strip()
            found.append((Path(model).parent.name or model, []))
        elif found and (m := pattern.match(line)):
            found[-1][1].append(float(m[1]))
    if not any(rows for _, rows in found):
        raise SystemExit(f"solve_seeds_figure: {path} has no Monte-Carlo seed section")
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sets", nargs="+", help="LABEL=GLOB, one per set of runs")
    parser.add_argument("--out", required=True)
    parser.add_argument("--names", default="", help="display names of the models, comma-separated")
    parser.add_argument("--decided", action="store_true", help="as crank solve decides")
    args = parser.parse_args()
    sets = []
    for spec in args.sets:
        label, _, pattern = spec.partition("=")
        logs = sorted(glob.glob(pattern))
        if not logs:
            raise SystemExit(f"solve_seeds_figure: no log matches {pattern!r}")
        sets.append((label, {m: r for log in logs for m, r in read(log, decided=args.decided)}))
    models = list(sets[0][1])
    names = args.names.split(",") if args.names else models
    if len(names) != len(models):
        raise SystemExit(f"solve_seeds_figure: {len(names)} names for {len(models)} models")
    fig = Figure(figsize=(8, 4.2), layout="constrained")
    ax = fig.add_subplot()
    width = 0.8 / len(sets)
    for k, (label, runs) in enumerate(sets):
        for i, model in enumerate(models):
            x = i + (k - (len(sets) - 1) / 2) * width
            ratios = runs[model]
            ax.scatter([x] * len(ratios), ratios, color=f"C{k}", s=22, label=None if i else label)
            ax.hlines(statistics.median(ratios), x - width / 3, x + width / 3, color=f"C{k}")
    ax.axhline(3.0, color="k", ls="--", lw=1, label="target 3")
    ax.set_xticks(range(len(names)), names, fontsize=8)
    ax.set_xlabel("model (one dot per Monte-Carlo seed, a bar at the median)", fontsize=9)
    what = "as crank solve decides" if args.decided else "robust loop"
    ax.set_ylabel(f"{what} / nominal solve")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8)
    fig.savefig(args.out, dpi=110)


if __name__ == "__main__":
    main()
