"""Paper Fig. 12 for a campaign: every run's slider position against the constraint, one column
per profile (nominal, robust, robust-fb), one row per mode, and the torques actually applied."""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.figure import Figure

from control.figures import COLORS, constraint_boxes, predicted_band
from control.ocp_file import OCPFile
from replay.campaign import Campaign
from replay.laws import closed_loop_gains


def replay_figure(campaign: Campaign, ocp: OCPFile, stats: dict[str, Any]) -> Figure:
    """Rows: slider position per mode, then torque; columns: the profiles of `ocp`."""
    modes = campaign.config.modes
    names = ocp.names
    fig = Figure(figsize=(5.5 * len(names), 3.2 * (len(modes) + 1)), layout="constrained")
    axes = fig.subplots(len(modes) + 1, len(names), sharex=True, squeeze=False)
    t = np.arange(ocp.horizon) * ocp.dt
    k = ocp.config.k_sigma
    top = ocp.geometry.within_stroke
    for col, profile in enumerate(names):
        color = COLORS[profile]
        planned = ocp.profiles[profile]
        for row, mode in enumerate(modes):
            ax = axes[row, col]
            replay = campaign.replays[profile, mode]
            s = stats["profiles"][profile][mode]
            ax.plot(t, replay.slider_position.T, color=color, lw=0.4, alpha=0.35)
            if replay.predicted_sigma is not None:  # the law played: open, closed, the MPC's LQR
                lower, upper = predicted_band(
                    planned, replay.predicted_sigma, k, geometry=ocp.geometry
                )
                loop = "its LQR" if mode == "mpc" else f"{mode} loop"
                ax.fill_between(
                    t, lower, upper, color="k", alpha=0.12, label=f"PPANN ±{k:g}σ ({loop})"
                )
            ax.plot(t, s["slider"]["mean"], color="k", lw=1.2, label="twin mean")
            for side, label in (("lower", f"twin ±{k:g}σ (within the stroke)"), ("upper", None)):
                ax.plot(t, top(s["slider"][side]), "k--", lw=0.8, label=label)
            constraint_boxes(ax, ocp)
            if mode != "open":  # feedback keeps every run near the plan: show the constraint
                ax.set_ylim(ocp.config.height - 0.005, ocp.geometry.stroke_top + 0.002)
            else:
                ax.set_ylim(-0.005, ocp.geometry.stroke_top + 0.005)
            shown = ", ".join(f"{v} at k={n}" for n, v in s["violations"].items())
            title = f"{mode} loop"
            if mode == "closed":  # a PD applies the same gains at every sample, an LQR does not
                gains = closed_loop_gains(planned, campaign.config)
                title = f"closed loop ({'PD' if np.all(gains == gains[0]) else 'LQR'})"
            if "mpc" in s:
                title = f"MPC, {s['mpc']['median_ms']:.2f} ms/step"
            ax.set_title(f"{profile}, {title}: {shown} of {s['runs']} below", fontsize=10)
            ax.set_ylabel("slider position [m]")
            if row == 0 and col == 0:
                ax.legend(loc="lower right", fontsize=7)
        ax = axes[-1, col]
        for mode, style in zip(modes, ("-", ":", "--"), strict=False):
            applied = campaign.replays[profile, mode].tau
            ax.fill_between(t, applied.min(axis=0), applied.max(axis=0), color=color, alpha=0.2)
            ax.plot(
                t,
                applied.mean(axis=0),
                style,
                color=color,
                lw=1,
                label=f"{'MPC' if mode == 'mpc' else mode + ' loop'} (mean, range)",
            )
        ax.plot(t, planned.tau, color="k", lw=1, label="planned")
        ax.set_ylabel("τ applied [N·m]")
        ax.set_xlabel("t [s]")
        ax.legend(fontsize=7)
    return fig
