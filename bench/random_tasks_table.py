"""bench/random_tasks.md's tables from its runs: run 1's sweep folder, read with the product's own
rows (crank/sweep_report.py `rows_of`, which count every machine a second stage played), and run
2's mc_seeds.json files (bench/bench_tasks.py, one per task folder).

    python bench/random_tasks_table.py SWEEP_FOLDER [MC_FOLDER]
        (MC_FOLDER holds task<i>/mc_seeds.json)
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

from random_tasks import task_index  # the script's folder is on the path

from crank.sweep import leaf_results
from crank.sweep_report import rows_of
from crank.sweep_spec import read_spec


def _epochs(report: Path) -> str:
    ppann = json.loads(report.read_text())["models"]["ppann"]
    return f"{ppann['epochs']}{'' if ppann['phase1_converged'] else ' (cap)'}"


def run_1(folder: Path) -> None:
    """One line per task and profile the chain ended with (a refusal: its reason)."""
    _, leaves = read_spec(folder / "sweep.toml")
    rows = rows_of(leaf_results(leaves, folder), folder)
    rows.sort(key=lambda r: task_index(r["case"]))
    print(
        "| task | profile | campaign below | held-out below (95 % bound) | verdict "
        "| machines below | nominal campaign | premium | k | σ ratio per sample "
        "| phase-1 epochs (first, final) | the model's own rate |"
    )
    print("|---" * 12 + "|")
    for row in rows:
        name = f"{task_index(row['case'])}"
        if row.get("error"):
            print(f"| {name} | {row.get('profile')} | refused: {row['error']} |" + " |" * 9)
            continue
        below = round(row["robust_heldout_rate"] * row["heldout_runs"])
        ks = sorted(int(k[6:]) for k in row if re.fullmatch(r"ratio_\d+", k) and row[k] != "")
        ratios = ", ".join(f"{row[f'ratio_{k}']:.3f} @{k}" for k in ks)
        first = _epochs(folder / "model" / row["model_key"] / "model.report.json")
        final = _epochs(folder / "solve" / row["solve_key"] / "model.report.json")
        print(
            f"| {name} | {row['profile']}{' (fallback)' if row.get('fallback') else ''} "
            f"| {row['robust_100']}/{row['campaign_runs']} "
            f"| {below} of {row['heldout_runs']} ({100 * row['robust_heldout_upper_95']:.2f} %) "
            f"| {row['robust_heldout_verdict']} | {row.get('robust_heldout_machines')} "
            f"| {row['nominal_100']}/{row['campaign_runs']} | {100 * row['premium']:.1f} % "
            f"| {row['solved_k']} | {ratios} | {first}, {final} "
            f"| {100 * row['robust_model_rate']:.3f} % |"
        )


def run_2(folder: Path) -> None:
    """One line per task and profile: the verdicts over its Monte-Carlo seeds."""
    print(
        "| task | profile | verdicts over seeds 0-4 | below per seed (runs) | premium "
        "| margins' spread over the seeds |"
    )
    print("|---" * 6 + "|")
    for path in sorted(folder.glob("task*/mc_seeds.json"), key=lambda p: int(p.parent.name[4:])):
        rows = json.loads(path.read_text())["rows"]
        for profile in dict.fromkeys(r["profile"] for r in rows):
            mine = [r for r in rows if r["profile"] == profile]
            held = [r for r in mine if r["verdict"] == "robust"]
            verdicts = "/".join(sorted({r.get("heldout_verdict", "refused") for r in mine}))
            counts = ", ".join(
                f"{round(r['heldout_rate'] * r['heldout_runs'])}/{r['heldout_runs']}" for r in held
            )
            premium = (
                f"{100 * min(r['premium'] for r in held):.1f}-"
                f"{100 * max(r['premium'] for r in held):.1f} %"
                if held
                else ""
            )
            spread = (
                ", ".join(
                    f"{max(m) - min(m):.2f}"
                    for m in zip(*(r["margins_mm"] for r in held), strict=True)
                )
                + " mm"
                if held
                else ""
            )
            print(
                f"| {path.parent.name[4:]} | {profile} | {verdicts} ({len(held)} of {len(mine)} "
                f"returned) | {counts} | {premium} | {spread} |"
            )


def main() -> None:
    if len(sys.argv) not in (2, 3):
        raise SystemExit("usage: python bench/random_tasks_table.py SWEEP_FOLDER [MC_FOLDER]")
    run_1(Path(sys.argv[1]))
    if len(sys.argv) > 2:
        print()
        run_2(Path(sys.argv[2]))


if __name__ == "__main__":
    main()
