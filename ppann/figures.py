"""Figures of a trained PPANN: network maps (paper Fig. 7), validation (Fig. 8), Monte-Carlo bands
(Fig. 9), and predicted against observed σ on the twin."""

from __future__ import annotations

import numpy as np
import torch
from matplotlib.figure import Figure

from ppann.model import PPANN, Z_NAMES
from ppann.montecarlo import Bands
from ppann.report import TwinReplay

CALIBRATION_BAND = (0.8, 1.25)
"""The predicted / observed σ the calibration aims at (issue 11), drawn as a band."""


def network_maps(model: PPANN) -> Figure:
    """z_mu and z_sigma of J and K against theta; of B over (theta, omega)."""
    theta = np.linspace(0, 2 * np.pi, 181)
    omega = np.linspace(-80, 80, 121)
    fig = Figure(figsize=(13, 7), layout="constrained")
    axes = fig.subplots(2, 3)
    tg, wg = np.meshgrid(theta, omega)
    with torch.no_grad():
        t, w = torch.from_numpy(tg.ravel()), torch.from_numpy(wg.ravel())
        mean = model.z_mean(t, w).numpy().reshape(*tg.shape, 3)
        sigma = model.z_sigma(t, w).numpy().reshape(*tg.shape, 3)
    for row, (values, label) in enumerate(((mean, r"\mu"), (sigma, r"\sigma"))):
        for col, name in enumerate(Z_NAMES):
            ax = axes[row, col]
            i = Z_NAMES.index(name)
            if name == "B":
                image = ax.pcolormesh(
                    theta, omega, values[..., i], cmap="coolwarm" if row == 0 else "viridis"
                )
                fig.colorbar(image, ax=ax)
                ax.set_ylabel("ω [rad/s]")
            else:
                ax.plot(theta, values[0, :, i])
                ax.set_ylabel(f"$z^{{{label} {name}}}$")
            kind = "mean network" if row == 0 else "sigma network"
            ax.set_title(f"$z^{{{label} {name}}}$ ({kind}, eq. {14 if row == 0 else 9})")
            ax.set_xlabel("θ mod 2π [rad]")
    return fig


def validation(t: np.ndarray, measured: np.ndarray, predictions: dict[str, np.ndarray]) -> Figure:
    """Measured theta and omega against each model's free run."""
    fig = Figure(figsize=(12, 6), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    for i, label in enumerate(("θ [rad]", "ω [rad/s]")):
        axes[i].plot(t, measured[:, i], "k", lw=1.5, label="twin (measured)")
        for name, p in predictions.items():
            axes[i].plot(t, p[:, i], lw=1, label=name)
        axes[i].set_ylabel(label)
    axes[0].legend(loc="best")
    axes[1].set_xlabel("t [s]")
    fig.suptitle("Free run over the validation split")
    return fig


BAND_MODES = ("step", "mixed")
"""Modes drawn in the band figure (paper eq. 11 and the machine-level model)."""
RATIO_MODES = ("step", "machine", "mixed")
"""Modes drawn in the calibration figure. "trajectory" is left out of both figures: its draws can
diverge (a negative damping), and its numbers are in model.report.json (null where diverged)."""


def _finite(band: Bands) -> bool:
    return bool(np.all(np.isfinite(band.std)))


def monte_carlo_bands(
    t: np.ndarray, measured: np.ndarray, bands: dict[str, Bands], replay: TwinReplay | None
) -> Figure:
    """Measured data, PPANN mean ± 3σ per draw mode, and the twin's observed ± 3σ (none for
    rig data: no twin)."""
    fig = Figure(figsize=(12, 6), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    for i, label in enumerate(("θ [rad]", "ω [rad/s]")):
        ax = axes[i]
        ax.plot(t, measured[:, i], "k", lw=1.2, label="validation data")
        shown = [(m, bands[m]) for m in BAND_MODES if m in bands and _finite(bands[m])]
        for (mode, b), color in zip(shown, ("C0", "C1"), strict=False):
            ax.plot(t, b.mean[:, i], color=color, lw=1, label=f"PPANN mean ({mode} draws)")
            ax.fill_between(
                t,
                b.mean[:, i] - 3 * b.std[:, i],
                b.mean[:, i] + 3 * b.std[:, i],
                color=color,
                alpha=0.2,
                label=f"±3σ ({mode})",
            )
        if i == 0 and replay is not None:
            n = replay.theta.shape[1]
            twin_mean, twin_std = replay.theta.mean(0), replay.theta.std(0, ddof=1)
            ax.fill_between(
                t[:n],
                twin_mean - 3 * twin_std,
                twin_mean + 3 * twin_std,
                color="C2",
                alpha=0.25,
                label="twin ±3σ (100 machines)",
            )
        ax.set_ylabel(label)
    axes[0].legend(loc="best", fontsize=8)
    axes[1].set_xlabel("t [s]")
    fig.suptitle("Monte-Carlo uncertainty on the validation split")
    return fig


def sigma_ratio(t: np.ndarray, bands: dict[str, Bands], replay: TwinReplay) -> Figure:
    """σ(θ) predicted by each draw mode against σ(θ) observed on the twin, and their ratio with
    the 0.8-1.25 band the calibration aims at. The first 20 ms (every run starts from the same
    state, σ ~ 0) are left out."""
    fig = Figure(figsize=(10, 6), layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True)
    n = replay.theta.shape[1]
    start = min(10, n - 1)
    observed = replay.theta.std(0, ddof=1)
    top.semilogy(t[start:n], observed[start:], "k", label="observed on the twin")
    bottom.axhspan(*CALIBRATION_BAND, color="0.9", label="0.8-1.25")
    bottom.axhline(1.0, color="k", lw=0.8)
    for mode in RATIO_MODES:
        if mode in bands and _finite(bands[mode]):
            predicted = bands[mode].std[:n, 0]
            top.semilogy(t[start:n], predicted[start:], label=f"PPANN, {mode} draws")
            bottom.plot(t[start:n], predicted[start:] / observed[start:], label=mode)
    top.set_ylabel("σ(θ) [rad]")
    top.legend(fontsize=8)
    bottom.set_ylabel("predicted / observed")
    bottom.set_xlabel("t [s]")
    bottom.legend(fontsize=8, ncol=4)
    fig.suptitle("Calibration on the validation torque: predicted and observed spread of θ")
    return fig
