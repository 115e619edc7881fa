"""Fit a model of one kind on a dataset: the PPANN (two phases) or a baseline (phase 1 only).

Kinds:
  ppann     eq. 14: prior + mean networks (phase 1), then sigma networks (phase 2, eq. 9).
  physics   eq. 13 alone with J_m, B_m, K_m fitted by the same phase 1; no uncertainty.
  blackbox  an MLP for alpha with no physics, same phase 1; no uncertainty.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import torch

from common.streams import torch_seed
from ppann.baselines import BlackBox, BlackBoxConfig
from ppann.checkpoint import KINDS
from ppann.model import PPANN, PPANNConfig
from ppann.train import History, Splits, TrainConfig, make_splits, train_mean, train_sigma
from twin.dataset import Dataset


@dataclass
class Fitted:
    kind: str
    model: torch.nn.Module
    history: History
    seconds: float


def new_model(kind: str, *, ppann_config: PPANNConfig | None = None) -> torch.nn.Module:
    """An untrained model of `kind`."""
    if kind == "ppann":
        return PPANN(ppann_config or PPANNConfig())
    if kind == "physics":
        return PPANN(PPANNConfig(use_networks=False))
    if kind == "blackbox":
        return BlackBox(BlackBoxConfig())
    raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")


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
    model = new_model(kind, ppann_config=ppann_config)
    history = History()
    started = time.perf_counter()
    train_mean(
        model,
        splits,
        config,
        history=history,
        on_epoch=None if on_epoch is None else (lambda e, t, v: on_epoch("mean", e, v)),
    )
    if kind == "ppann":
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
