"""Phase 1 continued on the plan round's episodes whole (beyond the paper; `[train] plan_fit`).

Phase 1 fits the mean model over `horizon` steps (10, the paper's Ns). Over a plan's 150-200
steps its small errors add up, and they do not cancel: session 90 read the plan (the mean model's
noise-free rollout) 3-43 mrad ahead of the twin's mean angle at the tasks' later constraint
samples, and on the plan round's own episodes, data it had trained on, the height-0.085 seed-0
model of session 89 ran +24 and +47 mrad ahead of the recorded angle at samples 50 and 100
(session 91). Past top dead centre a plan ahead of the machines predicts the slider where x(theta)
is steeper: a wider spread and a larger premium than the machines need (docs/robustness.md).

Here, when the data holds the plan round's episodes (twin/plan_data.py, `plan_episode` in the run
record: the plan's torque, scaled and dithered, on many machines with the white force), phase 1
goes on from its best weights with two terms: its N-step loss on minibatches of its windows as
before, plus the loss of the plan episodes rolled out whole from their first state under their
own torque (each state divided by the same scale), weighted so that the two are equal at the
start. Over episodes of many machines and white forces that whole-episode loss is least at their
mean trajectory, so the plan is pulled to the line's mean under torques like the plan's; the
window term keeps the one-step dynamics everywhere else. Every STOP_EVERY-th plan episode is kept
out of the fit and decides early stopping (patience PATIENCE, at most EPOCHS epochs of phase 1's
size); the best weights are kept, the starting ones if no epoch improved on them. Phase 2 then
fits the spread around the continued mean as it would around phase 1's. A dataset without plan
episodes (a first round, a rig's data) leaves the model as phase 1 left it, bit for bit.

Measured (bench/plan_fit.md, pre-registered, session 91): on the four tasks nobody tuned, seeds
0-1, it did not meet its rule (7 of 16 000 held-out machines below against 2, the lead smaller on
5 of 8 torques), so it stays off. The episodes carry the lead, but this loss is nearly all their
spread and moved their mean bias by tens of mrad either way; a fit of their mean trajectory
(bench/plan_fit_mean_probe.py) is the design to measure next.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from common.streams import torch_seed
from ppann.data import Windows
from ppann.losses import n_step_mse
from ppann.model import n_step_prediction
from ppann.train import evaluate
from twin.dataset import Dataset

EPOCHS = 40
"""Most epochs of the continued phase 1 (each of phase 1's `epoch_windows`)."""
PATIENCE = 5
"""Epochs without a better held-out episode loss before it stops."""
LR_SHARE = 0.1
"""Its Adam's learning rate as a share of phase 1's starting one."""
STOP_EVERY = 6
"""Every this-many-th plan episode (the last of each group) decides early stopping."""


def plan_episodes(dataset: Dataset, stop: int) -> Windows | None:
    """The plan round's episodes that end before sample `stop`, each as one window from its
    first sample over the shortest such episode's length; None if the data holds fewer than
    STOP_EVERY of them (none to stop on)."""
    records = dataset.run.get("episodes") or []
    marked = [
        record.get("index", i) for i, record in enumerate(records) if record.get("plan_episode")
    ]
    firsts, lengths = [], []
    for episode in marked:
        samples = np.flatnonzero(dataset.episode == episode)
        if samples.size > 1 and samples[-1] < stop:
            firsts.append(int(samples[0]))
            lengths.append(int(samples.size))
    if len(firsts) < STOP_EVERY:
        return None
    first = np.asarray(firsts)
    steps = first[:, None] + np.arange(min(lengths))[None, :]
    states = np.stack([dataset.theta, dataset.omega], axis=-1)
    return Windows(
        x0=torch.from_numpy(states[first]),
        tau=torch.from_numpy(dataset.tau[steps[:, :-1]]),
        target=torch.from_numpy(states[steps[:, 1:]]),
    )


def _part(windows: Windows, keep: torch.Tensor) -> Windows:
    return Windows(x0=windows.x0[keep], tau=windows.tau[keep], target=windows.target[keep])


def _loss(model: torch.nn.Module, windows: Windows, scale: torch.Tensor) -> torch.Tensor:
    """`ppann.train.evaluate`'s loss, with its gradient."""
    return n_step_mse(n_step_prediction(model, windows.x0, windows.tau), windows.target, scale)


@dataclass(frozen=True)
class PlanFit:
    """What the continued phase 1 did, for the training history."""

    episodes: int
    """Plan episodes in the fit."""
    held: int
    """Plan episodes that decided early stopping."""
    steps: int
    """Steps of each episode's rollout."""
    weight: float
    """The episode term's weight: the window loss over the episode loss at the start."""
    start: float
    """The held-out episodes' loss before it (phase 1's best weights)."""
    kept: float
    """Their loss at the weights kept."""
    epochs: int
    best_epoch: int
    """-1: no epoch improved on phase 1's weights, which are kept."""


def fit_plan_episodes(
    model: torch.nn.Module,
    episodes: Windows,
    train: Windows,
    scale: torch.Tensor,
    *,
    lr: float,
    epoch_windows: int,
    batch_size: int,
    seed: int,
    on_epoch: Callable[[int, float], None] | None = None,
) -> PlanFit:
    """The continued phase 1 of the module docstring, in place: `episodes` from `plan_episodes`,
    `train` and `scale` phase 1's windows and state scale, `lr` phase 1's learning rate.
    `on_epoch(epoch, held-out episode loss)` reports progress."""
    held = torch.arange(len(episodes)) % STOP_EVERY == STOP_EVERY - 1
    fitted, stopping = _part(episodes, ~held), _part(episodes, held)
    window_start = evaluate(
        model, _part(train, torch.arange(min(len(train), epoch_windows))), scale
    )
    episode_start = evaluate(model, fitted, scale)
    best = start = evaluate(model, stopping, scale)
    weight = window_start / episode_start if episode_start > 0 else 0.0  # 0: nothing to fit
    generator = torch.Generator().manual_seed(torch_seed(seed, "training") + 2)
    params = [p for p in model.parameters() if p.requires_grad]
    optimizer = torch.optim.Adam(params, lr=lr * LR_SHARE)
    best_state, best_epoch, waited, epoch = copy.deepcopy(model.state_dict()), -1, 0, 0
    for epoch in range(EPOCHS):
        order = torch.randperm(len(train), generator=generator)[:epoch_windows]
        for batch in order.split(batch_size):
            loss = _loss(model, _part(train, batch), scale) + weight * _loss(model, fitted, scale)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
        held_loss = evaluate(model, stopping, scale)
        if on_epoch is not None:
            on_epoch(epoch, held_loss)
        if held_loss < best:
            best, best_state, best_epoch, waited = (
                held_loss,
                copy.deepcopy(model.state_dict()),
                epoch,
                0,
            )
        else:
            waited += 1
            if waited >= PATIENCE:
                break
    model.load_state_dict(best_state)
    return PlanFit(
        episodes=int((~held).sum()),
        held=int(held.sum()),
        steps=int(episodes.tau.shape[1]),
        weight=weight,
        start=start,
        kept=best,
        epochs=epoch + 1,
        best_epoch=best_epoch,
    )
