"""Figures of a solved OCP: nominal (paper Fig. 10) and robust against nominal (Fig. 11)."""

from __future__ import annotations

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from control.ocp_file import OCPFile, Profile
from twin.geometry import Geometry


def predicted_band(
    profile: Profile, sigma: np.ndarray, k_sigma: float, *, geometry: Geometry
) -> tuple[np.ndarray, np.ndarray]:
    """The PPANN's slider ∓ k `sigma` about the profile's plan, (N,) each, within `geometry`'s
    stroke; for drawing, not for statistics. `sigma`: the profile's in a loop
    (Profile.sigma_in) or a replay's under the law it played (Replay.predicted_sigma)."""
    clip = geometry.within_stroke
    return clip(profile.slider - k_sigma * sigma), clip(profile.slider + k_sigma * sigma)


def constraint_boxes(ax: Axes, ocp: OCPFile, heights: list[float] | None = None) -> None:
    """Shade the forbidden region below each constraint sample's height."""
    c = ocp.config
    for i, k in enumerate(c.constraint_samples):
        t = (k - 1) * ocp.dt
        h = c.height if heights is None else heights[i]
        ax.vlines(t, -0.005, h, color="k", lw=2.5, label="constraint" if i == 0 else None)
        ax.plot([t], [h], "kv", ms=7)


def _slider(
    ax: Axes, ocp: OCPFile, profile: Profile, color: str, label: str, *, loop: str | None = None
) -> None:
    """The profile's mean slider and its ±kσ band in `loop` (default: the loop it was sized
    for)."""
    # the k the profile was solved with (its own tail's check may have raised it)
    k = ocp.raw.get(label, {}).get("k_sigma", ocp.config.k_sigma)
    loop = loop or profile.loop
    ax.plot(profile.time, profile.slider, color=color, label=f"{label}: mean PPANN")
    lower, upper = predicted_band(profile, profile.sigma_in(loop), k, geometry=ocp.geometry)
    # the trajectories its last decision drew (control/profiles.py may draw more than configured)
    runs = ocp.raw.get(label, {}).get("mc_samples", ocp.config.mc_samples)
    ax.fill_between(
        profile.time,
        lower,
        upper,
        color=color,
        alpha=0.2,
        label=f"{label}: ±{k:g}σ {loop} loop (Monte-Carlo, {runs} runs; within the stroke)",
    )


def torque_limits(ax: Axes, ocp: OCPFile) -> None:
    """The OCP's torque bounds ±limit as dashed lines."""
    limit = ocp.config.torque_limit
    for sign in (1, -1):
        ax.axhline(
            sign * limit, color="0.4", ls="--", lw=1, label="torque limit" if sign > 0 else None
        )


def nominal_figure(ocp: OCPFile) -> Figure:
    """Fig. 10: the nominal torque and its slider position with the ±kσ band."""
    fig = Figure(figsize=(9, 6), layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True)
    top.plot(ocp.nominal.time, ocp.nominal.tau, color="C0", label="nominal")
    torque_limits(top, ocp)
    top.legend(fontsize=8)
    top.set_ylabel("τ [N·m]")
    top.set_title(f"Nominal OCP on the mean PPANN (cost {ocp.nominal.cost:.4g})")
    _slider(bottom, ocp, ocp.nominal, "C0", "nominal")
    constraint_boxes(bottom, ocp)
    bottom.set_ylabel("slider position [m]")
    bottom.set_xlabel("t [s]")
    bottom.legend(loc="lower center", fontsize=8)
    return fig


TITLES = {
    "robust": "Robust OCP tightened for the open loop",
    "robust-fb": "Robust OCP tightened for the LQR closed loop (a tube)",
    "robust-pd": "Robust OCP tightened for the fixed-PD closed loop (a tube)",
}
TIGHTENING_WORDS = {
    "centred": "k·σ below the Monte-Carlo's mean",
    "gaussian": "eq. 16, k·σ below the plan",
    "quantile": "the Monte-Carlo's Φ(−k) quantile",
}
"""How each tightening (control/tightening.py) is named in the robust figure's title."""
COLORS = {"nominal": "C0", "robust": "C3", "robust-fb": "C2", "robust-pd": "C4"}


def robust_figure(ocp: OCPFile, name: str) -> Figure:
    """Fig. 11: nominal and the robust profile `name`'s torque; the slider position with its ±kσ
    band in the loop it was tightened for, and the margins of each of its robust iterations."""
    fig = Figure(figsize=(9, 8), layout="constrained")
    top, middle, bottom = fig.subplots(3, 1, height_ratios=(1, 1.3, 0.8))
    robust = ocp.profiles[name]
    top.plot(ocp.nominal.time, ocp.nominal.tau, color=COLORS["nominal"], label="nominal")
    top.plot(robust.time, robust.tau, color=COLORS[name], label=name)
    torque_limits(top, ocp)
    top.set_ylabel("τ [N·m]")
    method = ocp.raw[name].get("tightening_method", ocp.config.tightening)
    how = TIGHTENING_WORDS.get(method, method)
    checks = ocp.raw[name].get("tail_checks", [])
    tail = ""
    if checks:  # control/tail.py: the returned torque's own tail; the one before it, if re-solved
        ahead = [c for c in checks if c.get("draft")]  # its loop's draft, before the returned one
        checks = [c for c in checks if not c.get("draft")] or checks
        last = checks[-1]
        read = f"line sampling, {last['draws']} lines; " if last.get("sampling") == "lines" else ""
        tail = (
            f"\nits own Monte-Carlo, with the allowances, {100 * last['rate']:.2f} % below the "
            f"height ({read}target {100 * last['target']:g} %)"
        )
        if ahead and ahead[0]["k_sigma"] != checks[0]["k_sigma"]:
            tail += (
                f"\nk raised to {checks[0]['k_sigma']:g} before its full solve: its draft at k "
                f"{ahead[0]['k_sigma']:g} had {100 * ahead[0]['rate']:.2f} %"
            )
        if len(checks) > 1:
            first = checks[0]
            now = (
                f"at k {last['k_sigma']:g}"
                if last["tightening"] == first["tightening"]
                else "with this tightening"
            )
            tail += (
                f"\nsolved again {now}: the {first['tightening']} torque at k "
                f"{first.get('k_sigma', ocp.config.k_sigma):g} had {100 * first['rate']:.2f} %"
            )
    top.set_title(
        f"{TITLES[name]} ({how}): cost {robust.cost:.4g}, {ocp.premium(name):+.1%} over nominal"
        + tail,
        fontsize=10,
    )
    top.legend(fontsize=8)
    _slider(middle, ocp, ocp.nominal, COLORS["nominal"], "nominal", loop=robust.loop)
    _slider(middle, ocp, robust, COLORS[name], name)
    constraint_boxes(middle, ocp)
    middle.set_ylabel("slider position [m]")
    middle.set_xlabel("t [s]")
    middle.legend(loc="lower center", fontsize=7)
    iterations = [it for it in ocp.raw.get("robust_iterations", []) if it["profile"] == name]
    schemes = {it.get("scheme", "bracket") for it in iterations}
    kept = "kept (aware) or used" if len(schemes) > 1 else "kept" if "aware" in schemes else "used"
    for i, k in enumerate(ocp.config.constraint_samples):
        margins = [1e3 * it["margin"][i] for it in iterations]
        sigmas = [1e3 * it["tightening"][i] for it in iterations]
        errors = [1e3 * it.get("tightening_se", [0.0] * (i + 1))[i] for it in iterations]
        steps = range(1, len(iterations) + 1)
        bottom.plot(steps, margins, "o-", color=f"C{i}", label=f"margin {kept}, sample {k}")
        bottom.errorbar(
            steps,
            sigmas,
            yerr=errors,
            fmt="x--",
            color=f"C{i}",
            capsize=3,
            label=f"tightening its solution asks (± s.e.; {method} and allowances), sample {k}",
        )
    full = [step for step, it in enumerate(iterations, 1) if not it.get("draft", False)]
    for step in full:
        bottom.axvline(step, color="0.6", lw=0.8, ls=":")
    scheme = " then ".join(sorted(schemes))  # aware, then the bracket it hands over to
    bottom.set_xlabel(f"robust iteration, {scheme} margins (dotted: full solve, others drafts)")
    bottom.xaxis.set_major_locator(MaxNLocator(integer=True))  # solves: no 1.5
    bottom.set_ylabel("[mm]")
    bottom.legend(fontsize=7)
    return fig
