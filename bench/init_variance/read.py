"""Print bench/init_variance.md's figures from each model folder's ocp.json and heldout.json."""

import json
import sys
from pathlib import Path

print(
    "| model | k | premium | held-out below | σ ratio @50 (interval) | σ ratio @100 (interval) "
    "| θ ratio @100 | lead @100 mrad | phase-1 epochs |"
)
print("|---|---|---|---|---|---|---|---|---|")
for folder in map(Path, sys.argv[1:]):
    h = json.loads((folder / "heldout.json").read_text())
    o = json.loads((folder / "ocp.json").read_text())
    entry = h["profiles"]["robust"]["open"]
    cells = []
    for k in ("50", "100"):
        p = entry["samples"][k]["predicted"]["mixed"]
        lo, hi = p["ratio_ci95"]
        cells.append(f"{p['ratio']:.3f} ({lo:.3f}-{hi:.3f})")
    theta = entry["samples"]["100"]["theta"]
    mixed = theta["predicted"]["mixed"]
    lead = 1e3 * (mixed["mean"] - theta["observed_mean"])
    robust, nominal = o["robust"], o["nominal"]
    premium = 100 * (robust["cost"] / nominal["cost"] - 1)
    k = robust["k_sigma"]
    report = folder / "model.report.json"
    epochs = "?"
    if report.exists():
        r = json.loads(report.read_text())
        epochs = r["models"]["ppann"]["epochs"]
    print(
        f"| {folder.name} | {k} | {premium:.1f} % | {entry['violating_runs']} of {h['runs']} | "
        f"{cells[0]} | {cells[1]} | {mixed['ratio']:.3f} | {lead:+.1f} | {epochs} |"
    )
