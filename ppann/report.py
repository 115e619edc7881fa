"""Validation report of a trained PPANN and its baselines, and its calibration against the twin.

On the validation split (the last 3 s by default):
- 10-step and 100-step-ahead RMSE of theta and omega (error at the last step of every window) and
  the free-run RMSE over the validation segment, for every model;
- the fraction of validation samples inside the PPANN's Monte-Carlo ±3σ band, per draw mode;
- calibration: the validation torque replayed 100 times on the twin from the segment's initial
  state, each run a fresh machine of the dataset's variability distribution (friction, backlash,
  disturbance; warm-up: run for as long as the dataset's machines, U[0, max_start_time] s, plus
  the segment's time in its episode). Observed σ(t) of theta and of the
  slider position against the Monte-Carlo σ(t); the ratio predicted / observed is summarised by
  its median and 10th-90th percentiles over t (samples where the observed σ is still below
  1e-6 are left out).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from common import streams
from ppann.data import split_index, windows
from ppann.model import n_step_prediction, rollout
from ppann.modes import MODES
from ppann.montecarlo import Bands, monte_carlo
from twin.dataset import Dataset
from twin.geometry import Geometry
from twin.physics import SliderCrank
from twin.stepping import simulate
from twin.variability import Variability

HORIZONS = (10, 100)


@dataclass(frozen=True)
class Segment:
    """Validation samples [start, stop), all in one episode."""

    start: int
    stop: int

    @property
    def length(self) -> int:
        return self.stop - self.start


def validation_segment(dataset: Dataset, validation_fraction: float) -> Segment:
    start = split_index(len(dataset), validation_fraction)
    same = np.flatnonzero(dataset.episode[start:] != dataset.episode[start])
    stop = start + (int(same[0]) if same.size else len(dataset) - start)
    return Segment(start, stop)


def rmse(error: np.ndarray) -> dict[str, float]:
    """RMSE per state of errors (..., 2)."""
    value = np.sqrt(np.mean(error.reshape(-1, 2) ** 2, axis=0))
    return {"theta": float(value[0]), "omega": float(value[1])}


def prediction_rmse(model: torch.nn.Module, dataset: Dataset, segment: Segment) -> dict:
    """N-step-ahead RMSE for each N in HORIZONS (error at step N), and the free run."""
    out = {}
    for n in HORIZONS:
        if segment.length <= n:
            continue
        w = windows(dataset, start=segment.start, stop=segment.stop, horizon=n)
        with torch.no_grad():
            p = n_step_prediction(model, w.x0, w.tau)
        out[f"rmse_{n}_step"] = rmse((p[:, -1] - w.target[:, -1]).numpy())
    free = free_run(model, dataset, segment)
    measured = np.stack([dataset.theta, dataset.omega], -1)[segment.start : segment.stop]
    out["free_run_rmse"] = rmse(free - measured)
    return out


def free_run(model: torch.nn.Module, dataset: Dataset, segment: Segment) -> np.ndarray:
    """Mean-model simulation over the segment from its first measured state: (length, 2)."""
    x0 = torch.tensor([dataset.theta[segment.start], dataset.omega[segment.start]])
    tau = torch.from_numpy(dataset.tau[segment.start : segment.stop - 1])
    with torch.no_grad():
        return rollout(model, x0.double(), tau).numpy()


def bands(model: torch.nn.Module, dataset: Dataset, segment: Segment, *, n: int, seed: int):
    x0 = [dataset.theta[segment.start], dataset.omega[segment.start]]
    tau = dataset.tau[segment.start : segment.stop - 1]
    seq = streams.stream(seed, "validation_monte_carlo")
    return {mode: monte_carlo(model, x0, tau, n_samples=n, mode=mode, seed=seq) for mode in MODES}


def inside_3sigma(band: Bands, measured: np.ndarray) -> dict[str, float]:
    inside = np.abs(measured - band.mean) <= 3 * band.std
    return {"theta": float(inside[:, 0].mean()), "omega": float(inside[:, 1].mean())}


@dataclass(frozen=True)
class TwinReplay:
    """The twin's runs of the validation torque: theta and slider position, (n_runs, length)."""

    theta: np.ndarray
    slider_position: np.ndarray


def twin_replay(
    dataset: Dataset, segment: Segment, *, physics: SliderCrank, n_runs: int, seed: int
) -> TwinReplay:
    """Replay the segment's torque on n_runs fresh machines from its initial measured state."""
    variability = Variability.from_dict(dataset.run["config"]["variability"])
    rng = streams.rng(seed, "calibration_machines")
    draws = [variability.sample(rng) for _ in range(n_runs)]
    # datasets from before max_start_time started every machine cold
    operating = float(dataset.run["config"].get("max_start_time", 0.0))
    running = rng.uniform(0.0, operating, n_runs)
    noise = streams.rng(seed, "calibration_noise")
    state = physics.initial_state(dataset.theta[segment.start], dataset.omega[segment.start])
    episode_start = np.flatnonzero(dataset.episode == dataset.episode[segment.start])[0]
    warm = float(dataset.t[segment.start] - dataset.t[episode_start])
    tau = np.tile(dataset.tau[segment.start : segment.stop], (n_runs, 1))
    runs = simulate(
        physics,
        variability,
        draws=draws,
        initial_states=np.tile(state, (n_runs, 1)),
        tau=tau,
        disturbance=variability.disturbance(noise, tau.size).reshape(tau.shape),
        start_times=running + warm,
    )
    return TwinReplay(
        theta=physics.sensor(runs.sensordata, "theta"),
        slider_position=physics.sensor(runs.sensordata, "slider_position"),
    )


def ratio_summary(predicted: np.ndarray, observed: np.ndarray) -> dict[str, float]:
    keep = observed > 1e-6
    ratio = predicted[keep] / observed[keep]
    p10, median, p90 = np.percentile(ratio, [10, 50, 90])
    return {"median": float(median), "p10": float(p10), "p90": float(p90)}


def calibration(band: Bands, replay: TwinReplay, *, geometry: Geometry) -> dict[str, Any]:
    """Predicted σ / observed σ over time for theta and the slider position (by `geometry`'s
    kinematics; NaN, reported as null, where a diverged draw left no number)."""
    length = replay.theta.shape[1]
    predicted_theta = band.std[:length, 0]
    with np.errstate(over="ignore", invalid="ignore"):
        slider = geometry.slider_position(band.samples[:, :length, 0])
        predicted_slider = slider.std(axis=0, ddof=1)
    observed_theta = replay.theta.std(axis=0, ddof=1)
    observed_slider = replay.slider_position.std(axis=0, ddof=1)
    return {
        "theta": ratio_summary(predicted_theta, observed_theta),
        "slider_position": ratio_summary(predicted_slider, observed_slider),
    }
