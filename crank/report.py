"""What `crank run` tells its user: terminal summaries and `report.md` beside `report.json`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from common.atomic import atomic_path
from common.jsonio import finite_or_none
from crank.report_heldout import heldout_lines, loop_words, number, ratio_text
from ppann.modes import MODES
from replay.statistics import format_table, summary_rows

FIGURES = (
    ("dataset.excitation.png", "Dataset: excitation torque and response (paper Fig. 5)"),
    ("dataset.coverage.png", "Dataset: coverage of θ and ω (Fig. 6)"),
    ("model.maps.png", "PPANN networks over θ and ω (Fig. 7)"),
    ("model.validation.png", "Free runs on the validation data (Fig. 8)"),
    ("model.bands.png", "Monte-Carlo ±3σ bands against the twin (Fig. 9)"),
    ("model.calibration.png", "Predicted against observed σ"),
    ("ocp.nominal.png", "Nominal OCP (Fig. 10)"),
    ("ocp.robust.png", "Robust OCP and its margin iterations (Fig. 11)"),
    ("ocp.robust-fb.png", "Robust OCP for the LQR closed loop (a tube) and its margin iterations"),
    ("ocp.robust-pd.png", "Robust OCP for the fixed-PD closed loop (a tube) and its iterations"),
    ("replay.png", "Replays on the twin (Fig. 12)"),
)


def train_summary(report: dict[str, Any]) -> dict[str, Any]:
    """The training report in a few lines (n/a where a diverged draw left no number)."""
    report = finite_or_none(report)
    rows: dict[str, Any] = {}
    for kind, entry in report["models"].items():
        r10 = entry["rmse_10_step"]
        rows[f"{kind} 10-step RMSE θ / ω"] = (
            f"{number(r10['theta'], '.4f')} rad / {number(r10['omega'], '.3f')} rad/s"
        )
    if report["calibration"] is None:
        rows["σ predicted/observed"] = "n/a: rig data, no twin to observe"
    for mode in MODES if report["calibration"] is not None else ():
        c = report["calibration"][mode]
        theta, slider = c["theta"]["median"], c["slider_position"]["median"]
        rows[f"σ predicted/observed ({mode})"] = (
            f"θ {ratio_text(theta)}, slider {ratio_text(slider)}"
        )
    seen = report["models"]["ppann"].get("spread_data")
    if seen:  # what the machine spread was learnt from (ppann/machine.py)
        rows["spread learnt from"] = f"{seen['machines']} machines, {seen['episodes']} episodes"
        quantile = report["models"]["ppann"].get("line_mean_quantile", 0.0)
        if quantile is None:  # ppann/confidence.py: one machine bounds nothing about the line
            rows["spread learnt from"] += "; no bound on the line at 0.95 (one machine)"
        elif report["models"]["ppann"].get("bounds_calibrated"):  # ppann/inversion.py
            radius = report["models"]["ppann"]["line_mean_radius"]
            rows["spread learnt from"] += "; line mean bounded at " + ", ".join(
                f"{name} {r:.2f}" for name, r in zip("JBK", radius, strict=True)
            )
            rows["spread learnt from"] += " se (0.95; calibrated by simulation)"
        elif quantile:
            rows["spread learnt from"] += f"; line mean bounded at {quantile:.2f} se (0.95)"
    force = report["models"]["ppann"].get("lever_sigma")
    if force is not None:  # the slider force's channel (ppann/lever.py)
        rows["slider force σ (fitted)"] = f"{force:.1f} N"
    share = report["models"]["ppann"].get("residual_mean_share")
    if share is not None:  # the residual's mean (ppann/residual_mean.py)
        rows["residual's mean, of phase 2's power"] = f"{100 * share:.1f} %"
    rows["PPANN training"] = f"{report['models']['ppann']['train_seconds']:.1f} s"
    return rows


def solve_summary(payload: dict[str, Any]) -> dict[str, Any]:
    """The OCP result in a few lines: per robust profile its cost, iterations and margins, or
    why it was refused."""
    n = payload["nominal"]
    rows: dict[str, Any] = {"nominal cost": f"{n['cost']:.6g}"}
    height, k = payload["config"]["height"], payload["config"]["k_sigma"]
    for name in payload["profiles"][1:]:
        r = payload[name]
        solves = [it for it in payload["robust_iterations"] if it["profile"] == name]
        rows |= {
            f"{name} cost": f"{r['cost']:.6g} ({r['cost'] / n['cost'] - 1:+.1%}; {r['loop']} loop)",
            f"{name} iterations": len(solves),
            f"{name} final margins": ", ".join(
                f"{1e3 * (h - height):.2f} mm" for h in r["heights"]
            ),
            f"{name}: of which for the line's mean": ", ".join(
                f"{1e3 * v:.2f} mm" for v in r["population"]
            )
            + f" (confidence {payload['config']['confidence']:g})",
            f"{name}: of which for the Monte-Carlo's standard error": ", ".join(
                f"{1e3 * v:.2f} mm" for v in r["sampling"]
            ),
        }
        checks = r.get("tail_checks", [])
        if checks:  # control/tail.py
            told = "; ".join(
                f"{'its draft, before the returned solve: ' if c.get('draft') else ''}"
                f"{c['tightening']} at k {c.get('k_sigma', k):g} {100 * c['rate']:.2f} % of "
                f"{c['draws']}{' lines' if c.get('sampling') == 'lines' else ''} below "
                f"(target {100 * c['target']:g} %)"
                for c in checks
            )
            if len(checks) > 1:
                told += " -> the last one returned"
            rows[f"{name}: its own tail"] = told
    for name, why in payload.get("refused", {}).items():
        rows[name] = f"refused: {why}"
    if payload.get("fallback"):
        rows["fallback"] = f"{', '.join(payload['fallback'])}: every profile asked was refused"
    return rows


def solve_timing(payload: dict[str, Any]) -> dict[str, str]:
    """The solves' wall times, for the terminal (not in report.json: the reproducibility rule
    of common/jsonio.py)."""
    t = payload["timing"]
    return {
        "nominal solve": f"{t['nominal_solve_s']:.2f} s",
        **{f"{name} loop": f"{s:.2f} s" for name, s in t["robust_loop_s"].items()},
    }


def _rows(title: str, rows: dict[str, Any]) -> list[str]:
    lines = [f"## {title}", "", "| | |", "| --- | --- |"]
    lines += [
        f"| {k} | {v:.6g} |" if isinstance(v, float) else f"| {k} | {v} |" for k, v in rows.items()
    ]
    return [*lines, ""]


def markdown(report: dict[str, Any], *, stats: dict[str, Any], run_dir: Path) -> str:
    """report.md: the verdict first, then the replay table, the steps, the figures, the files."""
    config = report["config"]
    claim = stats["claim"]
    runs = stats["config"]["runs"]
    samples = ", ".join(str(k) for k in stats["ocp"]["constraint_samples"])
    premiums = stats["ocp"]["premiums"]
    refused, fallback = report["refused"], report.get("fallback", [])
    if claim["holds"] is None:
        verdict = "The robust torque was not replayed open loop: the paper's claim was not checked."
        if "robust" in refused:
            verdict = f"No robust torque: {refused['robust']}"
    else:
        word = "**holds**" if claim["holds"] else "**does not hold**"
        verdict = (
            f"The paper's claim {word} on this twin: open loop, the robust torque left the slider "
            f"below {stats['ocp']['height']:g} m at a constraint sample ({samples}) in "
            f"{claim['robust_open_violating_runs']} of {runs} runs, the nominal torque in "
            f"{claim['nominal_open_violating_runs']} (the claim needs 0 and at least "
            f"{claim['nominal_needed']}). Robust cost premium: {premiums['robust']:+.1%}."
        )
    verdicts = [verdict]
    for name, c in stats.get("claims", {}).items():
        if name == "robust":
            continue  # the paper's claim above
        word = "**holds**" if c["holds"] else "**does not hold**"
        verdicts.append(
            f"The {name} torque {word}: {loop_words(c['loop'], name)}, it left the slider below "
            f"the height in {c['violating_runs']} of {c['runs']} runs (cost premium "
            f"{premiums[name]:+.1%})."
        )
    verdicts += [f"No {name} torque: {why}" for name, why in refused.items() if name != "robust"]
    if fallback:  # control/profiles.py solve_profiles
        verdicts.insert(
            1,
            f"Every profile asked for ({', '.join(config['ocp']['profiles'])}) was refused, so "
            f"the fallback {', '.join(fallback)} was solved from the same plan (`[ocp] fallback`, "
            "`--fallback none` to stop at the refusal).",
        )
    lines = [
        f"# crank run `{run_dir.name.removesuffix('.partial')}`",  # a sweep step's folder
        "",
        *(line for v in verdicts for line in (v, "")),
        *heldout_lines(report.get("heldout")),
        "## Replays on the twin",
        "",
        f"{runs} machines per profile and mode (the same machines for all), seed {config['seed']}; "
        f"violations and lowest slider position at samples {samples}; kσ of the slider observed "
        "over the runs / predicted by the PPANN's Monte-Carlo; θ error at the last sample; Σu² "
        "applied (planned).",
        "",
        format_table(summary_rows(stats), markdown=True),
        "",
        *_rows("Dataset", report["dataset"]),
        *_rows("PPANN", train_summary(report["ppann"])),
        *_rows("OCP", report["ocp"]),
        *_plan_rows(report.get("plan_round")),
        *_rows("Wall time [s] (estimated beforehand)", _wall(report)),
        "## Figures",
        "",
    ]
    for name, caption in FIGURES:
        if (run_dir / name).exists():
            lines += [f"### {caption}", "", f"![{caption}]({name})", ""]
    lines += [
        "## Files",
        "",
        "- `config.json`: the resolved configuration and seeds of every step",
        "- `dataset.mcap`: the training dataset (Foxglove; `crank inspect`)",
        "- `model.pt`, `model.report.json`: the PPANN and its validation",
        "- `ocp.json`: nominal and robust torques with their predicted bands (a profile as the "
        "CSV a machine's controller plays: `crank export ocp.json --profile NAME`; the runs "
        "it plays there, recorded and imported, against the plan: `crank verify`)",
        "- `replay.mcap`: every replay, tagged by run, profile and mode (Foxglove)",
        "- `replay.rrd`: the same for the Rerun viewer (`crank view replay.rrd`)",
        "- `replay.stats.json`: the statistics above, per sample",
        "- `heldout.json`: the held-out check and calibration (if run)",
        *(
            [
                "- `plan.mcap`: the dataset after the plan round's episodes (what model.pt "
                "learnt from)",
                "- `round-0/`: the first model and solve, whose torque the round played",
            ]
            if report.get("plan_round")
            else []
        ),
        "",
        f"Reproduce with `{_rerun_args(config.get('argv', []))}` (same seed, same "
        "numbers; `--name` for another folder name).",
        "",
    ]
    return "\n".join(lines)


def _rerun_args(argv: list[str]) -> str:
    """The command that repeats a run: its own arguments without its folder name."""
    args = list(argv[1:])
    for i, arg in enumerate(args):
        if arg == "--name":
            del args[i : i + 2]
            break
        if arg.startswith("--name="):
            del args[i]
            break
    return " ".join(["crank", "run", *args])


def write_markdown(path: str | Path, report: dict[str, Any], *, stats: dict[str, Any]) -> None:
    path = Path(path)
    text = markdown(report, stats=stats, run_dir=path.parent)
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text)


def _plan_rows(plan_round: dict[str, Any] | None) -> list[str]:
    """The plan round's section: what was played, on how many machines, and the first solve."""
    if plan_round is None:
        return []
    plan = plan_round["plan"]
    played = {
        "played": f"the first solve's {plan['played']['profile']} torque (round-0/ocp.json), "
        f"dither {plan['dither']:g} N·m, on {plan['episodes']} "
        + (
            "fresh machines"
            if plan.get("fresh_machines", True)
            else f"episodes of the dataset's {plan['machines']} machines"
        ),
        "samples added": f"{plan['samples_added']} (dataset after the round: {plan['samples']})",
    }
    if plan_round.get("first_tail_refused"):
        played["first solve's own-tail check"] = (
            f"refused ({plan_round['first_tail_refused']}); the round played the loop's torque "
            "without the check (it is never returned)"
        )
    first = {f"first solve: {k}": v for k, v in plan_round["first_solve"].items()}
    return _rows("Plan round (the model and OCP above are its second round)", played | first)


def _wall(report: dict[str, Any]) -> dict[str, str]:
    """Each stage's measured seconds beside the range estimated before it ran."""
    estimated = report["estimated_seconds"]
    out = {}
    for stage, seconds in report["wall_seconds"].items():
        low, high = estimated.get(stage, (None, None))
        if low is None:
            out[stage] = f"{seconds:.1f}"
        else:
            span = f"{low:.0f}" if low == high else f"{low:.0f}-{high:.0f}"
            out[stage] = f"{seconds:.1f} ({span})"
    return out
