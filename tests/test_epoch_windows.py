"""Phase 1's epoch as a fixed number of windows (`TrainConfig.epoch_windows`): a random subset
each epoch, so that longer datasets need not mean longer epochs; at or above the window count it
is the full epoch, bit for bit."""

from __future__ import annotations

import pytest
import torch

from ppann.kinds import model_kind
from ppann.train import History, make_splits, train_mean
from ppann.train_config import TrainConfig, TrainConfigError
from tests.test_ppann import synthetic


def _phase1(config: TrainConfig, *, count_steps: bool = False) -> tuple[dict, History, int]:
    """Phase 1 of a black-box model on 4 s of the synthetic system; its weights, history and
    the optimiser steps taken."""
    data = synthetic(seconds=4.0)
    splits = make_splits(data, config)
    torch.manual_seed(0)
    model = model_kind("blackbox").new(None)
    steps = 0
    if count_steps:
        original = torch.optim.Adam.step

        def counted(self, *args, **kwargs):
            nonlocal steps
            steps += 1
            return original(self, *args, **kwargs)

        torch.optim.Adam.step = counted
    try:
        history = History()
        train_mean(model, splits, config, history=history)
    finally:
        if count_steps:
            torch.optim.Adam.step = original
    return model.state_dict(), history, steps


def _config(**options) -> TrainConfig:
    return TrainConfig(max_epochs=3, patience=10, batch_size=256, horizon=5, **options)


def test_a_cap_at_or_above_the_window_count_is_the_full_epoch_bit_for_bit() -> None:
    windows = len(make_splits(synthetic(seconds=4.0), _config()).train.x0)
    full, full_history, _ = _phase1(_config(epoch_windows=10**9))
    capped, capped_history, _ = _phase1(_config(epoch_windows=windows))
    for name, tensor in full.items():
        assert torch.equal(tensor, capped[name]), name
    assert full_history.train == capped_history.train


def test_a_cap_below_the_window_count_takes_that_many_windows_per_epoch() -> None:
    windows = len(make_splits(synthetic(seconds=4.0), _config()).train.x0)
    assert windows > 1000  # 4 s at 500 Hz less the early-stopping tails
    _, history, steps = _phase1(_config(epoch_windows=600), count_steps=True)
    assert steps == 3 * 3  # ceil(600 / 256) batches in each of 3 epochs
    _, _, full_steps = _phase1(_config(epoch_windows=10**9), count_steps=True)
    assert full_steps == 3 * -(-windows // 256)
    assert len(history.train) == 3 and all(loss > 0 for loss in history.train)


def test_the_default_cap_holds_every_window_of_the_papers_dataset() -> None:
    from twin import PAPER_SECONDS
    from twin.dataset import GenerationConfig

    config = TrainConfig()
    generation = GenerationConfig(seconds=PAPER_SECONDS)
    episodes = round(generation.seconds / generation.episode_seconds)
    per_episode = generation.n_samples // episodes
    tail = round(per_episode * config.validation_fraction)
    # every episode's windows less its early-stopping tail (the last episode's includes the split)
    assert episodes * (per_episode - tail - config.horizon) <= config.epoch_windows


@pytest.mark.parametrize("value", [0, -5, 2.5])
def test_a_cap_that_is_not_a_positive_count_is_refused(value) -> None:
    with pytest.raises(TrainConfigError, match="epoch_windows must be an integer"):
        TrainConfig(epoch_windows=value)
