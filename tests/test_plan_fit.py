"""Phase 1 continued on the plan episodes' mean trajectory (ppann/plan_fit.py, `[train] plan_fit`):
the episodes are the ones the run record marks, a biased mean model is pulled to the episodes'
mean, an exact one is left bit for bit, and data without plan episodes trains as before."""

from __future__ import annotations

import copy
import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from ppann.data import Windows
from ppann.fit import fit
from ppann.model import PPANN, rollout
from ppann.plan_fit import (
    PlanFit,
    fit_plan_episodes,
    mean_gap,
    plan_episodes,
)
from ppann.train_config import PLAN_FIT_EPOCHS, PLAN_FIT_MIN_EPISODES, TrainConfig
from twin.dataset import Dataset

TINY = TrainConfig(max_epochs=2, epoch_windows=2000, sigma_epochs=3, bound_lines=0)


def _dataset(lengths: list[int], marked: set[int]) -> Dataset:
    """Episodes of the given lengths, numbered in order, `marked` ones plan episodes; each sample
    holds its own index in theta (and 10x, 100x it in omega, tau) so that slices can be read."""
    episode = np.concatenate([np.full(n, i) for i, n in enumerate(lengths)])
    k = np.arange(len(episode), dtype=float)
    run = {
        "episodes": [
            {"index": i} | ({"plan_episode": True} if i in marked else {})
            for i in range(len(lengths))
        ]
    }
    return Dataset(
        t=k / 500,
        episode=episode,
        theta=k,
        omega=10 * k,
        tau=100 * k,
        slider_position=np.zeros_like(k),
        run=run,
    )


def test_plan_episodes_are_the_marked_ones_before_the_split() -> None:
    lengths = [30, 30, 30, 25, 30, 30, 30, 200, 200]
    data = _dataset(lengths, marked={0, 1, 2, 3, 4, 5, 6})
    got = plan_episodes(data, stop=len(data))
    firsts = np.cumsum([0, *lengths[:-1]])[:7]
    np.testing.assert_array_equal(got.x0[:, 0].numpy(), firsts)  # theta is the sample index
    assert got.tau.shape == (7, 24)  # the shortest marked episode: 25 samples, 24 steps
    np.testing.assert_array_equal(got.tau[2].numpy(), 100 * (firsts[2] + np.arange(24)))
    np.testing.assert_array_equal(got.target[2, :, 1].numpy(), 10 * (firsts[2] + 1 + np.arange(24)))
    cut = plan_episodes(data, stop=int(firsts[6]) + 10)  # the last marked one crosses the split
    assert len(cut) == 6
    assert plan_episodes(data, stop=int(firsts[5]) + 10) is None  # fewer than PLAN_FIT_MIN_EPISODES
    assert plan_episodes(_dataset(lengths, marked=set()), stop=len(data)) is None
    assert PLAN_FIT_MIN_EPISODES == 6


def _episodes(model: PPANN, *, count: int, steps: int, seed: int = 3) -> Windows:
    """Noise-free episodes of `model` from rest at theta = pi under scaled smooth torques."""
    gen = torch.Generator().manual_seed(seed)
    shape = torch.sin(torch.linspace(0, 2 * math.pi, steps, dtype=torch.float64))
    scale = 2.0 + torch.rand(count, 1, generator=gen, dtype=torch.float64)
    tau = scale * shape[None, :]
    x0 = torch.tensor([[math.pi, 0.0]], dtype=torch.float64).repeat(count, 1)
    with torch.no_grad():
        states = rollout(model, x0, tau)
    return Windows(x0=x0, tau=tau, target=states[:, 1:])


def _windows(episodes: Windows, horizon: int = 10) -> Windows:
    states = torch.cat([episodes.x0[:, None], episodes.target], dim=1)
    starts = range(0, episodes.tau.shape[1] - horizon, 5)
    return Windows(
        x0=torch.cat([states[:, s] for s in starts]),
        tau=torch.cat([episodes.tau[:, s : s + horizon] for s in starts]),
        target=torch.cat([states[:, s + 1 : s + horizon + 1] for s in starts]),
    )


def _truth() -> PPANN:
    torch.manual_seed(7)
    return PPANN().double()


def _fit(model: PPANN, episodes: Windows) -> PlanFit:
    """The continuation on `episodes` and 10-step windows of them, 64 to a batch."""
    scale = torch.tensor([1e-3, 0.1], dtype=torch.float64)
    return fit_plan_episodes(
        model,
        episodes,
        _windows(episodes),
        scale,
        lr=5e-3,
        epoch_windows=4096,
        batch_size=64,
        seed=0,
    )


def test_a_biased_mean_is_pulled_to_the_episodes() -> None:
    truth = _truth()
    episodes = _episodes(truth, count=24, steps=120)
    model = copy.deepcopy(truth)
    with torch.no_grad():
        model.mean_nets["B"][-1].bias += 0.3  # 30 % more damping than the episodes had
    fresh = _episodes(truth, count=8, steps=120, seed=4)  # torques the fit never saw

    def end_error() -> float:
        with torch.no_grad():
            end = rollout(model, fresh.x0, fresh.tau)[:, -1, 0]
        return float((end - fresh.target[:, -1, 0]).abs().max())

    before = end_error()
    done = _fit(model, episodes)
    assert before > 0.05  # rad: the bias shows over 120 steps
    assert end_error() < before / 5
    assert done.fitted and done.kept < done.start / 10
    with torch.no_grad():
        bias = float(mean_gap(model, episodes)[:, 0].abs().max())
    assert done.theta_bias_kept == pytest.approx(bias, rel=1e-12)
    assert done.theta_bias_kept < done.theta_bias_start / 5
    assert (done.episodes, done.steps, done.epochs) == (24, 120, PLAN_FIT_EPOCHS)


def test_an_exact_mean_is_left_bit_for_bit() -> None:
    model = _truth()
    episodes = _episodes(model, count=12, steps=40)
    before = copy.deepcopy(model.state_dict())
    done = _fit(model, episodes)
    assert done.start < 1e-20  # rounding: the same model, batched differently
    assert not done.fitted and done.kept == done.start
    for name, value in model.state_dict().items():
        assert torch.equal(value, before[name]), name


@pytest.fixture(scope="module")
def with_plan_episodes(paper_dataset) -> Dataset:
    """The paper dataset after six 80-sample plan episodes cut from its first episode."""
    base = paper_dataset.loaded
    starts = [0, 500, 1000, 1500, 2000, 2500]
    cut = np.concatenate([np.arange(s, s + 80) for s in starts])
    fields = ("theta", "omega", "tau", "slider_position")
    episode = np.concatenate([np.repeat(np.arange(6), 80), base.episode + 6])
    records = [{"index": i, "plan_episode": True} for i in range(6)]
    later = [e | {"index": e["index"] + 6} for e in base.run.get("episodes", [])]
    return Dataset(
        t=np.arange(len(episode)) / 500,
        episode=episode,
        **{
            name: np.concatenate([getattr(base, name)[cut], getattr(base, name)]) for name in fields
        },
        run=base.run | {"episodes": records + later},
    )


def test_training_fits_the_plan_episodes_only_when_asked_and_present(
    paper_dataset, with_plan_episodes
) -> None:
    fitted = fit(with_plan_episodes, kind="ppann", config=replace(TINY, plan_fit=True))
    record = fitted.history.plan_fit
    assert (record["episodes"], record["steps"], record["epochs"]) == (6, 79, PLAN_FIT_EPOCHS)
    assert record["kept"] <= record["start"]
    off = fit(with_plan_episodes, kind="ppann", config=replace(TINY, plan_fit=False))
    assert off.history.plan_fit is None
    plain = [
        fit(paper_dataset.loaded, kind="ppann", config=replace(TINY, plan_fit=on))
        for on in (True, False)
    ]
    assert plain[0].history.plan_fit is None
    for name, value in plain[0].model.state_dict().items():
        assert torch.equal(value, plain[1].model.state_dict()[name]), name
