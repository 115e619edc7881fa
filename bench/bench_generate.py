"""Benchmark: the 90 s dataset (simulation + MCAP) against a bare mujoco.rollout.

Prints, from the same run: wall time of generating the paper's 90 s dataset on `crank generate`'s
code path (MCAP written, figures excluded), wall time of one bare `mujoco.rollout` call over the
same model, the same number of runs and physics steps and the same thread count, and their ratio.
Target: ratio <= 2.0.

    python bench/bench_generate.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np
from mujoco import rollout

from twin import PAPER_SECONDS
from twin.dataset import GenerationConfig, generate
from twin.generation import generate_file
from twin.physics import SliderCrank, load_model


def bare_rollout(physics: SliderCrank, n_runs: int, n_samples: int, nthread: int) -> float:
    """Seconds for one rollout call: n_runs × n_samples × substeps steps, controls precomputed."""
    rng = np.random.default_rng(0)
    states = np.array([physics.initial_state(t) for t in rng.uniform(0, 2 * np.pi, n_runs)])
    controls = np.repeat(
        rng.uniform(-3, 3, (n_runs, n_samples, physics.model.nu)), physics.substeps, axis=1
    )
    data = [mujoco.MjData(physics.model) for _ in range(nthread)]
    started = time.perf_counter()
    rollout.rollout(physics.model, data, states, controls)
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    config = GenerationConfig(seconds=PAPER_SECONDS)
    physics = SliderCrank(load_model()[0])
    lengths = config.episode_lengths()
    nthread = os.cpu_count() or 1
    project, simulate_only, bare = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):
            started = time.perf_counter()
            generate_file(config, out=Path(tmp) / "dataset.mcap", figures=False)
            project.append(time.perf_counter() - started)
            started = time.perf_counter()
            generate(config, physics=physics)
            simulate_only.append(time.perf_counter() - started)
            bare.append(bare_rollout(physics, len(lengths), max(lengths), nthread))
    steps = config.n_samples * physics.substeps
    p, s, b = (statistics.median(x) for x in (project, simulate_only, bare))
    print(
        f"90 s dataset, {len(lengths)} episodes, {steps:,} physics steps, {nthread} threads, "
        f"median of {args.repeats}"
    )
    print(f"  crank generate (simulation + MCAP): {p:7.3f} s")
    print(f"    of which simulation             : {s:7.3f} s")
    per_step = b / steps * 1e6 * nthread
    print(f"  bare mujoco.rollout               : {b:7.3f} s  ({per_step:.2f} µs/step/thread)")
    print(f"  ratio generate / bare             : {p / b:7.3f}   (target <= 2.0)")


if __name__ == "__main__":
    main()
