"""The reading of bench/trapezoid.md: two `crank study` folders (Euler and trapezoid lanes) side
by side, per seed and profile, and the pre-registered rule.

    python bench/trapezoid_read.py EULER_STUDY TRAPEZOID_STUDY

Reads each finished `seed-<s>/` (a study still running is read as far as both lanes got): the
study's own rows (crank/study.py `seed_rows`) and, from `heldout.json`, the model's own rate at
each constraint sample beside the twin's and the model's mean motor angle less the twin's there
and its mean slider less the twin's (the Monte-Carlo's mode, in the profile's loop).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

from crank.study import seed_rows

PROFILES = ("robust", "robust-fb", "robust-pd")


def lane(folder: Path) -> dict[tuple[int, str], dict[str, Any]]:
    """(seed, profile) -> the study's row with the held-out per-sample figures added."""
    rows = {}
    for run_dir in sorted(folder.glob("seed-*")):
        if not (run_dir / "report.md").is_file():
            continue
        seed = int(run_dir.name.removeprefix("seed-"))
        heldout = json.loads((run_dir / "heldout.json").read_text())
        for row in seed_rows(seed, run_dir):
            if row.get("error") or row["profile"] not in heldout["profiles"]:
                rows[(seed, row["profile"])] = row | {"samples": None}  # refused: no torque
                continue
            played = heldout["profiles"][row["profile"]][row["loop"]]
            mode = row["mc_mode"]
            row["samples"] = {
                sample: {
                    "below": entry["violations"],
                    "model_rate": played["model_rate"]["samples"][sample],
                    "theta_offset_mrad": 1e3
                    * (entry["theta"]["predicted"][mode]["mean"] - entry["theta"]["observed_mean"]),
                    "slider_offset_mm": 1e3 * (entry["predicted"][mode]["mean"] - entry["mean"]),
                }
                for sample, entry in played["samples"].items()
            }
            rows[(seed, row["profile"])] = row
    return rows


def count(row: dict[str, Any]) -> int:
    return round(row["robust_heldout_rate"] * row["heldout_runs"])


def show(name: str, rows: dict[tuple[int, str], dict[str, Any]], seeds: list[int]) -> None:
    print(f"\n{name}")
    print(
        "seed profile   below/runs  bound   model  campaign nominal premium  ratio 50/100"
        "   own rate 50/100 vs twin       theta offset 50/100 mrad  slider mm  phase1"
    )
    for seed in seeds:
        for profile in PROFILES:
            r = rows[(seed, profile)]
            if r["samples"] is None:
                print(f"{seed:>4} {profile:<9} no torque: {r.get('error')}")
                continue
            s50, s100 = r["samples"]["50"], r["samples"]["100"]
            n, bound, own = r["heldout_runs"], r["robust_heldout_upper_95"], r["robust_model_rate"]
            print(
                f"{seed:>4} {profile:<9} {count(r):>5}/{n:<5} {100 * bound:.2f}%"
                f" {100 * own:.3f}% {r['robust_100']:>4}/100 {r['nominal_100']:>4}"
                f" {100 * r['premium']:6.1f}%  {r['ratio_50']:.3f}/{r['ratio_100']:.3f}"
                f"  {100 * s50['model_rate']:.3f}/{100 * s100['model_rate']:.3f}% vs"
                f" {100 * s50['below'] / n:.3f}/{100 * s100['below'] / n:.3f}%"
                f"  {s50['theta_offset_mrad']:+6.1f}/{s100['theta_offset_mrad']:+6.1f}"
                f"  {s50['slider_offset_mm']:+.2f}/{s100['slider_offset_mm']:+.2f}"
                f"  {'stopped' if r['phase1_converged'] else 'CAP'} {r['phase1_epochs']}"
            )


def rule(
    euler: dict[tuple[int, str], dict[str, Any]],
    trapezoid: dict[tuple[int, str], dict[str, Any]],
    seeds: list[int],
) -> bool:
    """bench/trapezoid.md's three conditions; prints each."""
    if any(
        rows[(s, p)]["samples"] is None
        for rows in (euler, trapezoid)
        for s in seeds
        for p in PROFILES
    ):
        print("\na profile was refused in a lane: the rule is read by hand")
        return False

    def targets(rows: dict[tuple[int, str], dict[str, Any]]) -> set[str]:
        met = set()
        if all(rows[(s, "robust")]["robust_100"] == 0 for s in seeds):
            met.add("robust 0/100 on every seed")
        if all(rows[(s, "robust")]["nominal_100"] >= 10 for s in seeds):
            met.add("nominal >= 10/100 on every seed")
        for p in PROFILES:
            if all(count(rows[(s, p)]) <= 0.005 * rows[(s, p)]["heldout_runs"] for s in seeds):
                met.add(f"{p} <= 0.5 % held out on every seed")
        return met

    lost = targets(euler) - targets(trapezoid)
    first = not lost
    print(f"\n1. targets the Euler lane meets and the trapezoid does not: {sorted(lost) or 'none'}")
    second = True
    for p in PROFILES:
        e = sum(count(euler[(s, p)]) for s in seeds)
        t = sum(count(trapezoid[(s, p)]) for s in seeds)
        allowed = e + 2 * math.sqrt(e + 1)
        second &= t <= allowed
        print(f"2. {p}: below summed over seeds, Euler {e}, trapezoid {t} (allowed {allowed:.1f})")

    def inside(rows: dict[tuple[int, str], dict[str, Any]]) -> int:
        return sum(
            0.8 <= rows[(s, p)][f"ratio_{k}"] <= 1.25
            for s in seeds
            for p in PROFILES
            for k in (50, 100)
        )

    total = 2 * len(PROFILES) * len(seeds)
    e, t = inside(euler), inside(trapezoid)
    print(f"3. σ ratios inside 0.8-1.25: Euler {e}, trapezoid {t} of {total}")
    third = t >= e
    verdict = first and second and third
    print(f"\nthe trapezoid becomes the default: {'yes' if verdict else 'no'} (seeds {seeds})")
    return verdict


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("euler", type=Path)
    parser.add_argument("trapezoid", type=Path)
    args = parser.parse_args()
    euler, trapezoid = lane(args.euler), lane(args.trapezoid)
    seeds = sorted({s for s, _ in euler} & {s for s, _ in trapezoid})
    if not seeds:
        raise SystemExit("no seed finished in both lanes")
    show(f"Euler ({args.euler})", euler, seeds)
    show(f"trapezoid ({args.trapezoid})", trapezoid, seeds)
    rule(euler, trapezoid, seeds)


if __name__ == "__main__":
    main()
