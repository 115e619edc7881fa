"""bench/plan_fit_last_rows.md's tables and rules from its output folder.

python bench/plan_fit_last_table.py /tmp/s95
    (paper-<S>/ and cmp/paper-<S>/ with their ocp.json, compare/compare.json, and
     tubes/<model>/tasks_mc.json inside)

Run 1: each compare folder's `robust` and nominal torques against the run's own (bit for bit),
the pooled counts per profile and controller over the seeds, and session 63's rule: each robust
profile in its own loop and under the MPC at most 15 of 3000 below, Σu² applied under its own law
within +10 % of the nominal plan's. Run 2: per model, task and tube the verdict over the
Monte-Carlo seeds, the machines below per seed (stage 1 → all where a second stage ran), the
staged verdicts, the margins' and premiums' ranges, and session 90's rule with the staged verdict.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from plan_fit_rows_table import below, ratios  # bench/ is the script's own folder

from control.ocp_file import read_ocp

OWN = {
    "robust": ("open", "mpc"),
    "robust-fb": ("closed-LQR", "mpc"),
    "robust-pd": ("closed-PD", "mpc"),
}
"""Session 63's rule: each profile in the loop it was tightened for and under the MPC."""
ALLOWED = 15
"""Pooled below of the three seeds' 1000 held-out machines each, per profile and controller."""
EFFORT = 0.10
"""Σu² applied under its own law over the nominal plan's."""


def span(values: list[float]) -> str:
    """The least and the most to one decimal, one figure where they print alike (no -0.0)."""
    low, high = (f"{round(v, 1) + 0.0:.1f}" for v in (min(values), max(values)))
    return low if low == high else f"{low}-{high}"


def same_torques(out: Path) -> None:
    """Each compare folder's solve against its run: the nominal and `robust` torques equal."""
    for solve in sorted((out / "cmp").glob("paper-*/ocp.json")):
        mine, run = read_ocp(solve), read_ocp(out / solve.parent.name / "ocp.json")
        for name in ("nominal", "robust"):
            equal = name in mine.profiles and np.array_equal(
                mine.profiles[name].tau, run.profiles[name].tau
            )
            print(f"{solve.parent.name} {name}: the run's torque bit for bit: {equal}")


def compare(out: Path) -> None:
    path = out / "compare" / "compare.json"
    if not path.exists():
        print("run 1: no compare.json (not run or not finished)")
        return
    data = json.loads(path.read_text())
    pooled: dict[tuple[str, str], dict] = {}
    for scenario in data["scenarios"]:
        for row in scenario["rows"]:
            key = (row["profile"], row["controller"])
            p = pooled.setdefault(key, {"below": 0, "runs": 0, "campaign": 0, "effort": []})
            p["below"] += round(row["heldout_rate"] * data["heldout_runs"])
            p["runs"] += data["heldout_runs"]
            p["campaign"] += row["below_campaign"]
            p["effort"].append(row["effort_over_nominal"])
            if row.get("mpc"):
                m = row["mpc"]
                ms = f"{m['median_ms']:.2f}/{m['p99_ms']:.2f}/{m['max_ms']:.2f}"
                p.setdefault("mpc", []).append(f"{ms} ({m['deadline_misses']})")
    seeds = [s["seed"] for s in data["scenarios"]]
    n, root = data["heldout_runs"], data["heldout_seed"]
    print(f"run 1: seeds {seeds}, {n} held-out machines each, root {root}")
    print(
        "| profile | controller | held-out below | campaign below | Σu² applied vs nominal "
        "| MPC median/p99/max ms (misses) |"
    )
    print("|---" * 6 + "|")
    met, strict = True, True
    for (profile, controller), p in pooled.items():
        effort = f"{100 * min(p['effort']):+.1f} to {100 * max(p['effort']):+.1f} %"
        print(
            f"| {profile} | {controller} | {p['below']} of {p['runs']} | {p['campaign']}/"
            f"{data['runs'] * len(seeds)} | {effort} | {'; '.join(p.get('mpc', []))} |"
        )
        if controller in OWN.get(profile, ()):
            met &= p["below"] <= ALLOWED
            strict &= p["campaign"] == 0
            if controller != "mpc" and profile != "robust":
                met &= max(p["effort"]) <= EFFORT
    word = "met" if met else "NOT met"
    print(
        f"\nrun 1 rule (≤ {ALLOWED} pooled, Σu² ≤ +{100 * EFFORT:.0f} %): {word}; "
        f"no campaign run below in its own loop or the MPC: {strict}\n"
    )


def tubes(out: Path) -> None:
    print(
        "| model | task | tube | below per Monte-Carlo seed 0-4 (stage 1 → all) | staged verdicts "
        "| margins [mm] per sample | premium |"
    )
    print("|---" * 7 + "|")
    met, done = True, 0
    for path in sorted((out / "tubes").glob("*/tasks_mc.json")):
        data = json.loads(path.read_text())
        done += 1
        for task in dict.fromkeys(r["task"] for r in data["rows"]):
            for profile in data["profiles"]:
                rows = sorted(
                    (r for r in data["rows"] if r["task"] == task and r["profile"] == profile),
                    key=lambda r: r["mc_seed"],
                )
                got = [r for r in rows if r["verdict"] == "robust"]
                counts = []
                for r in rows:
                    if r["verdict"] != "robust":
                        counts.append("refused")
                        continue
                    n = round(r["heldout_rate"] * r["heldout_runs"])
                    first = r.get("heldout_first_below")
                    runs = r["heldout_runs"]
                    counts.append(f"{first} → {n}/{runs}" if first is not None else str(n))
                verdicts = sorted({r["heldout_verdict"] for r in got})
                margins = "; ".join(
                    f"{min(m):.2f}-{max(m):.2f}"
                    for m in zip(*(r["margins_mm"] for r in got), strict=True)
                )
                premium = span([100 * r["premium"] for r in got]) + " %" if got else ""
                name = task.replace(" (0.08 m at 50, 100; N 150)", "")
                print(
                    f"| {path.parent.name} | {name} | {profile} | {', '.join(counts)} | "
                    f"{', '.join(verdicts)} | {margins} | {premium} |"
                )
                met &= len({r["verdict"] for r in rows}) == 1 and len(rows) == 5
                met &= all(r["heldout_verdict"] == "holds" for r in got)
                for r in rows:
                    if r["verdict"] != "robust":
                        print(f"  refused, mc {r['mc_seed']}: {r['error']}")
    print(f"\nrun 2: {done} of 3 models finished; rule {'met' if met else 'NOT met'} on those")
    for path in sorted((out / "tubes").glob("*/tasks_mc.json")):
        found = machines_below(path.parent)
        print(f"{path.parent.name}, machines below (under how many torques): {found}")


def machines_below(folder: Path) -> dict[str, dict[int, int]]:
    """Per tube, each held-out machine below and under how many of the model's torques, from
    bench_tasks.py's held-out files (`tasks/task<t>-mc<s>.heldout.json`, every stage played)."""
    found: dict[str, dict[int, int]] = {}
    for path in sorted((folder / "tasks").glob("*.heldout.json")):
        heldout = json.loads(path.read_text())
        lists = [
            (name, entry.get("violating_machines"))
            for name, loops in heldout["profiles"].items()
            if name != "nominal"
            for entry in loops.values()
        ]  # the first stage's, then a second stage's (replay/staged.py)
        staged = (heldout.get("staged") or {}).get("profiles", {})
        lists += [(name, entry.get("violating_machines")) for name, entry in staged.items()]
        for name, machines in lists:
            for machine in machines or []:
                mine = found.setdefault(name, {})
                mine[machine] = mine.get(machine, 0) + 1
    return found


def lines(out: Path) -> None:
    """Run 3: each line study's rows (crank/study.py, one seed a study), its rule."""
    print(
        "| line | seed | profile | campaign | nominal /100 | below (stage 1 → all) | verdict "
        "| σ ratios | premium | or refused |"
    )
    print("|---" * 10 + "|")
    met, tubes_seen = True, set()
    for path in sorted((out / "lines").glob("*/study.json")):
        study = json.loads(path.read_text())
        line = path.parent.name.rsplit("-seed", 1)[0]
        for row in study["rows"]:
            seed, profile = row["seed"], row["profile"]
            if row.get("error"):
                spread = row.get("refused_tightening")
                why = (
                    f"refused: tightening {1e3 * spread:.1f} mm at sample "
                    f"{row.get('refused_sample')} (stroke above the height "
                    f"{1e3 * row['refused_available']:.1f} mm)"
                    if spread is not None
                    else f"refused: {row['error']}"
                )
                print(f"| {line} | {seed} | {profile} |" + " |" * 6 + f" {why} |")
                met &= spread is not None and profile == "robust"  # a tube must return
                continue
            tubes_seen.add((line, seed, profile))
            sigma = " / ".join(f"{v:.3f} @{sample}" for sample, v in ratios(row))
            print(
                f"| {line} | {seed} | {profile} | {row['robust_100']}/{row['campaign_runs']} | "
                f"{row['nominal_100']} | {below(row)} | {row['robust_heldout_verdict']} | "
                f"{sigma} | {100 * row['premium']:.1f} % | |"
            )
            met &= row["robust_heldout_verdict"] == "holds" and row["robust_100"] == 0
    seeds = {(line, seed) for line, seed, _ in tubes_seen}
    for line, seed in seeds:
        met &= all((line, seed, tube) in tubes_seen for tube in ("robust-fb", "robust-pd"))
    print(
        f"\nrun 3: {len(seeds)} line seeds with rows; rule {'met' if met else 'NOT met'} on those"
    )


def main() -> None:
    out = Path(sys.argv[1])
    same_torques(out)
    compare(out)
    tubes(out)
    print()
    lines(out)


if __name__ == "__main__":
    main()
