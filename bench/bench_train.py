"""Benchmark: PPANN training on the 90 s dataset, the vectorised N-step loss against a per-window
Python loop, and the Monte-Carlo 100 × 150 steps.

Prints, from the same run:
- full two-phase training time (target <= 3 min);
- time of one phase-1 epoch's loss and gradient, vectorised over all windows, beside the same
  computation as a plain Python loop over windows (measured on a subset and scaled to all
  windows), and their ratio (target >= 20×);
- Monte-Carlo, 100 trajectories × 150 steps, per draw mode (target <= 20 ms).

    python bench/bench_train.py [--data logs/dataset.mcap]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from ppann.fit import fit
from ppann.heads import FusedHeads
from ppann.losses import n_step_mse
from ppann.model import PPANN, n_step_prediction
from ppann.modes import MODES
from ppann.montecarlo import monte_carlo
from ppann.train import make_splits
from ppann.train_config import TrainConfig
from twin import PAPER_SECONDS
from twin.dataset import GenerationConfig
from twin.generation import generate_file
from twin.mcap_dataset import read_dataset


def vectorised_epoch(model: PPANN, splits, batch_size: int) -> float:
    started = time.perf_counter()
    data = splits.train
    for batch in torch.arange(len(data)).split(batch_size):
        loss = n_step_mse(
            n_step_prediction(model, data.x0[batch], data.tau[batch]),
            data.target[batch],
            splits.scale,
        )
        model.zero_grad()
        loss.backward()
    return time.perf_counter() - started


def looped_epoch(model: PPANN, splits, n_windows: int) -> float:
    """Per-window loop over n_windows windows, scaled to the whole training split."""
    data = splits.train
    started = time.perf_counter()
    for i in range(n_windows):
        x = data.x0[i]
        loss = 0.0
        for k in range(data.tau.shape[1]):
            x = model.step(x, data.tau[i, k])
            loss = loss + (((x - data.target[i, k]) / splits.scale) ** 2).sum()
        model.zero_grad()
        (loss / (2 * data.tau.shape[1])).backward()
    return (time.perf_counter() - started) * len(data) / n_windows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=None)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = args.data
        if path is None:
            path = Path(tmp) / "dataset.mcap"
            generate_file(GenerationConfig(seconds=PAPER_SECONDS), out=path, figures=False)
        dataset = read_dataset(path)
    config = TrainConfig()
    splits = make_splits(dataset, config)
    fitted = fit(dataset, kind="ppann", config=config, splits=splits)
    epochs = len(fitted.history.train)
    torch.manual_seed(0)
    model = PPANN()
    vec = statistics.median(vectorised_epoch(model, splits, config.batch_size) for _ in range(3))
    loop = looped_epoch(model, splits, 300)
    heads = FusedHeads(fitted.model)
    x0, tau = [dataset.theta[0], dataset.omega[0]], np.full(150, 1.0)
    mc = {}
    for mode in MODES:
        monte_carlo(heads, x0, tau, mode=mode)
        times = []
        for _ in range(20):
            started = time.perf_counter()
            monte_carlo(heads, x0, tau, mode=mode)
            times.append(time.perf_counter() - started)
        mc[mode] = statistics.median(times)
    print(
        f"PPANN training on {len(dataset)} samples, {len(splits.train)} windows of "
        f"{config.horizon} steps, {torch.get_num_threads()} threads"
    )
    print(
        f"  two-phase training           : {fitted.seconds:7.1f} s  ({epochs} phase-1 epochs, "
        f"{config.phase2_epochs} phase-2: {config.phase2_epochs // config.sigma_epochs} "
        "pass(es), the history keeps the last)   (target <= 180 s)"
    )
    print(f"  epoch, vectorised            : {vec:7.3f} s")
    print(f"  epoch, per-window loop       : {loop:7.1f} s  (300 windows, scaled)")
    print(f"  ratio loop / vectorised      : {loop / vec:7.1f}x   (target >= 20x)")
    for mode, seconds in mc.items():
        print(f"  Monte-Carlo 100 x 150, {mode:<10}: {seconds * 1e3:6.1f} ms   (target <= 20 ms)")


if __name__ == "__main__":
    main()
