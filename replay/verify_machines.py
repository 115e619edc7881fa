"""Runs of several machines, each run a few times (`crank verify` on runs whose import named each
run's machine: `crank import`'s machine column or `--machines`; twin.dataset.episode_machines).

A lab with a few machines does not have the line's machines nor one machine's: its runs' spread
mixes both parts of the PPANN's. Named, they can be taken apart, on θ (replay/verify.py says why
θ): at each constraint sample the runs' spread about their own machine's mean, pooled over the
machines (its variance Σ_i Σ_r (θ_ir − θ̄_i)² / (N − M), N runs on M machines), set beside the
PPANN's white part (mode step); and the machines' own spread, the method of moments of a one-way
layout, σ_b² = var(θ̄_i) − mean(s_w² / n_i) (zero where the runs' spread alone explains the
means'), beside the PPANN's machine part (mode machine). Each with a percentile bootstrap
interval: runs resampled within their machine for the first; machines resampled, then their runs,
for the second. With a handful of machines the second interval is wide, as it should be: M
machines measure a spread to about 1 / sqrt(2 (M − 1)).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from replay.spread_interval import BOOTSTRAP_DRAWS, LEVEL, ratio_interval
from twin.dataset import Dataset, episode_machines, machine_ids

UNDEFINED = (
    "within_sigma",
    "within_sigma_ci95",
    "white_ratio",
    "white_ratio_ci95",
    "between_sigma",
    "between_sigma_ci95",
    "machine_ratio",
    "machine_ratio_ci95",
)
"""The keys of a constraint sample that every machine running once leaves undefined."""


def run_machines(dataset: Dataset, episodes: np.ndarray) -> list[str] | None:
    """Each run's machine (its label, or its number where the record has none) for the runs of
    `episodes`; None unless they name two or more machines."""
    ids = machine_ids(dataset)
    if not any(int(e) in ids for e in episodes):
        return None
    machine = episode_machines(dataset)
    labels = [
        str(ids[e]) if e in ids else f"#{machine[np.argmax(dataset.episode == e)]}"
        for e in map(int, episodes)
    ]
    return labels if len(set(labels)) >= 2 else None


def _parts(theta: np.ndarray, groups: list[np.ndarray]) -> tuple[float, float]:
    """(within σ, between σ) of `theta` (runs,) over the machines' run indices `groups`."""
    means = np.array([theta[g].mean() for g in groups])
    sizes = np.array([len(g) for g in groups])
    within = sum(float(((theta[g] - m) ** 2).sum()) for g, m in zip(groups, means, strict=True))
    within /= max(int(sizes.sum()) - len(groups), 1)
    between = float(means.var(ddof=1)) - float(np.mean(within / sizes))
    return float(np.sqrt(within)), float(np.sqrt(max(between, 0.0)))


def _intervals(
    theta: np.ndarray, groups: list[np.ndarray], rng: np.random.Generator
) -> tuple[list[float], list[float]]:
    """LEVEL percentile-bootstrap intervals of (within σ, between σ)."""
    within, between = np.empty(BOOTSTRAP_DRAWS), np.empty(BOOTSTRAP_DRAWS)
    for d in range(BOOTSTRAP_DRAWS):
        runs = [g[rng.integers(0, len(g), len(g))] for g in groups]
        within[d] = _parts(theta, runs)[0]
        picked = [groups[i] for i in rng.integers(0, len(groups), len(groups))]
        between[d] = _parts(theta, [g[rng.integers(0, len(g), len(g))] for g in picked])[1]
    tail = (1 - LEVEL) / 2
    low_high = np.quantile(np.stack([within, between]), [tail, 1 - tail], axis=1).T
    return low_high[0].tolist(), low_high[1].tolist()


def _ratio(predicted: float | None, observed: float, interval: list[float]) -> dict[str, Any]:
    if predicted is None or observed <= 0:
        return {"ratio": None, "ratio_ci95": None}
    return {
        "ratio": predicted / observed,
        "ratio_ci95": ratio_interval(predicted, observed, tuple(interval)),
    }


def machines_section(
    theta: dict[int, np.ndarray],
    labels: list[str],
    split: dict[int, dict[str, float]] | None,
    *,
    seed: int,
) -> dict[str, Any]:
    """verify.json's `machines`: the machines' labels and runs, and per constraint sample (keys
    of `theta`, each the runs' θ there) the runs' θ spread within a machine beside the PPANN's
    white part and the machines' own beside its machine part (`split`: spread_split's; None
    without the PPANN), with bootstrap intervals from the stream `seed`; each σ and ratio None
    where every machine ran once (the runs are then the line's machines, read as such above)."""
    names = list(dict.fromkeys(labels))
    groups = [np.flatnonzero(np.array(labels) == name) for name in names]
    rng = np.random.default_rng(seed)
    samples = {}
    for k, values in theta.items():
        white = None if split is None else split[k]["theta_white"]
        machine = None if split is None else split[k]["theta_machine"]
        if len(values) == len(groups):  # each machine ran once: no spread within a machine
            samples[str(k)] = dict.fromkeys(UNDEFINED) | {
                "white_sigma": white,
                "machine_sigma": machine,
            }
            continue
        within, between = _parts(values, groups)
        within_ci, between_ci = _intervals(values, groups, rng)
        samples[str(k)] = {
            "within_sigma": within,
            "within_sigma_ci95": within_ci,
            "white_sigma": white,
            **{f"white_{key}": v for key, v in _ratio(white, within, within_ci).items()},
            "between_sigma": between,
            "between_sigma_ci95": between_ci,
            "machine_sigma": machine,
            **{f"machine_{key}": v for key, v in _ratio(machine, between, between_ci).items()},
        }
    return {
        "count": len(names),
        "labels": names,
        "runs": [len(g) for g in groups],
        "samples": samples,
    }
