"""Fit a model of one kind (ppann/kinds.py) on a dataset: the PPANN in two phases, a baseline in
phase 1 only."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import torch

from common.streams import torch_seed
from ppann.kinds import model_kind
from ppann.model import PPANNConfig
from ppann.train import History, Splits, make_splits, train_mean, train_sigma
from ppann.train_config import TrainConfig
from ppann.transmission import fit_quantiles
from twin.dataset import Dataset


@dataclass
class Fitted:
    kind: str
    model: torch.nn.Module
    history: History
    seconds: float


def fit(
    dataset: Dataset,
    *,
    kind: str,
    config: TrainConfig,
    splits: Splits | None = None,
    ppann_config: PPANNConfig | None = None,
    on_epoch: Callable[[str, int, float], None] | None = None,
) -> Fitted:
    """Train a model of `kind`; `on_epoch(phase, epoch, loss)` reports progress."""
    splits = splits or make_splits(dataset, config)
    torch.manual_seed(torch_seed(config.seed, "training"))
    spec = model_kind(kind)
    if kind == "ppann" and config.sigma_wrap:  # asked for in the training config
        ppann_config = replace(ppann_config or PPANNConfig(), sigma_wrap=True)
    model = spec.new(ppann_config if kind == "ppann" else None)
    if hasattr(model, "geometry"):
        model.geometry = dataset.geometry
    history = History()
    started = time.perf_counter()
    train_mean(
        model,
        splits,
        config,
        history=history,
        on_epoch=None if on_epoch is None else (lambda e, t, v: on_epoch("mean", e, v)),
    )
    if spec.sigma_phase:
        stop = splits.split
        with torch.no_grad():
            model.transmission.copy_(
                torch.from_numpy(
                    fit_quantiles(
                        dataset.theta[:stop],
                        dataset.slider_position[:stop],
                        geometry=dataset.geometry,
                    )
                )
            )
        train_sigma(
            model,
            dataset,
            splits,
            config,
            history=history,
            on_epoch=None if on_epoch is None else (lambda e, loss: on_epoch("sigma", e, loss)),
        )
    model.eval()
    return Fitted(kind, model, history, time.perf_counter() - started)
