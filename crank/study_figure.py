"""`study.png`, and the calibration panel `crank sweep`'s figure shares with it: per training
seed the robust torque's held-out violation rate with its 95 % bound, its cost premium, and the
predicted / observed σ of the slider at each constraint sample with the interval the held-out
machines allow, against the 0.8-1.25 band issue 11 aims at."""

from __future__ import annotations

import re
from typing import Any

from matplotlib.figure import Figure

from control.config import loop_of
from control.figures import COLORS
from crank.report_heldout import diverged
from ppann.figures import CALIBRATION_BAND
from replay.rates import TARGET_RATE as TARGET_HELDOUT_RATE


def solved_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The rows whose profile has a torque (no error, a premium), checked on held-out machines
    or not (heldout_runs = 0 skips the check): the study's and the sweep's figures and tables."""
    return [r for r in rows if not r.get("error") and r.get("premium") is not None]


def figure(rows: list[dict[str, Any]]) -> Figure:
    """Violation rates (held-out, with the 95 % bound), cost premium, and predicted / observed
    σ of the slider at each constraint sample with its 95 % interval against the 0.8-1.25 band
    (issue 11's rows) against seed; where a profile was refused beyond the stroke, the
    tightening its model asked for against the stroke left (a seed red where no profile, nor a
    fallback, has a torque). A run without the held-out check (`--heldout-runs 0`) has its
    premium drawn and says so in the two held-out panels."""
    solved = solved_rows(rows)
    ok = [r for r in solved if "robust_heldout_rate" in r]
    refused = [r for r in rows if "refused_tightening" in r]
    panels = 3 + bool(refused)
    fig = Figure(figsize=(10, 3 * panels), layout="constrained")
    axes = fig.subplots(panels, 1, sharex=True)
    top, bottom, calibration = axes[0], axes[1], axes[2]
    samples: dict[str, str] = {}  # constraint sample -> colour, in the order met
    names = list(dict.fromkeys(r["profile"] for r in solved))
    width = 0.8 / max(1, len(names))
    upper: list[float] = []
    for i, name in enumerate(names):  # side by side per seed
        offset = (i - (len(names) - 1) / 2) * width
        color = COLORS[name]
        label = f"{name} ({loop_of(name)} loop)"
        mine = [r for r in solved if r["profile"] == name]
        x = [r["seed"] + offset for r in mine]
        bottom.bar(x, [100 * r["premium"] for r in mine], width, color=color, label=label)
        mine = [r for r in ok if r["profile"] == name]
        x = [r["seed"] + offset for r in mine]
        bounds = [100 * r["robust_heldout_upper_95"] for r in mine]
        upper += bounds
        rates = [100 * r["robust_heldout_rate"] for r in mine]
        if mine:  # an empty bar's legend entry would not take the colour
            top.bar(x, rates, width, color=color, label=label)
        top.scatter(x, bounds, color="k", marker="_", s=200 * width)
        for at, bound, row in zip(x, bounds, mine, strict=True):
            _count_label(top, at, bound, row, turned=len(names) > 1)
        for at, row in zip(x, mine, strict=True):
            calibration_marks(calibration, at, row, samples)
    top.scatter([], [], color="k", marker="_", label="95 % upper bound")
    top.axhline(100 * TARGET_HELDOUT_RATE, color="k", ls="--", lw=1, label="target 0.5 %")
    # a seed whose every profile was refused (a fallback's torque is a profile)
    failed = sorted({r["seed"] for r in rows if r.get("error")} - {r["seed"] for r in solved})
    for s in failed:
        top.axvline(s, color="C3", alpha=0.3, lw=8)
    top.set_ylim(0, max([100 * TARGET_HELDOUT_RATE * 1.2, *upper]) * 1.3)  # the counts above
    top.set_ylabel("held-out violations [%]")
    top.legend(fontsize=8)
    bottom.set_ylim(bottom=0)
    bottom.set_ylabel("robust cost premium [%]")
    calibration_frame(calibration, samples)
    empty = {}
    if not solved:
        empty = dict.fromkeys((top, bottom, calibration), "no seed has a robust profile")
    elif not ok:
        empty = dict.fromkeys((top, calibration), "no held-out check (--heldout-runs 0)")
        bottom.legend(fontsize=8)  # the profiles' colours, which the first panel has not
    for axis, text in empty.items():
        axis.text(0.5, 0.5, text, transform=axis.transAxes, ha="center", va="center", color="C3")
    if refused:
        axis = axes[3]
        x = [r["seed"] for r in refused]
        asked = [1e3 * r["refused_tightening"] for r in refused]
        line = [1e3 * r["refused_line"] for r in refused]
        axis.bar(x, asked, color="C3", alpha=0.6, label="tightening the model asks for")
        axis.bar(x, line, color="C4", label="of which for the line's mean")
        axis.scatter(
            x,
            [1e3 * r["refused_available"] for r in refused],
            color="k",
            marker="_",
            s=400,
            label="stroke above the height",
        )
        what = "/".join(dict.fromkeys(r["profile"] for r in refused))
        axis.set_ylabel(f"{what} refused: sample {refused[0]['refused_sample']} [mm]")
        axis.legend(fontsize=8)
    axes[-1].set_xticks(sorted({r["seed"] for r in rows}))
    axes[-1].set_xlabel("seed" + (" (red: no robust profile)" if failed else ""))
    fig.suptitle("Robust torque per training seed")
    return fig


def _count_label(axis: Any, x: float, bound: float, row: dict[str, Any], *, turned: bool) -> None:
    """The machines below out of those played ("0/2000"), over the 95 % bound's mark (a rate of
    0 is a bar nobody sees); `turned` upright, for profiles side by side."""
    runs = row.get("heldout_runs")
    if not runs:
        return
    below = round(row["robust_heldout_rate"] * runs)
    axis.annotate(
        f"{below}/{runs}",
        (x, bound),
        xytext=(0, 4),
        textcoords="offset points",
        ha="center",
        va="bottom",
        rotation=90 if turned else 0,
        fontsize=7,
    )


def calibration_marks(ax: Any, at: float, row: dict[str, Any], samples: dict[str, str]) -> None:
    """A row's slider ratio at each of its constraint samples with its 95 % interval (study.csv's
    and sweep.csv's ratio_<k>, ratio_<k>_low, ratio_<k>_high; a ratio without an interval
    alone, none where it diverged, crank/report_heldout.py's rule), side by side at `at`."""
    ks = [key[len("ratio_") :] for key in row if re.fullmatch(r"ratio_\d+", key)]
    for i, k in enumerate(ks):
        value = row.get(f"ratio_{k}")
        if diverged(value):
            continue
        colour = samples.setdefault(k, f"C{2 + len(samples) % 8}")
        low, high = row.get(f"ratio_{k}_low"), row.get(f"ratio_{k}_high")
        error = None if low is None or high is None else [[value - low], [high - value]]
        x = at + 0.04 * (i - (len(ks) - 1) / 2)
        ax.errorbar([x], [value], yerr=error, color=colour, fmt="o", ms=4, capsize=2)


def calibration_frame(ax: Any, samples: dict[str, str]) -> None:
    """The calibration panel's band (0.8-1.25, the issue's target), the line at 1 and the legend
    of `samples` (constraint sample -> colour, as `calibration_marks` filled it), beside the
    panel: inside, with many tasks' samples it covered their points."""
    ax.axhspan(*CALIBRATION_BAND, color="0.9", zorder=0)
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_ylabel("predicted / observed σ,\nslider (OCP's mode)")
    ax.legend(
        handles=[
            ax.errorbar([], [], yerr=[], color=c, fmt="o", ms=4, label=f"sample {k}")
            for k, c in samples.items()
        ]
        + [ax.fill_between([], [], color="0.9", label="0.8-1.25")],
        fontsize=8,
        loc="upper left",
        bbox_to_anchor=(1.005, 1.0),
    )
