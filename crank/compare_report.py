"""compare.md and compare.png of `crank compare` (crank/compare.py): a table per scenario of
profile × controller, the verdict against issue 12's targets, and violation rate and premium
against the scenario's spread."""

from __future__ import annotations

from typing import Any

from matplotlib.figure import Figure

from control.figures import COLORS

CONTROLLER_STYLES = {"open": "o-", "closed-PD": "s:", "closed-LQR": "^--", "mpc": "D-."}
DODGE = {"nominal": -0.9, "robust": -0.3, "robust-fb": 0.3, "robust-pd": 0.9}
"""Each profile's points beside its scenario's spread in the rate panel, ±%: equal rates of two
profiles drew one over the other (session 46: `robust` open loop under `robust-pd`'s PD)."""
COLUMNS = (
    ("profile", "profile", ""),
    ("controller", "controller", ""),
    ("below_campaign", "below /runs", ""),
    ("heldout_rate", "held-out", ".2%"),
    ("heldout_upper_95", "95 % bound", ".2%"),
    ("lowest_campaign_mm", "lowest campaign mm", ".1f"),
    ("lowest_heldout_mm", "lowest held-out mm", ".1f"),
    ("premium", "cost premium", "+.1%"),
    ("effort_over_nominal", "Σu² applied vs nominal plan", "+.1%"),
    ("theta_rms_mrad", "θ RMS to plan mrad", ".1f"),
    ("saturated_share", "saturated", ".1%"),
    ("final_theta_error", "θ_N error rad", "+.3f"),
    ("final_omega_error", "ω_N error rad/s", "+.2f"),
)


def _cell(row: dict[str, Any], key: str, spec: str) -> str:
    value = row.get(key)
    if key == "below_campaign":
        return f"{value}/{row['campaign_runs']}"
    if value is None:
        return "n/a"
    return format(value, spec) if spec else str(value)


def _mpc(row: dict[str, Any]) -> str:
    m = row.get("mpc")
    if not m:
        return ""
    return f"{m['median_ms']:.2f} / {m['p99_ms']:.2f} / {m['max_ms']:.2f} ({m['deadline_misses']})"


OWN_LAW = {"robust-fb": ("closed-LQR", "mpc"), "robust-pd": ("closed-PD",)}
"""The controllers each tube was sized for (the MPC plays the LQR it reduces to)."""


def verdict(scenario: dict[str, Any], *, rate: float, effort: float) -> list[str]:
    """Issue 12's targets on this scenario: each tube (robust-fb, robust-pd) under the law it was
    sized for (OWN_LAW) at 0 campaign runs and <= `rate` of held-out machines, with Σu² applied
    within `effort` of the nominal plan's."""
    lines = []
    for row in scenario["rows"]:
        if row["controller"] not in OWN_LAW.get(row["profile"], ()):
            continue
        holds = row["below_campaign"] == 0 and row["heldout_rate"] <= rate
        word = "met" if holds else "NOT met"
        if holds and row["heldout_upper_95"] > rate:  # replay/rates.py
            word = "met on these machines, not confirmed: the bound is above the target"
        cheap = row["effort_over_nominal"] <= effort
        lines.append(
            f"- {row['profile']} under {row['controller']}: {row['below_campaign']}/"
            f"{row['campaign_runs']} campaign runs and {100 * row['heldout_rate']:.2f} % of "
            f"held-out machines below (bound {100 * row['heldout_upper_95']:.2f} %): "
            f"**{word}**; Σu² applied "
            f"{100 * row['effort_over_nominal']:+.1f} % over the nominal plan's: "
            f"**{'met' if cheap else 'NOT met'}**"
        )
    if not lines:
        lines.append(
            "- no tube (robust-fb, robust-pd) in this run: the closed-loop targets were not checked"
        )
    return lines


def _range(values: list[float], spec: str) -> str:
    low, high = min(values), max(values)
    return format(low, spec) if low == high else f"{format(low, spec)} to {format(high, spec)}"


def pooled(compare: dict[str, Any]) -> list[str]:
    """One table over every run: per scenario, profile and controller, the held-out machines
    below the height summed over the runs (seeds), the worst run's 95 % bound, and the ranges of
    the premium and of the Σu² applied against the nominal plan's."""
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for scenario in compare["scenarios"]:
        for row in scenario["rows"]:
            groups.setdefault((row["scenario"], row["profile"], row["controller"]), []).append(row)
    lines = [
        "| scenario | profile | controller | seeds | campaign below | held-out below | worst "
        "95 % bound | lowest held-out mm | cost premium | Σu² applied vs nominal plan | MPC p99 "
        "ms (max) |",
        "|" + "---|" * 11,
    ]
    for (scenario, profile, controller), rows in groups.items():
        machines = sum(round(r["heldout_rate"] * compare["heldout_runs"]) for r in rows)
        mpc = [r["mpc"] for r in rows if r.get("mpc")]
        lines.append(
            f"| {scenario} | {profile} | {controller} | {', '.join(str(r['seed']) for r in rows)} "
            f"| {sum(r['below_campaign'] for r in rows)}/{sum(r['campaign_runs'] for r in rows)} "
            f"| {machines}/{compare['heldout_runs'] * len(rows)} "
            f"| {max(r['heldout_upper_95'] for r in rows):.2%} "
            f"| {min(r['lowest_heldout_mm'] for r in rows):.1f} "
            f"| {_range([r['premium'] for r in rows], '+.1%')} "
            f"| {_range([r['effort_over_nominal'] for r in rows], '+.1%')} "
            + (
                f"| {max(m['p99_ms'] for m in mpc):.2f} ({max(m['max_ms'] for m in mpc):.2f}) |"
                if mpc
                else "| |"
            )
        )
    return lines


def markdown(compare: dict[str, Any]) -> str:
    """compare.md: per scenario the verdict, then profile × controller."""
    rate, effort = compare["target_rate"], compare["target_effort"]
    lines = [
        "# Controllers per product-line scenario",
        "",
        f"Each profile on {compare['runs']} campaign machines (the run's replay seed) and "
        f"{compare['heldout_runs']} held-out machines (root seed {compare['heldout_seed']}), "
        "the same machines for every controller: open loop, the fixed PD (Kp "
        f"{compare['pd']['kp']:g}, Kd {compare['pd']['kd']:g}), the "
        "profile's LQR law, the online MPC on the run's PPANN (horizon "
        f"{compare['mpc']['horizon']}). Targets (issue 12): <= {100 * rate:.1f} % of held-out "
        f"machines below the height, Σu² applied within {100 * effort:.0f} % of the nominal "
        "plan's.",
        "",
        "![held-out violation rate and premium against the scenario's spread](compare.png)",
        "",
        "## Every run pooled",
        "",
        *pooled(compare),
        "",
    ]
    for scenario in compare["scenarios"]:
        lines += [
            f"## `{scenario['scenario']}` (friction and damping ±{100 * scenario['spread']:.0f} %, "
            f"seed {scenario['seed']}, run `{scenario['run']}`)",
            "",
            *verdict(scenario, rate=rate, effort=effort),
            *(f"- {name}: refused: {why}" for name, why in scenario["refused"].items()),
            "",
            "| "
            + " | ".join(c[1] for c in COLUMNS)
            + " | MPC step median / p99 / max ms (misses) |",
            "|" + "---|" * (len(COLUMNS) + 1),
        ]
        for row in scenario["rows"]:
            cells = [_cell(row, key, spec) for key, _, spec in COLUMNS]
            lines.append("| " + " | ".join(cells) + f" | {_mpc(row)} |")
        lines.append("")
    return "\n".join(lines)


def figure(compare: dict[str, Any]) -> Figure:
    """Held-out violation rate per profile and controller, and each robust profile's premium
    and Σu² applied over the nominal plan's, against the scenarios' spread."""
    fig = Figure(figsize=(13, 8), layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True)
    rows = [r for s in compare["scenarios"] for r in s["rows"]]
    series: dict[tuple[str, str], dict[float, list[dict[str, Any]]]] = {}
    for row in rows:
        series.setdefault((row["profile"], row["controller"]), {}).setdefault(
            row["spread"], []
        ).append(row)
    for (profile, controller), by_spread in series.items():
        x = [100 * v for v in sorted(by_spread)]
        worst = [max(r["heldout_rate"] for r in by_spread[v]) for v in sorted(by_spread)]
        style = {"color": COLORS[profile], "ms": 5}
        label = f"{profile}, {controller}" + (" (worst seed)" if len(rows) > len(series) else "")
        dodged = [v + DODGE.get(profile, 0.0) for v in x]
        rates = [100 * w for w in worst]
        top.plot(dodged, rates, CONTROLLER_STYLES[controller], label=label, **style)
        if profile != "nominal" and controller in ("closed-LQR", "mpc", *OWN_LAW.get(profile, ())):
            most = [max(r["effort_over_nominal"] for r in by_spread[v]) for v in sorted(by_spread)]
            label = f"{profile}: Σu² applied under {controller} (largest)"
            bottom.plot(
                x, [100 * m for m in most], CONTROLLER_STYLES[controller], label=label, **style
            )
    premiums: dict[str, list[tuple[float, float]]] = {}
    for row in rows:
        if row["profile"] != "nominal" and row["controller"] == "open":
            premiums.setdefault(row["profile"], []).append((row["spread"], row["premium"]))
    for profile, points in premiums.items():
        points.sort()
        bottom.plot(
            [100 * p for p, _ in points],
            [100 * v for _, v in points],
            "*",
            color=COLORS[profile],
            ms=10,
            label=f"{profile}: plan's cost premium (each seed)",
        )
    top.axhline(100 * compare["target_rate"], color="k", lw=1, ls="--", label="target 0.5 %")
    refused: dict[float, set[str]] = {}
    for scenario in compare["scenarios"]:
        refused.setdefault(100 * scenario["spread"], set()).update(scenario["refused"])
    for x, names in refused.items():
        if names:
            top.annotate(
                "\n".join(f"{n}: refused" for n in sorted(names)),
                (x, 0.02),
                ha="center",
                color="C3",
                fontsize=8,
            )
    top.set_yscale("symlog", linthresh=0.1)
    top.set_ylim(0, 110)
    top.set_ylabel("held-out machines below the height [%]\n(0 to 0.1 linear, log above)")
    top.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1))
    bottom.axhline(100 * compare["target_effort"], color="k", lw=1, ls="--", label="target +10 %")
    bottom.set_ylabel("over the nominal plan [%]")
    bottom.set_xlabel("friction and damping spread of the scenario [±%]")
    spreads = {100 * s["spread"]: s["scenario"] for s in compare["scenarios"]}
    bottom.set_xticks(list(spreads), [f"{name}\n±{x:.0f} %" for x, name in spreads.items()])
    bottom.set_xlim(0, max(spreads) + 5)
    bottom.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1))
    names = dict.fromkeys(  # in the x axis' order, narrowest line first
        f"{s['scenario']} ±{100 * s['spread']:.0f} %"
        for s in sorted(compare["scenarios"], key=lambda s: s["spread"])
    )
    runs = len(compare["scenarios"])
    count = f"{runs} run" if runs == 1 else f"{runs} runs"
    fig.suptitle(f"Profiles × controllers on the twin: {', '.join(names)} ({count})")
    return fig
