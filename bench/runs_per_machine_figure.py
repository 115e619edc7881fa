"""bench/runs_per_machine.md as a figure: per study (line, machines × runs, bounds) and seed, the
two readings of the same runs side by side — grouped by machine (what training does since
session 78) and every episode a machine of its own (before) — with the line mean's standard error
in damping (top), and the returned robust torque's premium (bottom; a circle: open loop, a
square: the tube after the open loop was refused) labelled with its held-out machines below.

    python bench/runs_per_machine_figure.py --out docs/runs_per_machine.png \
        bench/runs_per_machine.json bench/runs_per_machine_24x3.json ...

Each JSON is one `bench/runs_per_machine.py` record; its label is read from its config.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from matplotlib.figure import Figure
from matplotlib.lines import Line2D

SHAPES = {"o": "open loop (`robust`)", "s": "tube (`robust-fb`): the open loop refused"}
READINGS = {"grouped": ("grouped by machine", "tab:blue"), "episodes": ("as episodes", "tab:gray")}


def label(record: dict) -> str:
    c = record["config"]
    bounds = (
        " exact"
        if any(s["grouped"].get("line_mean_quantile") for s in record["seeds"].values())
        else ""
    )
    return f"{c.get('variability', 'paper')}\n{c['machines']} × {c['runs']}{bounds}"


def returned(entry: dict) -> tuple[str, float, int] | None:
    """The returned robust profile of one reading: (name, premium %, held-out below)."""
    for name, profile in entry.get("profiles", {}).items():
        if "premium" not in profile:
            continue
        (loop,) = entry["heldout"][name].values()
        return name, 100 * profile["premium"], loop["below"]
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("records", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    records = [json.loads(p.read_text()) for p in args.records]
    fig = Figure(figsize=(11, 6.5), layout="constrained")
    se_ax, cost_ax = fig.subplots(2, 1, sharex=True)
    ticks, names, refused = [], [], False
    for i, record in enumerate(records):
        seeds = sorted(record["seeds"], key=int)
        for j, seed in enumerate(seeds):
            for k, (reading, (text, colour)) in enumerate(READINGS.items()):
                x = i + (j - 1) * 0.22 + (k - 0.5) * 0.09
                entry = record["seeds"][seed][reading]
                first = i == 0 and j == 0  # one legend entry per reading
                se_ax.bar(x, entry["line_mean_se"]["B"], 0.08, color=colour,
                          label=text if first else None)  # fmt: skip
                got = returned(entry)
                if got is None:
                    cost_ax.plot(x, 0, "x", color="tab:red")
                    refused = True
                    continue
                name, premium, below = got
                cost_ax.plot(x, premium, "o" if name == "robust" else "s", color=colour, ms=7)
                cost_ax.annotate(str(below), (x, premium), xytext=(0, 6),
                                 textcoords="offset points", ha="center", fontsize=7)  # fmt: skip
        ticks.append(i)
        names.append(label(record))
    se_ax.set_ylabel("line mean's s.e. of the\ndamping log-factor")
    se_ax.legend(loc="upper right")
    se_ax.set_title(
        "The same runs read by machine and as episodes (seeds 0–2 each); "
        "numbers: held-out machines below of 1000"
    )
    cost_ax.set_ylabel("robust premium (%)")
    cost_ax.set_ylim(0, None)
    cost_ax.set_xticks(ticks, names)
    shapes = [Line2D([], [], ls="", marker=m, color="k", label=t) for m, t in SHAPES.items()]
    if refused:  # a reading with no robust torque at all
        shapes.append(Line2D([], [], ls="", marker="x", color="tab:red", label="no robust torque"))
    cost_ax.legend(handles=shapes, loc="center left", fontsize=8)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
