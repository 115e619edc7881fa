"""A development probe (session 91, bench/plan_fit.md): the plan episodes' *mean* trajectory fitted.

`crank train --plan-fit` with ppann/plan_fit.py's objective (the whole-episode MSE, which did not
meet bench/plan_fit.md's rule: it is almost all the episodes' spread) replaced by

    window MSE + W * mean over k of ((mean_i prediction_i(k) - mean_i recorded_i(k)) / scale)^2

over every plan episode, MF_EPOCHS epochs at MF_LR, the last weights kept (no early stopping:
the mean of a held-out sixth is known to ~27 mrad only), the PPANN alone (no baselines).

    python bench/plan_fit_mean_probe.py crank train --plan-fit --data plan.mcap --out m.pt --seed S

Environment: MF_W (1.0), MF_EPOCHS (10), MF_LR (5e-4). Prints the episodes' mean angle bias
(mrad) at a third, two thirds and the end of the episode, before and after each epoch.
"""

import os
import sys

import torch

import ppann.fit as fit
import ppann.pipeline as pipeline
from ppann.data import Windows
from ppann.losses import n_step_mse
from ppann.model import n_step_prediction
from ppann.plan_fit import PlanFit

W = float(os.environ.get("MF_W", "1.0"))
EPOCHS = int(os.environ.get("MF_EPOCHS", "10"))
LR = float(os.environ.get("MF_LR", "5e-4"))


def bias(model: torch.nn.Module, episodes: Windows) -> torch.Tensor:
    with torch.no_grad():
        pred = n_step_prediction(model, episodes.x0, episodes.tau)
    return (pred.mean(0) - episodes.target.mean(0))[:, 0] * 1e3


def at_thirds(b: torch.Tensor) -> str:
    """The bias (mrad) a third, two thirds and all the way along the episode."""
    n = len(b)
    return f"{b[n // 3]:+.1f} {b[2 * n // 3]:+.1f} {b[-1]:+.1f}"


def mean_fit(model, episodes, train, scale, *, lr, epoch_windows, batch_size, seed, on_epoch=None):
    target = episodes.target.mean(0)

    def mean_loss():
        pred = n_step_prediction(model, episodes.x0, episodes.tau)
        return (((pred.mean(0) - target) / scale) ** 2).mean()

    start = bias(model, episodes)
    print(f"[meanfit] start bias mrad at a third, two thirds, the end: {at_thirds(start)}")
    gen = torch.Generator().manual_seed(777)
    opt = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=LR)
    for epoch in range(EPOCHS):
        order = torch.randperm(len(train), generator=gen)[:epoch_windows]
        for batch in order.split(batch_size):
            loss = (
                n_step_mse(
                    n_step_prediction(model, train.x0[batch], train.tau[batch]),
                    train.target[batch],
                    scale,
                )
                + W * mean_loss()
            )
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
        b = bias(model, episodes)
        with torch.no_grad():
            m = float(mean_loss())
        print(f"[meanfit] epoch {epoch}: mean loss {m:.4g}, bias {at_thirds(b)}", flush=True)
        if on_epoch is not None:
            on_epoch(epoch, m)
    return PlanFit(
        episodes=len(episodes),
        held=0,
        steps=len(start),
        weight=W,
        start=0.0,
        kept=m,
        epochs=EPOCHS,
        best_epoch=EPOCHS - 1,
    )


fit.fit_plan_episodes = mean_fit
pipeline.KINDS = pipeline.KINDS[:1]
from crank.cli import main  # noqa: E402

sys.argv = ["crank", *sys.argv[2:]]
main()
