"""Figure of `bench/bench_tasks.py` outputs for the tubes over Monte-Carlo seeds: per tube (a
column each), the held-out machines below the height of every returned torque, one dot per
Monte-Carlo seed, grouped by task with a colour per line, against the rule of at most 5 of 1000
(0.5 %); below, each tube's cost premium over the seeds (a bar from the least to the most).
A refusal is a cross on the axis; a torque the first machines could not judge, which
`bench_tasks.py --second-stage` played on more, a ring at its first stage's count.

    python bench/tubes_mc_seeds_figure.py --out docs/tubes_mc_seeds.png LABEL=tasks_mc.json ...

Each LABEL=FILE is one model's `tasks_mc.json` (bench_tasks' --out with --profiles
robust-fb,robust-pd, beside its model).
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from labelled import figure_parser, labelled_json  # the script's folder is on the path

from common.figures import save_figure

TARGET = 0.005
"""The held-out rate a robust torque is judged by."""


def _label(task: str) -> str:
    return task.replace(" (0.08 m at 50, 100; N 150)", "").replace(", samples", ",\nsamples")


def main() -> None:
    parser = figure_parser(__doc__, inputs="tasks_mc.json")
    args = parser.parse_args()
    runs = labelled_json(args.runs, script="tubes_mc_seeds_figure")
    rows = [row | {"line": label} for label, _, data in runs for row in data["rows"]]
    tasks = list(dict.fromkeys(row["task"] for row in rows))
    profiles = list(dict.fromkeys(row["profile"] for row in rows))
    seeds = sorted({row["mc_seed"] for row in rows})
    machines = {data["runs"] for _, _, data in runs}
    roots = {data["heldout_seed"] for _, _, data in runs}
    if len(machines) != 1:
        raise SystemExit(f"tubes_mc_seeds_figure: the files checked {sorted(machines)} machines")
    (n,) = machines
    fig, axes = plt.subplots(
        2, len(profiles), figsize=(6 * len(profiles), 7), sharex=True, squeeze=False
    )
    width = 0.8 / len(runs)
    for p, profile in enumerate(profiles):
        counts, premiums = axes[0, p], axes[1, p]
        for m, (label, _, _) in enumerate(runs):
            color = f"C{m}"
            for t, task in enumerate(tasks):
                mine = [
                    r
                    for r in rows
                    if r["line"] == label and r["task"] == task and r["profile"] == profile
                ]
                x0 = t - 0.4 + width * (m + 0.5)
                returned = [r for r in mine if r["verdict"] == "robust"]
                for r in mine:
                    x = x0 + width * 0.6 * ((seeds.index(r["mc_seed"]) + 0.5) / len(seeds) - 0.5)
                    first = r.get("heldout_first_below")  # bench_tasks --second-stage
                    if r["verdict"] == "robust" and first is not None:
                        counts.plot(x, first, "o", mfc="none", color=color, ms=6)
                    elif r["verdict"] == "robust":
                        below = round(r["heldout_rate"] * n)
                        counts.plot(x, below, "o", color=color, ms=4)
                    else:
                        counts.plot(x, 0, "x", color=color, ms=7)
                if returned:
                    low = min(100 * r["premium"] for r in returned)
                    high = max(100 * r["premium"] for r in returned)
                    premiums.bar(
                        x0,
                        max(high - low, 0.05),
                        width * 0.8,
                        bottom=low,
                        color=color,
                        label=label if t == 0 else None,
                    )
        counts.axhline(TARGET * n, color="k", ls="--", lw=1)
        counts.text(
            len(tasks) - 0.55, TARGET * n, f"{TARGET * n:g} of {n}", ha="right", va="bottom"
        )
        counts.set_ylim(-0.5, max(TARGET * n + 1.5, counts.get_ylim()[1]))
        counts.set_title(
            f"{profile}: a dot per Monte-Carlo seed\n(x: refused; ring: its first {n}, "
            "a second stage judged it)",
            fontsize=10,
        )
        counts.set_ylabel(f"held-out machines below, of {n}")
        premiums.set_ylabel("cost premium, %\n(bar: least to most over the seeds)")
        # a bar from its least premium read against zero, room above it for the legend
        premiums.set_ylim(0, 1.2 * premiums.get_ylim()[1])
        premiums.set_xticks(range(len(tasks)))
        premiums.set_xticklabels([_label(t) for t in tasks], fontsize=8)
        premiums.legend(loc="upper left", fontsize=8)
    fig.suptitle(
        f"the tubes in the loops they were sized for, Monte-Carlo seeds "
        f"{', '.join(map(str, seeds))}, on {n} held-out "
        f"machines of root {', '.join(map(str, sorted(roots)))} per torque",
        fontsize=11,
    )
    fig.tight_layout()
    save_figure(fig, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
