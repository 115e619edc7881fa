"""bench/pair_today.md as a figure: per training seed, today's defaults beside the pair
(`mean_wrap` + the plan round) on the same held-out machines: the robust torque's rate below the
height with its 95 % bound, its cost premium, and predicted / observed σ of the slider (the
OCP's Monte-Carlo mode) at each constraint sample with its interval against 0.8-1.25.

    python bench/pair_today_figure.py --defaults /work/r60/def/seed-{0..4} \
        --pair /work/r60/pair --out docs/pair_today.png

Each --defaults folder holds the ocp.json and heldout.json of one seed (its seed is read from
ocp.json's Monte-Carlo seed, the chain's training seed); --pair is a `crank sweep` folder whose
sweep.csv names each seed's leaf and solve.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

from matplotlib.figure import Figure

TARGET = 0.5  # %, a robust profile's allowed rate below the height
BAND = (0.8, 1.25)  # issue 11's σ row
REFUSED = "refused"  # a sweep row whose robust profile has no torque


def entry(heldout: Path, ocp: Path) -> dict:
    """The robust open-loop torque's figures from a heldout.json and its ocp.json."""
    h = json.loads(heldout.read_text())
    o = json.loads(ocp.read_text())
    e = h["profiles"]["robust"]["open"]
    ratios = {
        k: (s["predicted"]["mixed"]["ratio"], s["predicted"]["mixed"]["ratio_ci95"])
        for k, s in e["samples"].items()
    }
    premium = 100 * (o["robust"]["cost"] / o["nominal"]["cost"] - 1)
    return {
        "rate": 100 * e["rate"],
        "upper": 100 * e["rate_upper_95"],
        "below": e["violating_runs"],
        "runs": h["runs"],
        "premium": premium,
        "ratios": ratios,
    }


def read_defaults(folders: list[str]) -> dict[int, dict]:
    found = {}
    for folder in map(Path, folders):
        seed = json.loads((folder / "ocp.json").read_text())["config"]["mc_seed"]
        found[int(seed)] = entry(folder / "heldout.json", folder / "ocp.json")
    return found


def read_sweep(sweep: Path) -> dict[tuple[str, int], dict | str]:
    """(case, seed) -> a `crank sweep` folder's robust open-loop torque's figures, or REFUSED."""
    found: dict[tuple[str, int], dict | str] = {}
    with (sweep / "sweep.csv").open() as f:
        for row in csv.DictReader(f):
            if row["profile"] != "robust":
                continue
            key = (row["case"], int(row["seed"]))
            if row["error"]:
                found[key] = REFUSED
                continue
            leaf, solve = sweep / "leaf" / row["leaf_key"], sweep / "solve" / row["solve_key"]
            found[key] = entry(leaf / "heldout.json", solve / "ocp.json")
    return found


def draw_rates(ax, xs: list[float], rows: list[dict], *, colour: str, label: str) -> None:
    """Each torque's rate below the height (dot) and its 95 % bound (bar) with the count over it."""
    ax.scatter(xs, [r["rate"] for r in rows], color=colour, label=label, zorder=3)
    ax.scatter(xs, [r["upper"] for r in rows], marker="_", s=300, color=colour)
    for x, r in zip(xs, rows, strict=True):
        ax.annotate(
            f"{r['below']}",
            (x, r["upper"]),
            textcoords="offset points",
            xytext=(0, 5),
            ha="center",
            fontsize=8,
        )


def read_pair(sweep: Path) -> dict[int, dict]:
    return {seed: e for (_, seed), e in read_sweep(sweep).items() if e != REFUSED}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--defaults", nargs="+", required=True)
    parser.add_argument("--pair", required=True)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    series = {
        "today's defaults": read_defaults(args.defaults),
        "the pair": read_pair(Path(args.pair)),
    }
    seeds = sorted(set.union(*(set(s) for s in series.values())))
    runs = next(iter(series["the pair"].values()))["runs"]
    fig = Figure(figsize=(10, 9), layout="constrained")
    rate, premium, sigma = fig.subplots(3, 1, sharex=True, height_ratios=(1, 0.7, 1.2))
    colours = {"today's defaults": "tab:grey", "the pair": "tab:blue"}
    for i, (name, found) in enumerate(series.items()):
        dx = -0.18 if i == 0 else 0.18
        xs = [s + dx for s in seeds if s in found]
        rows = [found[s] for s in seeds if s in found]
        total = sum(r["below"] for r in rows)
        label = f"{name}: {total} of {len(rows) * runs} below"
        draw_rates(rate, xs, rows, colour=colours[name], label=label)
        premium.scatter(xs, [r["premium"] for r in rows], color=colours[name], label=name)
        for j, (sample, marker) in enumerate((("50", "o"), ("100", "s"))):
            values = [r["ratios"][sample] for r in rows]
            offset = (-0.05, 0.05)[j]
            sigma.errorbar(
                [x + offset for x in xs],
                [v for v, _ in values],
                yerr=[[v - lo for v, (lo, _) in values], [hi - v for v, (_, hi) in values]],
                fmt=marker,
                color=colours[name],
                capsize=3,
                label=f"{name}, sample {sample}",
            )
    rate.axhline(TARGET, color="k", ls="--", lw=1, label="target 0.5 %")
    rate.set_ylim(0, max(TARGET * 1.25, rate.get_ylim()[1]))
    rate.set_ylabel("held-out machines below [%]\n(dot: rate; bar: 95 % bound)")
    rate.legend(loc="upper left", fontsize=8)
    premium.set_ylabel("cost premium [%]")
    premium.legend(loc="lower left", fontsize=8)
    sigma.axhspan(*BAND, color="0.92", zorder=0, label="0.8-1.25")
    sigma.axhline(1.0, color="k", lw=0.8)
    sigma.set_ylabel("predicted / observed σ\nof the slider (mixed)")
    sigma.legend(loc="lower left", fontsize=8, ncol=3)
    sigma.set_xticks(seeds, [f"training seed {s}" for s in seeds])
    fig.suptitle(f"The paper task on {runs} held-out machines per torque, the same for both")
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
