"""Figures of a dataset: excitation and response (paper Fig. 5), coverage maps (paper Fig. 6)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from common.figures import save_figure
from twin.dataset import Dataset

ZOOM_SECONDS = 2.0
"""Length of the zoomed window of the excitation plot, s."""


def coverage_map(dataset: Dataset, path: str | Path, *, bins: int = 60) -> None:
    """Sample counts over (θ mod 2π, ω), (θ mod 2π, τ) and (ω, τ), log colour scale."""
    angle = np.mod(dataset.theta, 2 * np.pi)
    pairs = (
        (angle, dataset.omega, "θ mod 2π [rad]", "ω [rad/s]"),
        (angle, dataset.tau, "θ mod 2π [rad]", "τ [N·m]"),
        (dataset.omega, dataset.tau, "ω [rad/s]", "τ [N·m]"),
    )
    fig = Figure(figsize=(15, 4.5), layout="constrained")
    axes = fig.subplots(1, 3)
    for ax, (x, y, xlabel, ylabel) in zip(axes, pairs, strict=True):
        counts, xe, ye = np.histogram2d(x, y, bins=bins)
        log_counts = np.full_like(counts.T, np.nan)
        np.log10(counts.T, where=counts.T > 0, out=log_counts)
        image = ax.pcolormesh(xe, ye, log_counts, cmap="viridis")
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
    fig.colorbar(image, ax=axes, label="log10 samples per bin")
    fig.suptitle(f"Coverage of {len(dataset)} samples")
    save_figure(fig, path)


def excitation_plot(dataset: Dataset, path: str | Path) -> None:
    """Torque, motor angle and speed, and slider position against time, episodes shaded; beside
    it the first ZOOM_SECONDS, where single crank turns can be seen (over the whole dataset the
    angle and slider panels are solid blocks)."""
    fig = Figure(figsize=(15, 9), layout="constrained")
    axes = fig.subplots(4, 2, sharex="col", width_ratios=(2.2, 1))
    series = (
        (dataset.tau, "τ [N·m]"),
        (np.mod(dataset.theta, 2 * np.pi), "θ mod 2π [rad]"),
        (dataset.omega, "ω [rad/s]"),
        (dataset.slider_position * 1e3, "slider [mm]"),
    )
    starts = np.flatnonzero(np.diff(dataset.episode, prepend=-1))
    zoom = dataset.t <= dataset.t[0] + ZOOM_SECONDS
    for (whole, near), (values, label) in zip(axes, series, strict=True):
        whole.plot(dataset.t, values, lw=0.5)
        whole.set_ylabel(label)
        for i, s in enumerate(starts):
            if i % 2:
                end = starts[i + 1] if i + 1 < len(starts) else len(dataset) - 1
                whole.axvspan(dataset.t[s], dataset.t[end], color="0.92", lw=0)
        whole.axvspan(dataset.t[0], dataset.t[zoom][-1], color="C1", alpha=0.15, lw=0)
        near.plot(dataset.t[zoom], values[zoom], lw=0.8)
    axes[-1, 0].set_xlabel("t [s] (episodes shaded alternately; orange: the zoom)")
    axes[-1, 1].set_xlabel(f"t [s], first {ZOOM_SECONDS:g} s")
    fig.suptitle("Excitation torque and measured response")
    save_figure(fig, path)
