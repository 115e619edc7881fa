"""Figure of `bench/bench_tasks.py` outputs: per task, each model's returned robust torque's
held-out rate below the height with its exact 95 % bound against the 0.5 % target, and its cost
premium with the k it was solved with (a refusal is marked where the torque would stand).

    python bench/tasks_figure.py --out docs/tasks_heldout.png LABEL=tasks.json [LABEL=...]

Each LABEL=FILE is one model's `tasks.json` (bench_tasks' --out, beside its model); the k of
each torque is read from the task's ocp file beside it (tasks/task<i>-mc<seed>.json).
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from bench_tasks import TASKS
from labelled import figure_parser, labelled_json  # the script's folder is on the path

TARGET = 0.5
"""The held-out rate a robust torque is judged by, %."""


def _k(folder: Path, task_index: int, mc_seed: int, profile: str) -> float | None:
    path = folder / "tasks" / f"task{task_index}-mc{mc_seed}.json"
    try:
        return float(json.loads(path.read_text())[profile]["k_sigma"])
    except (OSError, KeyError, ValueError):
        return None


def main() -> None:
    parser = figure_parser(__doc__, inputs="tasks.json")
    args = parser.parse_args()
    runs = labelled_json(args.runs, script="tasks_figure")
    tasks = list(dict.fromkeys(row["task"] for _, _, data in runs for row in data["rows"]))
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 7.5), sharex=True)
    width = 0.7 / len(runs)
    for m, (label, path, data) in enumerate(runs):
        color = f"C{m}"
        for row in data["rows"]:
            t = tasks.index(row["task"])
            x = t - 0.35 + width * (m + 0.5)
            if row["verdict"] == "none":
                for axis in (top, bottom):
                    axis.plot(x, 0, "x", color=color, ms=8)
                continue
            rate, bound = 100 * row["heldout_rate"], 100 * row["heldout_upper_95"]
            top.errorbar(
                x,
                rate,
                yerr=[[0], [bound - rate]],
                fmt="o",
                color=color,
                capsize=3,
                label=label if t == 0 else None,
            )
            bottom.bar(x, 100 * row["premium"], width * 0.9, color=color)
            k = _k(path.parent, list(TASKS).index(row["task"]), row["mc_seed"], row["profile"])
            if k is not None:
                bottom.text(
                    x,
                    100 * row["premium"] + 0.5,
                    f"k {k:g}",
                    rotation=90,
                    ha="center",
                    va="bottom",
                    fontsize=7,
                )
    top.axhline(TARGET, color="k", ls="--", lw=1)
    top.text(len(tasks) - 0.6, TARGET, f"target {TARGET:g} %", ha="right", va="bottom")
    runs_per = {data["runs"] for _, _, data in runs}
    roots = {data["heldout_seed"] for _, _, data in runs}
    top.set_ylabel("held-out machines below the height, %\n(dot: rate, bar: 95 % bound)")
    top.set_title(
        f"returned robust torques on {'/'.join(map(str, sorted(runs_per)))} held-out machines "
        f"each (root {', '.join(map(str, sorted(roots)))}); x: refused"
    )
    top.legend(loc="upper left", fontsize=8, ncol=len(runs))
    bottom.set_ylabel("cost premium over the nominal, %")
    bottom.set_ylim(0, 1.2 * bottom.get_ylim()[1])
    bottom.set_xticks(range(len(tasks)))
    bottom.set_xticklabels(
        [t.replace(", N 150", "").replace(";", ";\n") for t in tasks], fontsize=8
    )
    fig.tight_layout()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
