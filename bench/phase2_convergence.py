"""Is phase 2 converged, and does it matter? (issue 11, session 26)

    python bench/phase2_convergence.py --model M/model.pt --dataset D/dataset.mcap \
        --ocp S/ocp.json [--epochs 400,800,1600,2400] [--runs 1000] [--seed 999]

Retrains a model's phase 2 as the chain does (ppann/train.py `train_sigma`: the first pass, the
residual's mean with its machine offsets out, the second pass from the same initial sigma
weights) but continues the second pass to the largest of `--epochs`, keeping a copy of the model
at each of them. Prints each copy's phase-2 loss and its predicted / observed slider sigma
(mixed and step) under the ocp.json's robust torque on `--runs` held-out machines of `--seed`
(replay/heldout.py; use a development seed, not a held-out root). The second pass runs the
chain's own `SpreadFit` (ppann/train.py: its parameters, optimizer and epoch) for models of the
machine-level model with the residual's mean, with or without the slider force's channel; other
models are refused. At --epochs 400 it reproduces the chain's model (session 26, without the
channel: its loss to the last digit; session 27, with it: σ_F to the last digit; session 28,
through SpreadFit: the same). One core; ~0.2 s an epoch on the default 72 machines, and ~40 s a
held-out check of 1000 machines.
"""

from __future__ import annotations

import argparse
import copy

import torch

import ppann.train as train
from common.threads import set_rollout_threads
from ppann.checkpoint import load
from ppann.fit import new_model
from ppann.train import History, make_splits
from ppann.train_config import TrainConfig
from replay.heldout import heldout_check
from twin.mcap_dataset import read_dataset
from twin.physics import SliderCrank
from twin.variability import Variability


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", required=True)
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--ocp", required=True)
    parser.add_argument("--epochs", default="400,800,1600,2400")
    parser.add_argument("--runs", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=999)
    args = parser.parse_args()
    torch.set_num_threads(1)
    set_rollout_threads(1)
    epochs = sorted({int(e) for e in args.epochs.split(",")})
    trained, payload = load(args.model)
    config = TrainConfig(**payload["train_config"])
    if not config.machine_model or not config.residual_mean:
        raise SystemExit("needs a model of the default phase 2 (machine model, residual's mean)")
    dataset = read_dataset(args.dataset)
    splits = make_splits(dataset, config)
    fresh = new_model(dataset, kind="ppann", config=config)  # the chain's initial sigma weights
    start = {k: v for k, v in fresh.state_dict().items() if k.startswith("sigma_nets")}
    model = copy.deepcopy(trained)
    model.load_state_dict(model.state_dict() | start)
    with torch.no_grad():
        model.machine_sigma.zero_()
    copies: dict[int, tuple[object, float]] = {}
    passes: list[int] = []
    chain_pass = train._fit_spread

    def fit_spread(model, terms, theta, omega, config, *, history, on_epoch) -> None:
        passes.append(1)
        if len(passes) == 1:  # the first pass as the chain runs it: the machine offsets
            chain_pass(model, terms, theta, omega, config, history=history, on_epoch=on_epoch)
            return
        fit = train.SpreadFit.start(model, terms, config)  # the chain's second pass, longer
        for epoch in range(1, epochs[-1] + 1):
            loss = fit.step(model, terms, theta, omega)
            if epoch in epochs:
                kept = copy.deepcopy(model)
                with torch.no_grad():
                    kept.machine_sigma.copy_(fit.log_machine.exp())
                    if fit.log_force is not None:
                        kept.lever_sigma.copy_(fit.log_force.exp())
                copies[epoch] = (kept.eval(), loss)
                force = ""
                if fit.log_force is not None:
                    force = f", σ_F {float(fit.log_force.detach().exp()[0]):.6f} N"
                print(f"epoch {epoch}: loss {loss:.5f}{force}", flush=True)

    train._fit_spread = fit_spread
    try:
        torch.manual_seed(0)
        train.train_sigma(model, dataset, splits, config, history=History())
    finally:
        train._fit_spread = chain_pass
    variability = Variability.from_dict(payload["variability"])
    physics = SliderCrank()
    for epoch, (kept, loss) in copies.items():
        checked = heldout_check(
            physics, args.ocp, kept, runs=args.runs, seed=args.seed, variability=variability
        )
        cells = checked["profiles"]["robust"]["open"]["samples"]
        print(
            f"second pass {epoch} epochs, loss {loss:.5f}: "
            + " | ".join(
                f"sample {k}: observed σ {1e3 * v['observed_sigma']:.2f} mm, predicted / observed "
                f"mixed {v['predicted']['mixed']['ratio']:.3f}, step "
                f"{v['predicted']['step']['ratio']:.3f}"
                for k, v in cells.items()
            ),
            flush=True,
        )


if __name__ == "__main__":
    main()
