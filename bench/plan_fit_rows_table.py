"""bench/plan_fit_rows.md's tables and rules from its sweep folders, read with the product's own
rows (crank/sweep_report.py `rows_of`, which count every machine a second stage played).

python bench/plan_fit_rows_table.py /tmp/s94/pf [/tmp/s94/mc]
    (tasks_a/, tasks_b/, lines/ inside; run 3's <task>/mc_seeds.json inside the second)
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

from plan_fit_staged_table import kept  # bench/ is the script's own folder

from crank.sweep import leaf_results
from crank.sweep_report import rows_of
from crank.sweep_spec import read_spec

TODAY = Path(__file__).with_name("trapezoid_rest_tasks.csv")
"""Today's default on the same seeds and tasks (session 90, root 20261268, other machines)."""


def sweep_rows(folder: Path) -> list[dict]:
    """The rows of every leaf of a sweep folder (a leaf not run: its error "not run")."""
    if not (folder / "sweep.toml").exists():
        return []
    _, leaves = read_spec(folder / "sweep.toml")
    return rows_of(leaf_results(leaves, folder), folder)


def plan_fit_of(folder: Path, row: dict) -> str:
    """Whether the plan round's training kept plan_fit's weights, with its largest mean-angle
    gap before and after (plan_fit_staged_table.py's words)."""
    report = folder / "solve" / row["solve_key"] / "model.report.json"
    return kept(json.loads(report.read_text())["models"]["ppann"].get("plan_fit"))


def ratios(row: dict) -> list[tuple[str, float]]:
    keys = sorted(
        (k for k in row if k.startswith("ratio_") and k.count("_") == 1), key=lambda k: int(k[6:])
    )
    return [(k[6:], row[k]) for k in keys]


def below(row: dict) -> str:
    """Machines below: of all played, and the first stage's where a second stage ran."""
    runs = row["heldout_runs"]
    count = round(row["robust_heldout_rate"] * runs)
    first = row.get("robust_heldout_first_below")
    return f"{first} → **{count} of {runs}**" if first is not None else f"{count} of {runs}"


def tasks(out: Path) -> None:
    today = {}
    with TODAY.open() as f:
        for r in csv.DictReader(f):
            today[(int(r["seed"]), r["case"])] = r
    print(
        "| task | seed | campaign | nominal /100 | below (stage 1 → all) | verdict "
        "| machines below | σ ratios at the task's samples | premium "
        "| today's default (session 90): below / 1000, premium, σ ratios | plan_fit kept |"
    )
    print("|---" * 11 + "|")
    met = {1: True, 2: True, 3: True}
    finished = 0
    for name in ("tasks_a", "tasks_b"):
        for row in sweep_rows(out / name):
            task, seed = row["case"], row["seed"]
            if row.get("error"):
                print(f"| {task} | {seed} | {row['error']} |" + " |" * 8)
                met[1] &= row["error"] == "not run"  # a refusal fails item 1
                continue
            finished += 1
            a = today[(seed, task)]
            a_ratios = " / ".join(
                f"{float(v):.3f}"
                for k, v in a.items()
                if k.startswith("ratio_") and k.count("_") == 1 and v
            )
            mine = ratios(row)
            print(
                f"| {task} | {seed} | {row['robust_100']}/{row['campaign_runs']} | "
                f"{row['nominal_100']} | {below(row)} | {row['robust_heldout_verdict']} | "
                f"{row['robust_heldout_machines']} | "
                + " / ".join(f"{v:.3f} @{s}" for s, v in mine)
                + f" | {100 * row['premium']:.1f} % | "
                f"{round(1000 * float(a['robust_heldout_rate']))}, "
                f"{100 * float(a['premium']):.1f} %, {a_ratios} | {plan_fit_of(out / name, row)} |"
            )
            met[1] &= row["robust_heldout_verdict"] == "holds"
            met[2] &= row["robust_100"] == 0
            met[3] &= all(0.8 <= v <= 1.25 for _, v in mine)
    print(f"\nrun 1: {finished} of 12 torques finished; rule items met: {met}\n")


def lines(out: Path) -> None:
    print(
        "| line | profile | campaign | nominal /100 | below (stage 1 → all) | verdict "
        "| σ ratios @50 / @100 | premium | or refused: why |"
    )
    print("|---" * 9 + "|")
    for row in sweep_rows(out / "lines"):
        line = row["generation.variability"]
        if row.get("error"):
            print(f"| {line} | {row.get('profile')} | | | | | | | {row['error']} |")
            continue
        mine = ratios(row)
        print(
            f"| {line} | {row['profile']} | {row['robust_100']}/{row['campaign_runs']} | "
            f"{row['nominal_100']} | {below(row)} | {row['robust_heldout_verdict']} | "
            + " / ".join(f"{v:.3f}" for _, v in mine)
            + f" | {100 * row['premium']:.1f} % | |"
        )


def mc_seeds(out: Path) -> None:
    """Run 3: per model, each Monte-Carlo seed's verdict, machines below (stage 1 → all),
    margins and premium (bench/bench_tasks.py's rows)."""
    print(
        "| task (model) | verdict over seeds 0-4 | below per seed (stage 1 → all) "
        "| staged verdicts | premium | margins' spread over the seeds |"
    )
    print("|---" * 6 + "|")
    for path in sorted(out.glob("*/mc_seeds.json")):
        rows = json.loads(path.read_text())["rows"]
        kinds = {r["verdict"] for r in rows}
        got = [r for r in rows if r["verdict"] == "robust"]
        counts = []
        for r in got:
            count = round(r["heldout_rate"] * r["heldout_runs"])
            first = r.get("heldout_first_below")
            counts.append(
                f"{first} → {count}/{r['heldout_runs']}"
                if first is not None
                else f"{count}/{r['heldout_runs']}"
            )
        premiums = [100 * r["premium"] for r in got]
        spread = (
            [
                max(m[i] for m in (r["margins_mm"] for r in got))
                - min(m[i] for m in (r["margins_mm"] for r in got))
                for i in range(len(got[0]["margins_mm"]))
            ]
            if got
            else []
        )
        print(
            f"| {rows[0]['task']} ({path.parent.name}) | "
            f"{'/'.join(sorted(kinds))} on {len(rows)} | "
            f"{', '.join(counts)} | {', '.join(sorted({r['heldout_verdict'] for r in got}))} | "
            f"{min(premiums):.1f}-{max(premiums):.1f} % | "
            + ", ".join(f"{v:.2f}" for v in spread)
            + " mm |"
        )


def main() -> None:
    out = Path(sys.argv[1])
    tasks(out)
    lines(out)
    if len(sys.argv) > 2:
        print()
        mc_seeds(Path(sys.argv[2]))


if __name__ == "__main__":
    main()
