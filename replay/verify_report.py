"""`crank verify`'s files: `verify.json` (replay/verify.py), `verify.md` (what the runs showed, in
words and tables) and `verify.png` (every run's slider against the plan's band, the torques, and
each constraint sample's runs beside the prediction)."""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from common.atomic import atomic_path, writes
from common.errors import ConfigError
from common.figures import save_figure
from common.jsonio import write_json
from control.figures import COLORS, constraint_boxes, predicted_band
from control.ocp_file import OCPFile, read_ocp
from replay.rates import verdict_text
from replay.verify import (
    ALIGNS,
    PLAYED_TOLERANCE,
    RigRuns,
    check_data,
    line_up,
    verify_statistics,
)
from replay.verify_split import spread_split
from replay.verify_tables import mm_text, sample_rows, spread_sections, table_lines
from twin.mcap_dataset import read_dataset

MAX_PER_SAMPLE = 64
"""The fastest controller `--control-rate` takes, in evaluations of the law a sample (32 kHz
at the plan's 500 Hz)."""


def output_paths(out: str | Path) -> dict[str, Path]:
    """Every file `crank verify` writes, by kind: the JSON at `out`, the report and figure beside
    it."""
    out = Path(out)
    return {"json": out, "report": out.with_suffix(".md"), "figure": out.with_suffix(".png")}


def claim_text(stats: dict[str, Any]) -> str:
    """The verdict in one sentence (replay/rates.py's, said of runs)."""
    o = stats["ocp"]
    count, total = stats["violating_runs"], len(stats["runs"])
    at = ", ".join(map(str, o["constraint_samples"]))
    below = f"{count} of {total} runs below {o['height']:g} m at samples {at}"
    if stats["verdict"] is None:
        return f"{below}; the nominal profile claims nothing"
    said = verdict_text(count, total, target=stats["target_rate"], of="runs")
    return f"{below}: profile {o['profile']} {said}"


def report_markdown(stats: dict[str, Any], paths: dict[str, Path]) -> str:
    """verify.md: the verdict, the constraint samples, each run, and how to read them."""
    o, d = stats["ocp"], stats["data"]
    total = len(stats["runs"])
    runs = [
        {
            "run": str(i),
            "episode": str(r["episode"]),
            "from s": f"{r['start_s']:.3f}",
            "played RMS N·m": f"{r['played_rms']:.3g}",
            "θ RMS rad": f"{r['theta_rms']:.3g}",
            **{f"slider@{k} mm": mm_text(v) for k, v in r["slider"].items()},
            "below": "yes" if r["below"] else "no",
            **({} if stats["machines"] is None else {"machine": str(r["machine"])}),
        }
        for i, r in enumerate(stats["runs"], start=1)
    ]
    slider = (
        "measured"
        if d["slider"] == "measured"
        else "**not measured**: x(θ) of the motor angle, rigid and backlash-free; the constraint "
        "is on the slider, which these runs did not see"
    )
    lines = [
        f"# crank verify: profile {o['profile']} on {total} recorded runs",
        "",
        f"**{claim_text(stats)}.**",
        "",
        f"- Plan: `{o['path']}` (sha256 `{o['sha256'][:12]}…`), profile {o['profile']}, "
        f"tightened for the {o['loop']} loop, premium {100 * o['premium']:+.1f} %.",
        f"- Runs: `{d['path']}` ({d['source'] or 'no source'}"
        + (f", from `{d['input']}`" if d["input"] else "")
        + f"), {total} episodes; slider {slider}.",
        f"- Each run lined up by its {stats['align']} and checked to have played the "
        f"{o['loop']} loop's law"
        + (f" at {stats['control_rate_hz']:g} Hz" if o["loop"] == "closed" else "")
        + f" within {stats['played_tolerance']:g} of the "
        f"{o['torque_limit']:g} N·m limit (RMS).",
        "- The runs measure the spread, within the intervals below. The PPANN's σ is the "
        "product line's (machine to machine and run to "
        "run): runs on one machine show its run-to-run spread alone, a smaller one (a ratio "
        "above 1), and its mean offset says where that machine sits in the line.",
        "",
        "## At the constraint samples",
        "",
        *table_lines(sample_rows(stats)),
        "",
        f"σ pred/obs: the PPANN's Monte-Carlo σ in the {o['loop']} loop over the runs' (95 % "
        "bootstrap interval over the runs); mean offset: the runs' mean slider minus the "
        "predicted one, in predicted σ.",
        "",
        *spread_sections(stats),
        "## Runs",
        "",
        *table_lines(runs),
        "",
        f"Files: `{paths['json'].name}` (every number here), "
        + (f"`{paths['figure'].name}`." if paths.get("figure") else "no figure (--no-figures)."),
        "",
    ]
    return "\n".join(lines)


def verify_figure(ocp: OCPFile, runs: RigRuns, stats: dict[str, Any]) -> Figure:
    """Left: every run's slider against the plan's ±kσ band in its loop, the torques below;
    right: each constraint sample's runs beside the predicted mean ± kσ and the height."""
    o = stats["ocp"]
    plan, name = ocp.profiles[o["profile"]], o["profile"]
    k = o["k_sigma"]
    samples = o["constraint_samples"]
    fig = Figure(figsize=(12, 6.5), layout="constrained")
    grid = fig.add_gridspec(2, 1 + len(samples), width_ratios=(4, *[1] * len(samples)))
    slider_ax, torque_ax = fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[1, 0])
    n = runs.theta.shape[1]
    t = np.arange(n) * ocp.dt
    below = np.array([r["below"] for r in stats["runs"]])
    machines = stats["machines"]
    if machines is not None:
        machine_of_run = np.array([machines["labels"].index(r["machine"]) for r in stats["runs"]])
    color = COLORS.get(name, "C3")
    lower, upper = predicted_band(plan, plan.sigma_in(plan.loop), k, geometry=ocp.geometry)
    slider_ax.fill_between(
        plan.time, lower, upper, color=color, alpha=0.2, label=f"PPANN ±{k:g}σ ({plan.loop} loop)"
    )
    slider_ax.plot(plan.time, plan.slider, color=color, lw=1.2, label="PPANN mean")
    for rows, shade, label in ((~below, "k", "runs"), (below, "C3", "runs below")):
        if rows.any():
            lines = slider_ax.plot(t, runs.slider[rows].T, color=shade, lw=0.6, alpha=0.6)
            lines[0].set_label(f"{label} ({rows.sum()})")
    constraint_boxes(slider_ax, ocp)
    slider_ax.set_ylim(-0.005, ocp.geometry.stroke_top + 0.005)
    slider_ax.set_ylabel("slider position [m]")
    title = claim_text(stats).replace(" %", "\u00a0%")  # "95 %" kept on one line
    fig.suptitle("\n".join(textwrap.wrap(title, 120)), fontsize=10)
    slider_ax.legend(loc="lower right", fontsize=7)
    torque_ax.plot(t, runs.tau.T, color="k", lw=0.5, alpha=0.5)
    torque_ax.plot(plan.time, plan.tau, color=color, lw=1.2, label=f"{name}: planned")
    torque_ax.set_xlabel("t [s]")
    torque_ax.set_ylabel("torque applied [N·m]")
    torque_ax.set_title(f"each run's applied torque ({o['loop']} loop)", fontsize=9)
    torque_ax.legend(loc="lower right", fontsize=7)
    for column, sample in enumerate(samples, start=1):
        ax = fig.add_subplot(grid[:, column])
        s = stats["samples"][str(sample)]
        values = runs.slider[:, sample - 1]
        spread = np.random.default_rng(0).uniform(-0.25, 0.25, len(values))  # only to see them
        ticks, names = [0.0], ["runs"]
        if machines is not None:  # a narrow column per machine, in the order they are named
            width = 0.8 / len(machines["labels"])
            ticks = list(-0.5 + width * (np.arange(len(machines["labels"])) + 0.5))
            names = machines["labels"]
            spread = -0.5 + width * (machine_of_run + 0.5 + 0.6 * spread)
            ax.set_xlabel("runs by machine", fontsize=8)
        ax.scatter(spread, 1e3 * values, s=12, c=np.where(below, "C3", "k"), zorder=3)
        mean, sigma = s["predicted_mean"], s["predicted_sigma"]
        low, high = ocp.geometry.within_stroke(np.array([mean - k * sigma, mean + k * sigma]))
        ax.errorbar(
            [0.6], [1e3 * mean], yerr=[[1e3 * (mean - low)], [1e3 * (high - mean)]], fmt="o",
            color=color, capsize=4, label=f"PPANN mean ±{k:g}σ",
        )  # fmt: skip
        ax.axhline(1e3 * s["height"], color="k", ls="--", lw=1, label="height")
        ax.set_xlim(-0.6 if machines is None else -0.55, 1.0)
        ax.set_xticks([*ticks, 0.6], [*names, "PPANN"])
        floor = min(s["height"], s["lowest"], low)
        ax.set_ylim(1e3 * floor - 2.0, 1e3 * max(values.max(), high) + 1.0)
        ax.set_title(f"sample {sample}: {s['below']} below", fontsize=9)
        ax.set_ylabel("slider position [mm]")
        if column == 1:
            ax.legend(loc="lower left", fontsize=7)
    return fig


def evaluations_per_sample(control_rate: float | None, dt: float) -> int:
    """How many times a sample a controller at `control_rate` Hz evaluates the law (1: None).

    Raises:
      ConfigError: not a whole multiple of the plan's rate, or above MAX_PER_SAMPLE of it.
    """
    if control_rate is None:
        return 1
    plan = 1.0 / dt
    m = round(control_rate / plan) if np.isfinite(control_rate) else 0
    if not (1 <= m <= MAX_PER_SAMPLE and abs(control_rate - m * plan) <= 1e-9 * control_rate):
        raise ConfigError(
            f"--control-rate must be a whole multiple of the plan's {plan:g} Hz up to "
            f"{MAX_PER_SAMPLE * plan:g} Hz ({plan:g}, {2 * plan:g}, ...), got {control_rate}"
        )
    return m


@writes("out", inputs=("ocp_path", "data_path", "ppann"), suffix=".json")
def verify_file(
    ocp_path: str | Path,
    data_path: str | Path,
    out: str | Path,
    *,
    profile: str | None = None,
    align: str = "start",
    played_tolerance: float = PLAYED_TOLERANCE,
    control_rate: float | None = None,
    ppann: str | Path | None = None,
    figures: bool = True,
) -> dict[str, Any]:
    """Check the runs recorded in `data_path` (a dataset MCAP, one episode per run) against
    profile `profile` of `ocp_path` (default: its first robust one); write verify.json at `out`
    and verify.md, verify.png beside it; return the statistics. `control_rate` (Hz, a whole
    multiple of the plan's; default the plan's): the rate the runs' controller evaluated the
    closed-loop law at (replay/played_law.py). The spread is split into its
    white and machine parts with the plan's PPANN: `ppann`, which must be the checkpoint the
    plan names (sha256), or that checkpoint if it is there (else no split).

    Raises:
      OCPFileError, ContractError: an input is not what it should be. ConfigError: a bad option,
        no such profile, another rate. GeometryError: another mechanism. VerifyError: a run too
        short or one that did not play the profile's law.
    """
    from control.export import chosen_profile
    from replay.files import plan_model_path, prediction_model

    if align not in ALIGNS:
        raise ConfigError(f"--align must be one of {', '.join(ALIGNS)}, got {align!r}")
    if not (np.isfinite(played_tolerance) and 0 < played_tolerance <= 1):
        raise ConfigError(
            f"--played-tolerance must be within (0, 1] of the torque limit, got {played_tolerance}"
        )
    ocp_path, data_path = Path(ocp_path), Path(data_path)
    ocp = read_ocp(ocp_path)
    per_sample = evaluations_per_sample(control_rate, ocp.dt)
    name = chosen_profile(ocp, ocp_path, profile)
    dataset = read_dataset(data_path)
    check_data(dataset, ocp, source=str(data_path))
    runs = line_up(
        dataset,
        ocp,
        profile=name,
        align=align,
        played_tolerance=played_tolerance,
        per_sample=per_sample,
    )
    model = prediction_model(ocp_path, override=ppann, ocp=ocp)
    split = None if model is None else spread_split(ocp, name, model)
    stats = verify_statistics(
        ocp,
        runs,
        profile=name,
        ocp_path=ocp_path,
        data_path=data_path,
        dataset=dataset,
        align=align,
        played_tolerance=played_tolerance,
        per_sample=per_sample,
        out=Path(out),
        model_path=None if model is None else plan_model_path(ocp_path, override=ppann, ocp=ocp),
        split=split,
    )
    paths = output_paths(out)
    if not figures:
        del paths["figure"]
    write_json(paths["json"], stats)
    with atomic_path(paths["report"]) as tmp:
        tmp.write_text(report_markdown(stats, paths), encoding="utf-8")
    if figures:
        save_figure(verify_figure(ocp, runs, stats), paths["figure"])
    else:  # a figure of an earlier check would stand beside this one's numbers
        output_paths(out)["figure"].unlink(missing_ok=True)
    return stats
