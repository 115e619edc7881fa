"""bench/plan_fit_staged.md's table and rule from its run folders (`OUT/seed<S>/`).

python bench/plan_fit_staged_table.py /tmp/s93/pf
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def row(folder: Path) -> dict | None:
    if not (folder / "report.md").exists():
        return None  # not finished (a run folder is finished once report.md is written)
    report = json.loads((folder / "report.json").read_text())
    heldout = json.loads((folder / "heldout.json").read_text())
    mode = report["config"]["ocp"]["mc_mode"]
    entry = heldout["profiles"]["robust"]["open"]
    staged = heldout.get("staged", {}).get("profiles", {}).get("robust")
    claim = report["replay"]["claim"]
    ratios = {k: e["predicted"][mode]["ratio"] for k, e in entry["samples"].items()}
    return {
        "campaign": claim["robust_open_violating_runs"],
        "nominal": claim["nominal_open_violating_runs"],
        "first": entry["violating_runs"],
        "machines": staged["machines"] if staged else [heldout["runs"]],
        "counts": staged["counts"] if staged else [entry["violating_runs"]],
        "verdict": heldout["verdicts"]["robust"],
        "listed": (entry["violating_machines"] or [])
        + ((staged or {}).get("violating_machines") or []),
        "ratios": ratios,
        "premium": report["replay"]["premiums"]["robust"],
        "plan_fit": json.loads((folder / "model.report.json").read_text())["models"]["ppann"].get(
            "plan_fit"
        ),
    }


def kept(fit: dict | None) -> str:
    """Whether the second training kept plan_fit's weights, and its largest mean-angle gap."""
    if not fit:
        return "none"
    gap = f"{1e3 * fit['theta_bias_start']:.0f} → {1e3 * fit['theta_bias_kept']:.0f} mrad"
    return f"{'yes' if fit['fitted'] else 'no'}, {gap}"


def main() -> None:
    out = Path(sys.argv[1])
    rows = {}
    for folder in sorted(out.glob("seed*")):
        if folder.is_dir():
            rows[int(folder.name.removeprefix("seed"))] = row(folder)
    print(
        "| seed | campaign | nominal /100 | below, stage 1 / 1000 | below, all (machines) "
        "| verdict | machines below | σ ratio @50 / @100 | premium | plan_fit kept |"
    )
    print("|---" * 10 + "|")
    met = {1: True, 2: True, 3: True}
    for seed, r in sorted(rows.items()):
        if r is None:
            print(f"| {seed} | not finished |" + " |" * 8)
            continue
        r50, r100 = r["ratios"]["50"], r["ratios"]["100"]
        print(
            f"| {seed} | {r['campaign']}/100 | {r['nominal']} | {r['first']} | "
            f"{r['counts'][-1]} of {r['machines'][-1]} | {r['verdict']} | {r['listed']} | "
            f"{r50:.3f} / {r100:.3f} | {100 * r['premium']:.1f} % | {kept(r['plan_fit'])} |"
        )
        met[1] &= r["verdict"] == "holds"
        met[2] &= r["campaign"] == 0 and r["nominal"] >= 10
        met[3] &= all(0.8 <= v <= 1.25 for v in (r50, r100))
    done = [s for s, r in rows.items() if r is not None]
    print(f"\nfinished seeds {done}; rule items met: {met}")


if __name__ == "__main__":
    main()
