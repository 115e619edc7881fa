"""Phase 1's early-stopping data: the paper's validation tail, or the last fraction of every
training episode (`TrainConfig(early_stopping="machines")`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from ppann.data import DataError, episode_ranges, machine_split, split_index, windows
from ppann.train import make_splits
from ppann.train_config import TrainConfig, TrainConfigError
from tests.test_ppann import synthetic

HORIZON = 10


def four_machines(seconds: float = 4.0):
    """The synthetic system cut into four episodes of equal length (one machine each)."""
    data = synthetic(seconds=seconds)
    episode = np.repeat(np.arange(4), len(data) // 4)
    return replace(data, episode=np.resize(episode, len(data)).astype(np.int64))


def test_machine_split_takes_the_tail_of_every_episode_before_the_validation_split() -> None:
    data = four_machines()  # 2000 samples, episodes of 500
    split = split_index(len(data), 0.1)  # 1800: the last 200 samples (episode 3's tail)
    train, stopping = machine_split(data, split, 0.1)
    assert episode_ranges(data, split) == [(0, 500), (500, 1000), (1000, 1500), (1500, 1800)]
    assert train == [(0, 450), (500, 950), (1000, 1450), (1500, 1770)]
    assert stopping == [(450, 500), (950, 1000), (1450, 1500), (1770, 1800)]
    for (a, b), (c, d) in zip(train, stopping, strict=True):
        assert b == c and len(set(data.episode[a:d])) == 1  # one machine each, nothing skipped
    assert max(d for _, d in stopping) == split  # the validation split stays unseen


def test_machines_windows_are_the_ranges_windows_and_never_cross() -> None:
    data = four_machines()
    config = TrainConfig(validation_fraction=0.1, early_stopping="machines", horizon=HORIZON)
    splits = make_splits(data, config)
    train, stopping = machine_split(data, split_index(len(data), 0.1), 0.1)
    for got, ranges in ((splits.train, train), (splits.validation, stopping)):
        assert len(got.x0) == sum(b - a - HORIZON for a, b in ranges)
        expected = torch.cat(
            [windows(data, start=a, stop=b, horizon=HORIZON).x0 for a, b in ranges]
        )
        assert torch.equal(got.x0, expected)
    # no sample a training window reads is read by an early-stopping window
    states = np.stack([data.theta, data.omega], -1)
    read_train = {tuple(states[k]) for a, b in train for k in range(a, b)}
    read_stop = {tuple(states[k]) for a, b in stopping for k in range(a, b)}
    assert not read_train & read_stop


def test_machines_is_the_default() -> None:
    assert TrainConfig().early_stopping == "machines"


def test_tail_is_the_papers_split() -> None:
    data = four_machines()
    config = TrainConfig(validation_fraction=0.1, horizon=HORIZON, early_stopping="tail")
    splits = make_splits(data, config)
    split = split_index(len(data), 0.1)
    assert torch.equal(splits.train.x0, windows(data, start=0, stop=split, horizon=HORIZON).x0)
    assert torch.equal(
        splits.validation.x0, windows(data, start=split, stop=len(data), horizon=HORIZON).x0
    )


def test_an_episode_tail_too_short_for_a_window_names_the_samples() -> None:
    """Four tails of 5 samples (1 % of 500; the split at 1980) are each named, ends included."""
    with pytest.raises(DataError) as error:
        make_splits(
            four_machines(), TrainConfig(validation_fraction=0.01, early_stopping="machines")
        )
    assert str(error.value) == (
        "samples 495..499, 995..999, 1495..1499, 1975..1979 hold no window of 10 steps inside "
        "one episode; the dataset is too short for the split or the horizon"
    )


def test_many_short_tails_are_named_in_one_short_line() -> None:
    """40 episodes of 50 samples: the 38 before the split (1900) each stop on their last 2
    samples (round(2.5)); the message names the first three, the last and what they hold
    (a 240-episode plan round named all of its tails in 7000 characters before)."""
    data = synthetic(seconds=4.0)
    data = replace(data, episode=(np.arange(len(data)) // 50).astype(np.int64))
    with pytest.raises(DataError) as error:
        make_splits(data, TrainConfig(validation_fraction=0.05, early_stopping="machines"))
    assert str(error.value) == (
        "samples 48..49, 98..99, 148..149, …, 1898..1899 (38 ranges of 2 samples; a window "
        "needs 11) hold no window of 10 steps inside one episode; the dataset is too short for "
        "the split or the horizon"
    )


def test_unknown_early_stopping_is_refused() -> None:
    with pytest.raises(TrainConfigError, match="early_stopping must be one of tail, machines"):
        TrainConfig(early_stopping="best")
