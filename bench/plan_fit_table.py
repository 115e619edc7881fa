"""The table and rule of bench/plan_fit_mean.md (and the quantile lines beside it), from the lanes'
outputs: per leaf A (its own heldout.json and lead.json under a/) and B (under b/).

    python bench/plan_fit_table.py /tmp/s92/run1 [--leaves /tmp/s89/tasks/solve] \
        [--figure bench/plan_fit_mean.png]
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

from matplotlib.figure import Figure
from scipy.stats import beta, norm

NAMES = {
    (0.085, (50, 100)): "height 0.085",
    (0.08, (60, 90)): "samples 60/90",
    (0.08, (70, 130)): "horizon 200",
    (0.075, (40, 120)): "stroke's edge",
}
SE = {  # mrad: A's rows of bench/plan_fit_track.log, the episodes' mean at the later sample
    ("height 0.085", 0): 11.1,
    ("height 0.085", 1): 11.8,
    ("samples 60/90", 0): 10.2,
    ("samples 60/90", 1): 11.0,
    ("horizon 200", 0): 14.1,
    ("horizon 200", 1): 14.5,
    ("stroke's edge", 0): 14.4,
    ("stroke's edge", 1): 14.7,
}


def row(leaf: Path, lane: str, ocp: Path, task: str, seed: int, samples: tuple) -> dict:
    here = leaf / lane.lower()
    solved = json.loads(ocp.read_text())
    entry = json.loads((here / "heldout.json").read_text())["profiles"]["robust"]["open"]
    lead = json.loads((here / "lead.json").read_text())["samples"]
    r = {
        "task": task,
        "seed": seed,
        "lane": lane,
        "below": entry["violating_runs"],
        "machines": set(entry.get("violating_machines") or []),
        "bound": 100 * entry["rate_upper_95"],
        "premium": 100 * (solved["robust"]["cost"] / solved["nominal"]["cost"] - 1),
        "k": solved["robust"]["k_sigma"],
    }
    for i, s in enumerate(samples):
        at = entry["samples"][str(s)]
        r[f"ratio{i}"] = at["predicted"]["mixed"]["ratio"]
        r[f"ci{i}"] = at["predicted"]["mixed"]["ratio_ci95"]
        r[f"lead{i}"] = 1e3 * lead[str(s)]["lead"]
        r[f"mclead{i}"] = 1e3 * lead[str(s)]["mc_lead"]
        r[f"theta{i}"] = lead[str(s)]["theta_ratio"]
        r[f"q{i}"] = 1e3 * (at["observed_quantile"] - at["height"])
        r[f"skew{i}"] = at["skew"]
    return r


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--leaves", type=Path, default=Path("/tmp/s89/tasks/solve"))
    parser.add_argument("--figure", type=Path, default=None, help="draw the pairs into this PNG")
    args = parser.parse_args()
    rows = []
    for leaf in args.run.iterdir():
        config = json.loads((args.leaves / leaf.name / "config.json").read_text())
        ocp = config["ocp"]
        samples = tuple(ocp["constraint_samples"])
        task = NAMES[(ocp["height"], samples)]
        for lane, solved in (
            ("A", args.leaves / leaf.name / "ocp.json"),
            ("B", leaf / "b" / "ocp.json"),
        ):
            if (leaf / lane.lower() / "lead.json").exists():
                rows.append(row(leaf, lane, solved, task, config["seed"], samples))
    order = list(NAMES.values())
    rows.sort(key=lambda r: (r["seed"], order.index(r["task"]), r["lane"]))
    print(
        "| task | seed | lane | below of 2000 (95 % bound) | premium | k | plan lead, mrad "
        "(earlier / later) | MC lead | slider σ ratio (earlier / later [interval]) | θ ratio "
        "| Φ(−3) quantile − height, mm (earlier / later) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['task']} | {r['seed']} | {r['lane']} | {r['below']} ({r['bound']:.2f} %) "
            f"| {r['premium']:.1f} % | {r['k']:.2f} | {r['lead0']:+.1f} / {r['lead1']:+.1f} "
            f"| {r['mclead0']:+.1f} / {r['mclead1']:+.1f} | {r['ratio0']:.3f} / {r['ratio1']:.3f} "
            f"[{r['ci1'][0]:.3f}, {r['ci1'][1]:.3f}] | {r['theta0']:.3f} / {r['theta1']:.3f} "
            f"| {r['q0']:+.2f} / {r['q1']:+.2f} |"
        )
    pairs: dict = {}
    for r in rows:
        pairs.setdefault((r["task"], r["seed"]), {})[r["lane"]] = r
    full = [(key, p["A"], p["B"]) for key, p in pairs.items() if len(p) == 2]
    if not full:
        return
    print(f"\npairs: {len(full)}")
    for lane in "AB":
        got = [p[1] if lane == "A" else p[2] for p in full]
        below, runs = sum(r["below"] for r in got), 2000 * len(got)
        print(
            f"{lane}: {below} of {runs} below, pooled 95 % bound "
            f"{100 * beta.ppf(0.95, below + 1, runs - below):.3f} %; distinct machines "
            f"{sorted(set().union(*(r['machines'] for r in got)))}; largest bound "
            f"{max(r['bound'] for r in got):.2f} %; "
            f"premium {statistics.mean(r['premium'] for r in got):.2f} %"
        )
    median = {
        lane: statistics.median(abs(p[i]["lead1"]) for p in full)
        for i, lane in ((1, "A"), (2, "B"))
    }
    print(
        f"median |later lead| A {median['A']:.1f}, B {median['B']:.1f} "
        f"(half A's: {median['A'] / 2:.1f})"
    )
    for key, a, b in full:
        limit = abs(a["lead1"]) + 2 * SE[key]
        print(f"  {key}: |B| {abs(b['lead1']):.1f} against |A| + 2 s.e. {limit:.1f}")
    ratios = [b[f"ratio{i}"] for _, _, b in full for i in (0, 1)]
    print(f"B's slider σ ratios {min(ratios):.3f}–{max(ratios):.3f}")
    if args.figure is not None:
        draw(full, args.figure)


def draw(full: list, out: Path) -> None:
    """Left: each torque's later lead and slider σ ratio, A to B; right: its machines below."""
    fig = Figure(figsize=(12, 4.8), layout="constrained")
    lead, below = fig.subplots(1, 2, width_ratios=[1.2, 1])
    lead.axhspan(0.8, 1.25, color="tab:green", alpha=0.08, label="0.8–1.25")
    for (task, seed), a, b in full:
        lead.annotate(
            "",
            xy=(b["lead1"], b["ratio1"]),
            xytext=(a["lead1"], a["ratio1"]),
            arrowprops={"arrowstyle": "->", "color": "0.5"},
        )
        lead.plot(a["lead1"], a["ratio1"], "o", color="tab:red")
        lead.plot(b["lead1"], b["ratio1"], "o", color="tab:blue")
        lead.annotate(
            f"{task}, {seed}",
            (a["lead1"], a["ratio1"]),
            fontsize=7,
            xytext=(4, 4),
            textcoords="offset points",
        )
    lead.plot([], [], "o", color="tab:red", label="A: today's default")
    lead.plot([], [], "o", color="tab:blue", label="B: plan_fit (mean)")
    lead.axvline(0, color="0.7", lw=0.8)
    lead.set(
        xlabel="plan's lead over the twin at the later sample, mrad",
        ylabel="slider σ, predicted / observed",
        title="The lead and the σ it makes",
    )
    lead.legend(fontsize=8, loc="upper left")
    names = [f"{task.replace(' ', chr(10), 1)}\nseed {seed}" for (task, seed), _, _ in full]
    x = range(len(full))
    below.bar(
        [i - 0.2 for i in x], [a["below"] for _, a, _ in full], 0.4, color="tab:red", label="A"
    )
    below.bar(
        [i + 0.2 for i in x], [b["below"] for _, _, b in full], 0.4, color="tab:blue", label="B"
    )
    below.axhline(
        2000 * norm.cdf(-3), color="k", ls="--", lw=1, label="a tightening exactly at Φ(−3): 2.7"
    )
    below.axhline(
        4.5,
        color="tab:orange",
        ls=":",
        lw=1.5,
        label="more than 4 of 2000: not confirmed within 0.5 %",
    )
    below.set_xticks(list(x), names, fontsize=7)
    below.set(ylabel="machines below the height, of 2000", title="Held-out machines below")
    below.set_ylim(0, 7.5)
    below.legend(fontsize=8, loc="upper left")
    fig.suptitle(
        "plan_fit to the plan episodes' mean on the eight task torques "
        "(bench/plan_fit_mean.md, root 20261273)"
    )
    fig.savefig(out, dpi=110)


if __name__ == "__main__":
    main()
