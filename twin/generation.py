"""Generate a dataset file: simulate the episodes, describe the run, write the MCAP and figures."""

from __future__ import annotations

import platform
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from common.atomic import check_writable, writes
from common.resources import check_memory
from twin import __version__
from twin.dataset import Episode, GenerationConfig, generate, summarize
from twin.mcap_dataset import write_dataset
from twin.physics import MODEL_PATH, SAMPLE_RATE, SliderCrank, load_model, model_sha256
from twin.plots import coverage_map, excitation_plot


def run_metadata(
    *, config: GenerationConfig, physics: SliderCrank, episodes: list[Episode], model_path: Path
) -> dict[str, Any]:
    """The `run` metadata record: everything needed to reproduce the dataset."""
    amplitude = config.variability.disturbance_amplitude
    return {
        "seed": config.seed,
        "seconds": config.seconds,
        "rate_hz": SAMPLE_RATE,
        "n_samples": config.n_samples,
        "physics_timestep": physics.model.opt.timestep,
        "substeps": physics.substeps,
        "torque_limit": physics.torque_limit,
        "geometry": physics.geometry.as_dict(),
        "config": config.as_dict(),
        "disturbance_distribution": (
            f"uniform on [-{amplitude:g}, {amplitude:g}] N, one draw per sample, "
            "held over the substeps"
        ),
        "episodes": [episode_record(e) for e in episodes],
        **provenance(model_path),
    }


def episode_record(episode: Episode) -> dict[str, Any]:
    """One episode as the run record lists it (`machine_id` where several episodes play one
    machine: twin.dataset.episode_machines)."""
    same = {} if episode.machine_id is None else {"machine_id": episode.machine_id}
    return {
        "index": episode.index,
        "n_samples": episode.n_samples,
        "theta0": episode.theta0,
        "omega0": episode.omega0,
        "start_time": episode.start_time,
        "machine": episode.machine.as_dict(),
        **same,
    }


def provenance(model_path: str | Path) -> dict[str, str]:
    """Versions and the MJCF's path and sha256: what a file needs to say how it was made."""
    return {
        "project_version": __version__,
        "mujoco_version": mujoco.__version__,
        "numpy_version": np.__version__,
        "python_version": platform.python_version(),
        "mjcf_path": str(model_path),
        "mjcf_sha256": model_sha256(model_path),
    }


BYTES_PER_SAMPLE = 1000
"""Peak memory per dataset sample while generating and writing it (measured: 60 s and 240 s of
data peaked at 465 MB and 553 MB, 980 bytes per sample above a fixed ~400 MB)."""


def check_generation_memory(config: GenerationConfig) -> None:
    """Refuse a dataset that cannot fit in memory before anything is simulated (ResourceError)."""
    check_memory(
        config.n_samples * BYTES_PER_SAMPLE,
        what=f"a dataset of {config.n_samples:.4g} samples ({config.seconds:g} s)",
    )


@writes("out", inputs=("model_path",), suffix=".mcap")
def generate_file(
    config: GenerationConfig,
    *,
    out: str | Path,
    model_path: str | Path = MODEL_PATH,
    figures: bool = True,
    on_simulated: Callable[[int], None] | None = None,
    on_written: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Generate the dataset of `config` into the MCAP `out` (figures beside it); return its summary.

    The output location is checked before any simulation, and the MCAP is written atomically.
    Figures: `<out stem>.coverage.png` (paper Fig. 6) and `<out stem>.excitation.png` (Fig. 5).
    """
    out, model_path = Path(out), Path(model_path)
    check_generation_memory(config)
    check_writable(out)
    model, model_xml = load_model(model_path)
    physics = SliderCrank(model)
    started = time.perf_counter()
    dataset, truth, episodes = generate(config, physics=physics, on_progress=on_simulated)
    run = run_metadata(config=config, physics=physics, episodes=episodes, model_path=model_path)
    write_dataset(out, dataset, truth, run=run, model_xml=model_xml, on_progress=on_written)
    summary = summarize(replace(dataset, run=run), truth) | {
        "wall_seconds": time.perf_counter() - started
    }
    if figures:
        stem = out.with_suffix("")
        coverage_map(dataset, f"{stem}.coverage.png")
        excitation_plot(dataset, f"{stem}.excitation.png")
    return summary
