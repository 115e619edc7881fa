"""bench/beside_ab.py's logs as a figure: per model, each Monte-Carlo seed's ratio (as `crank
solve` decides, over the nominal solve) with the draft's check in line and beside the loop, the
two joined by a line (the same pair, the same process).

    python bench/beside_figure.py --out docs/beside.png bench/beside_ab.log \
        bench/beside_ab_seeds_5_9.log [--names "training seed 0,..."]
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from matplotlib.figure import Figure

PAIR = re.compile(r"^seed (\d+): in line ([0-9.]+) .*, beside ([0-9.]+) ")


def read(paths: list[str]) -> dict[str, list[tuple[int, float, float]]]:
    """Per model (its checkpoint's folder name), (seed, in line, beside) for every pair."""
    found: dict[str, list[tuple[int, float, float]]] = {}
    for path in paths:
        model = None
        for line in Path(path).read_text().splitlines():
            if line.startswith("== "):
                model = Path(line[3:]).parent.name
                found.setdefault(model, [])
            elif model is not None and (m := PAIR.match(line)):
                found[model].append((int(m[1]), float(m[2]), float(m[3])))
    if not any(found.values()):
        raise SystemExit("beside_figure.py: no pair lines in the logs given")
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("logs", nargs="+")
    parser.add_argument("--out", required=True)
    parser.add_argument("--names", default=None, help="the models' names, comma-separated")
    args = parser.parse_args()
    found = read(args.logs)
    names = [f"model {m}" for m in found] if args.names is None else args.names.split(",")
    if len(names) != len(found):
        parser.exit(2, f"beside_figure.py: {len(found)} models, {len(names)} --names\n")
    figure = Figure(figsize=(9, 4.5))
    axes = figure.subplots()
    for i, pairs in enumerate(found.values()):
        for seed, line, side in pairs:
            x = i + (seed - 4.5) * 0.06
            colour = "tab:green" if side < line else "tab:red"
            axes.plot([x, x], [line, side], color=colour, alpha=0.6, lw=1.2)
            axes.plot(x, line, "o", color="tab:blue", ms=4)
            axes.plot(x, side, "o", color="tab:orange", ms=4)
    axes.plot([], [], "o", color="tab:blue", label="the draft's check in line")
    axes.plot([], [], "o", color="tab:orange", label="beside the loop (one draft)")
    axes.axhline(3, color="k", ls="--", lw=1, label="target 3")
    axes.set_xticks(range(len(found)), names)
    axes.set_ylabel("as crank solve decides / nominal solve")
    axes.set_xlabel("one pair of dots per Monte-Carlo seed (0-9, left to right), the same process")
    axes.legend(loc="upper right", fontsize=8)
    figure.tight_layout()
    figure.savefig(args.out, dpi=110)


if __name__ == "__main__":
    main()
