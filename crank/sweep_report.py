"""A sweep's results, assembled from its step folders: sweep.csv (one row per leaf: its options and
every figure of its report), sweep.md (the verdict, then a pivot table over every option but the
seed) and sweep.png (held-out violation rate, premium and the calibration ratios with their
intervals per option group, one dot per seed)."""

from __future__ import annotations

import textwrap
from collections import defaultdict
from pathlib import Path
from typing import Any

from matplotlib.figure import Figure

from common.atomic import atomic_path
from common.figures import save_figure
from crank import stages
from crank.study import TARGET_HELDOUT_RATE, confirmed, run_rows, write_csv
from crank.study_figure import calibration_frame, calibration_marks, solved_rows
from crank.sweep_spec import KINDS, Leaf

Records = list[tuple[Leaf, list[dict[str, Any]]]]


def rows_of(records: Records, out: Path) -> list[dict[str, Any]]:
    """One row per leaf and robust profile: its options, the first failed step's error or the
    chain's figures, and each step's wall time (the step may be shared with other leaves)."""
    rows = []
    for leaf, steps in records:
        row: dict[str, Any] = {"leaf": leaf.name, **leaf.options}
        row["campaign_runs"] = leaf.config.replay.runs
        failed = next((s for s in steps if s.get("error")), None)
        if failed is not None:
            profiles = "/".join(leaf.config.ocp.profiles)
            row |= {"profile": profiles, "error": failed["error"], "failed_step": failed["kind"]}
            rows.append(row | ({"refused": True} if failed.get("refused") else {}))
            continue
        by_kind = dict(zip(KINDS, steps, strict=True))
        leaf_dir = out / "leaf" / by_kind["leaf"]["key"]
        ocp = out / "solve" / by_kind["solve"]["key"] / stages.OCP
        row |= {f"{kind}_s": step["seconds"] for kind, step in by_kind.items()}
        row |= {f"{kind}_key": step["key"] for kind, step in by_kind.items()}
        rows += [row | figures for figures in run_rows(leaf_dir, ocp)]
    return rows


def groups(rows: list[dict[str, Any]], axes: list[str]) -> dict[str, list[dict[str, Any]]]:
    """Rows by their options other than the seed, and by robust profile where a leaf has more
    than one (label "all" when the seed is the only axis)."""
    several = len({row.get("profile") for row in rows}) > 1
    out: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for row in rows:
        label = " ".join(f"{a}={row[a]}" for a in axes if a != "seed")
        if several:
            label = f"{label} profile={row.get('profile')}".strip()
        out[label or "all"].append(row)
    return dict(out)


def failure(row: dict[str, Any]) -> str | None:
    """Why a row has no figures: "refused" (the model has no robust torque for its profile: a
    solve step that raised NoSolutionError, or one profile of a solve that wrote the others),
    "failed" (a step of its leaf raised anything else, `failed_step`), or None."""
    if not row.get("error"):
        return None
    return "refused" if row.get("refused") or "failed_step" not in row else "failed"


def _pct(value: float | None, digits: int = 2) -> str:
    return "n/a" if value is None else f"{100 * value:.{digits}f} %"


def markdown(sweep: dict[str, Any], rows: list[dict[str, Any]]) -> str:
    """sweep.md: what ran, the verdict against the held-out target, the pivot table, the errors."""
    axes = sweep["axes"]
    ok = [r for r in rows if not r.get("error") and "robust_heldout_rate" in r]
    failed = [r for r in rows if r.get("error")]
    lines = [
        f"# Sweep: {len({r['leaf'] for r in rows})} leaves over "
        f"{', '.join(axes) or 'one configuration'}",
        "",
        f"Steps: {sweep['steps']}{_ran(sweep)} ({sweep['executor']}; {sweep['wall_s']:.0f} s "
        f"wall; {_estimate(sweep)}). "
        f"Held-out seed {sweep['heldout_seeds']}. Spec: `sweep.toml`; one row per leaf: "
        "`sweep.csv`.",
        "",
    ]
    if ok:
        worst = max(ok, key=lambda r: r["robust_heldout_rate"])
        holds = worst["robust_heldout_rate"] <= TARGET_HELDOUT_RATE
        lines.append(
            f"- every robust torque returned ({len(ok)} of {len(rows)} profiles of a leaf) on "
            f"held-out machines: worst {_pct(worst['robust_heldout_rate'])} ({_named(worst)}), "
            f"target <= {_pct(TARGET_HELDOUT_RATE, 1)}: **{'met' if holds else 'NOT met'}**"
        )
        unsure = [r for r in ok if not confirmed(r)]
        if unsure:
            lines.append(
                f"- {len(unsure)} of them not confirmed by their held-out verdict (worst 95 % "
                f"bound {_pct(max(r['robust_heldout_upper_95'] for r in unsure))}): their "
                "held-out machines are too few to decide"
            )
    unchecked = [r for r in solved_rows(rows) if "robust_heldout_rate" not in r]
    if unchecked:
        lines.append(
            f"- {len(unchecked)} robust torque(s) not checked on held-out machines "
            "(heldout_runs = 0): no rate to judge"
        )
    if failed:
        lines.append(
            f"- {len(failed)} profile(s) of a leaf gave no robust torque or no result: why, below"
        )
    lines += ["", "![held-out violation rate and premium per option group](sweep.png)", ""]
    head = [
        "options",
        "leaves",
        "robust held-out (all machines)",
        "worst leaf",
        "worst 95 % bound",
        "robust campaign",
        "premium (min–max)",
        "model's own rate (mean, worst)",
        "solved with",
        "errors",
    ]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for label, members in groups(rows, axes).items():
        solved = solved_rows(members)
        bad = len(members) - len(solved)
        if not solved:
            lines.append(f"| {label} | {len(members)} |" + " n/a |" * 7 + f" {bad} |")
            continue
        good = [r for r in solved if "robust_heldout_rate" in r]  # heldout_runs = 0: none
        checked = ["not checked"] * 3
        if good:
            machines = sum(r["heldout_runs"] for r in good)
            violated = sum(round(r["robust_heldout_rate"] * r["heldout_runs"]) for r in good)
            checked = [
                f"{violated}/{machines} ({_pct(violated / machines)})",
                _pct(max(r["robust_heldout_rate"] for r in good)),
                _pct(max(r["robust_heldout_upper_95"] for r in good)),
            ]
        premium = [r["premium"] for r in solved]
        campaign = sum(r["robust_100"] for r in solved), sum(r["campaign_runs"] for r in solved)
        mean = sum(premium) / len(premium)
        cells = [
            label,
            str(len(members)),
            *checked,
            f"{campaign[0]}/{campaign[1]}",
            f"{_pct(mean, 1)} ({_pct(min(premium), 1)}–{_pct(max(premium), 1)})",
            _own(solved),
            _solved(solved),
            str(bad),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    if failed:
        lines += ["", "## Errors", ""]
        for r in failed:
            refused = failure(r) == "refused"
            where = f"{r['profile']} refused" if refused else f"{r['failed_step']} step"
            lines.append(f"- {r['leaf']}: {where}: {r['error']}")
    return "\n".join(lines) + "\n"


def _own(rows: list[dict[str, Any]]) -> str:
    """The mean and the worst of the model's own rates below the height (heldout.json version
    4, `robust_model_rate`), "n/a" where a row has none."""
    own = [r["robust_model_rate"] for r in rows if r.get("robust_model_rate") is not None]
    if len(own) < len(rows):
        return "n/a"
    return f"{_pct(sum(own) / len(own), 3)}, {_pct(max(own), 3)}"


def _solved(rows: list[dict[str, Any]]) -> str:
    """The tightenings and k the group's torques were solved with (their own tail's check may
    have raised k or changed the tightening), with how many of each, and how many plan rounds
    played a first torque its own tail's check had refused (crank/stages.py
    `solve_first_round`); "n/a" where a row has no record of it."""
    if any("solved_k" not in r for r in rows):
        return "n/a"
    parts = []
    for method in dict.fromkeys(r["solved_tightening"] for r in rows):
        ks = [r["solved_k"] for r in rows if r["solved_tightening"] == method]
        span = f"{min(ks):g}" if min(ks) == max(ks) else f"{min(ks):g}–{max(ks):g}"
        parts.append(f"{method} k {span} ×{len(ks)}")
    refused = sum(bool(r.get("first_round_tail_refused")) for r in rows)
    tail = f"; first round refused by its tail check ×{refused}" if refused else ""
    return ", ".join(parts) + tail


TICK_WIDTH = 15
"""Characters of an option's value per line under its column (about the column's inch at 8 pt)."""


def figure(rows: list[dict[str, Any]], axes: list[str]) -> Figure:
    """Per option group (x), each seed's held-out violation rate with its 95 % bound (top), cost
    premium (middle) and predicted / observed slider σ at each constraint sample with its 95 %
    interval against the 0.8-1.25 band the calibration aims at (bottom); a red cross where a
    leaf failed or a profile was refused."""
    grouped = groups(rows, axes)
    names = [a for a in axes if a != "seed"]
    if len({row.get("profile") for row in rows}) > 1:
        names.append("profile")
    lines = max(1, len(names))
    fig = Figure(
        figsize=(max(6.0, 1.0 * len(grouped) + 2), 7.5 + 0.2 * lines), layout="constrained"
    )
    top, bottom, calibration = fig.subplots(3, 1, sharex=True)
    samples: dict[str, str] = {}  # constraint sample -> colour, in the order met
    ticks = []
    for x, members in enumerate(grouped.values()):
        solved = solved_rows(members)
        spread = [x + 0.3 * (i / max(1, len(solved) - 1) - 0.5) for i in range(len(solved))]
        if len(solved) == 1:
            spread = [float(x)]
        bottom.scatter(spread, [100 * r["premium"] for r in solved], color="C1", s=18)
        # the held-out check's figures, where it ran (heldout_runs = 0 skips it)
        good = [(at, r) for at, r in zip(spread, solved, strict=True) if "robust_heldout_rate" in r]
        places = [at for at, _ in good]
        top.scatter(places, [100 * r["robust_heldout_rate"] for _, r in good], color="C0", s=18)
        top.scatter(
            places,
            [100 * r["robust_heldout_upper_95"] for _, r in good],
            color="C3",
            marker="_",
            s=120,
        )
        for at, row in good:
            calibration_marks(calibration, at, row, samples)
        if len(solved) < len(members):
            top.scatter([x], [0], color="C3", marker="x", s=80)
        values = (str(members[0].get(name)) for name in names)
        label = "\n".join(textwrap.fill(v, TICK_WIDTH) for v in values) or "all"
        refused = sum(1 for r in members if failure(r) == "refused")
        unchecked = len(solved) - len(good)
        counts = (
            (len(members) - len(solved) - refused, "failed"),
            (refused, "refused"),
            (unchecked, "not checked"),
        )
        notes = [f"{n} {word}" for n, word in counts if n]
        ticks.append(label + (f"\n({', '.join(notes)} of {len(members)})" if notes else ""))
    top.axhline(100 * TARGET_HELDOUT_RATE, color="k", ls="--", lw=1)
    top.set_ylabel("robust, held-out violations [%]")
    top.set_ylim(bottom=0)
    top.legend(
        handles=[
            top.scatter([], [], color="C0", s=18, label="a seed's rate"),
            top.scatter([], [], color="C3", marker="_", s=120, label="its 95 % upper bound"),
            top.plot([], [], color="k", ls="--", lw=1, label="target")[0],
        ],
        fontsize=8,
        loc="upper left",  # beside the panel: inside, it hid a seed's bound (session 45)
        bbox_to_anchor=(1.005, 1.0),
    )
    bottom.set_ylabel("robust cost premium [%]")
    premiums = [100 * r["premium"] for r in rows if r.get("premium") is not None]
    # a premium below 0 stays in view, and the largest one's dot whole
    bottom.set_ylim(min([0.0, *premiums]) - 0.5, max([0.0, *premiums]) * 1.06 + 0.5)
    calibration_frame(calibration, samples)
    calibration.set_xticks(range(len(grouped)), ticks, fontsize=8)
    calibration.set_xlim(-0.5, len(grouped) - 0.5)
    calibration.set_xlabel(" / ".join(names) or "every leaf")
    fig.suptitle("Sweep: robust torque per option group (one dot per seed)")
    return fig


def write_results(out: Path, sweep: dict[str, Any], records: Records) -> list[dict[str, Any]]:
    """sweep.csv, sweep.md and sweep.png from the step folders; returns the rows."""
    rows = rows_of(records, out)
    write_csv(out / "sweep.csv", rows)
    save_figure(figure(rows, sweep["axes"]), out / "sweep.png")
    with atomic_path(out / "sweep.md") as tmp:
        tmp.write_text(markdown(sweep, rows))
    return rows


def _named(row: dict[str, Any]) -> str:
    """A row's leaf, and its profile if it has one."""
    return f"{row['leaf']}, {row['profile']}" if row.get("profile") else row["leaf"]


def _ran(sweep: dict[str, Any]) -> str:
    """How many steps this invocation made, if a resume found some finished (sweeps made before
    it was recorded say nothing)."""
    run = sweep.get("steps_run")
    total = sum(sweep.get("step_counts", {}).values())
    if run is None or run == total:
        return ""
    return f"; {total - run} found finished by a resume, {run} made by it"


def _estimate(sweep: dict[str, Any]) -> str:
    """The work estimated before the start (sweeps made before it was recorded have none)."""
    if "serial_seconds_estimate" not in sweep:
        return "no estimate recorded"
    low, high = sweep["serial_seconds_estimate"]
    return f"estimated {low:.0f}-{high:.0f} s of work one step after another"
