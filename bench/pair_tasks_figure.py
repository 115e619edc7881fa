"""bench/pair_tasks_today.md as a figure: per task nobody tuned and training seed, today's
defaults beside the pair (`mean_wrap` + the plan round) on the same held-out machines: the
robust open-loop torque's rate below the height with its 95 % bound (a refusal marked on the
axis), its cost premium, and predicted / observed σ of the slider (the OCP's Monte-Carlo mode)
at the task's constraint samples with its interval against 0.8-1.25.

    python bench/pair_tasks_figure.py --defaults /work/r61/def/seed-{0..4} \
        --pair /work/r61/tasks --out docs/pair_tasks_today.png

Each --defaults folder holds one model's `bench/bench_tasks.py` outputs (`tasks-*.json`, and
under `tasks/` each task's ocp and heldout files); --pair is a `crank sweep` folder whose
sweep.csv names each case's and seed's solve and leaf.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from bench_tasks import TASKS
from matplotlib.figure import Figure
from pair_today_figure import BAND, REFUSED, TARGET, draw_rates, entry, read_sweep


def read_defaults(folders: list[str]) -> dict[tuple[str, int], dict | str]:
    """(task, seed) -> the torque's figures, or REFUSED."""
    found: dict[tuple[str, int], dict | str] = {}
    index = {name: t for t, name in enumerate(TASKS)}
    for folder in map(Path, folders):
        for path in sorted(folder.glob("tasks-*.json")):
            for row in json.loads(path.read_text())["rows"]:
                if row["profile"] != "robust":
                    continue
                key = (row["task"], int(row["mc_seed"]))
                if row["verdict"] == "none":
                    found[key] = REFUSED
                    continue
                stem = folder / "tasks" / f"task{index[row['task']]}-mc{row['mc_seed']}"
                found[key] = entry(Path(f"{stem}.heldout.json"), Path(f"{stem}.json"))
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--defaults", nargs="+", required=True)
    parser.add_argument("--pair", required=True)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    series = {
        "today's defaults": read_defaults(args.defaults),
        "the pair": read_sweep(Path(args.pair)),
    }
    colours = {"today's defaults": "tab:grey", "the pair": "tab:blue"}
    tasks = [t for t in TASKS if any(k[0] == t for s in series.values() for k in s)]
    seeds = sorted({k[1] for s in series.values() for k in s})
    fig = Figure(figsize=(4 * len(tasks), 9), layout="constrained")
    axes = fig.subplots(3, len(tasks), sharex=True, sharey="row", squeeze=False)
    runs = 0
    for c, task in enumerate(tasks):
        rate, premium, sigma = axes[:, c]
        for i, (name, found) in enumerate(series.items()):
            dx = (-0.18, 0.18)[i]
            got = {s: found[(task, s)] for s in seeds if (task, s) in found}
            ok = {s: r for s, r in got.items() if r != REFUSED}
            refused = [s for s, r in got.items() if r == REFUSED]
            below = sum(r["below"] for r in ok.values())
            runs = max([runs, *(r["runs"] for r in ok.values())])
            label = f"{name}: {below} below, {len(refused)} refused of {len(got)}"
            xs = [s + dx for s in ok]
            draw_rates(rate, xs, list(ok.values()), colour=colours[name], label=label)
            rate.scatter(
                [s + dx for s in refused],
                [0] * len(refused),
                marker="x",
                s=60,
                color="tab:red" if name == "the pair" else "k",
                zorder=4,
            )
            premium.scatter(
                xs, [r["premium"] for r in ok.values()], color=colours[name], label=name
            )
            for j, marker in enumerate("os"):
                values = [
                    sorted(r["ratios"].items(), key=lambda kv: int(kv[0]))[j] for r in ok.values()
                ]
                if not values:
                    continue
                offset = (-0.05, 0.05)[j]
                sigma.errorbar(
                    [x + offset for x in xs],
                    [v for _, (v, _) in values],
                    yerr=[
                        [v - lo for _, (v, (lo, _)) in values],
                        [hi - v for _, (v, (_, hi)) in values],
                    ],
                    fmt=marker,
                    color=colours[name],
                    capsize=3,
                    label=f"{name}, sample {values[0][0]}",
                )
        rate.axhline(TARGET, color="k", ls="--", lw=1)
        rate.set_ylim(-0.05, 1.0)
        rate.set_title(task, fontsize=10)
        rate.legend(loc="upper left", fontsize=7)
        premium.legend(loc="lower left", fontsize=7)
        sigma.axhspan(*BAND, color="0.92", zorder=0)
        sigma.axhline(1.0, color="k", lw=0.8)
        sigma.legend(loc="lower left", fontsize=7)
        sigma.set_xticks(seeds, [f"seed {s}" for s in seeds])
    axes[0, 0].set_ylabel("held-out machines below [%]\n(dot: rate; bar: 95 % bound;\nx: refused)")
    axes[1, 0].set_ylabel("cost premium [%]")
    axes[2, 0].set_ylabel("predicted / observed σ\nof the slider (mixed)")
    fig.suptitle(
        f"The tasks nobody tuned on {runs} held-out machines per torque, the same for both "
        "(dashed: the 0.5 % target; grey band: 0.8-1.25)"
    )
    fig.savefig(args.out, dpi=100)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
