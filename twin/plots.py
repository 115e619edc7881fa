"""Figures of a dataset: excitation and response (paper Fig. 5), coverage maps (paper Fig. 6)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from common.figures import save_figure
from twin.dataset import Dataset


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
    """Torque, motor angle and speed, and slider position against time, episodes shaded."""
    fig = Figure(figsize=(12, 9), layout="constrained")
    axes = fig.subplots(4, 1, sharex=True)
    series = (
        (dataset.tau, "τ [N·m]"),
        (np.mod(dataset.theta, 2 * np.pi), "θ mod 2π [rad]"),
        (dataset.omega, "ω [rad/s]"),
        (dataset.slider_position * 1e3, "slider [mm]"),
    )
    starts = np.flatnonzero(np.diff(dataset.episode, prepend=-1))
    for ax, (values, label) in zip(axes, series, strict=True):
        ax.plot(dataset.t, values, lw=0.5)
        ax.set_ylabel(label)
        for i, s in enumerate(starts):
            if i % 2:
                end = starts[i + 1] if i + 1 < len(starts) else len(dataset) - 1
                ax.axvspan(dataset.t[s], dataset.t[end], color="0.92", lw=0)
    axes[-1].set_xlabel("t [s] (episodes shaded alternately)")
    fig.suptitle("Excitation torque and measured response")
    save_figure(fig, path)
