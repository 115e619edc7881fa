"""The plan round's second training started from the first model's weights ("warm") against
the chain's round, which starts from the seed's fresh networks ("scratch"): one seed, one arm.

Session 51, development (bench/warm_round.md). The first solve, the plan's episodes and the
second solve are the chain's own stages (crank/stages.py); "warm" only loads the first model's
weights into the fresh PPANN before the second training (bench/warm_round.patch is the option
this was measured for, not landed). Writes into OUT the chain's round files and round.json
(seconds per stage, phase-1 epochs); check the torques with `crank heldout` (the md's commands).

    python bench/warm_round.py --seed S --first DIR --arm warm|scratch --out OUT \
        [--horizon 200 --samples 70,130]

DIR holds the first round's model.pt and dataset.mcap of training seed S (the default chain's).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

import ppann.fit as fit
from crank import stages
from crank.chain import Hooks, RunConfig
from ppann.checkpoint import load


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, required=True)
    parser.add_argument("--first", type=Path, required=True)
    parser.add_argument("--arm", choices=("warm", "scratch"), required=True)
    parser.add_argument("--episodes", type=int, default=240)
    parser.add_argument("--horizon", type=int, default=150, help="the task's (paper: 150)")
    parser.add_argument("--samples", default="50,100", help="its constraint samples")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    torch.set_num_threads(1)  # two arms run side by side on the two cores
    task = {
        "horizon": args.horizon,
        "constraint_samples": tuple(int(k) for k in args.samples.split(",")),
    }
    config = RunConfig.for_seed(
        args.seed, ocp=task, plan={"episodes": args.episodes}, baselines=False
    )
    out, first = args.out, args.out / stages.FIRST_ROUND
    first.mkdir(parents=True, exist_ok=True)
    seconds = {}
    t = time.perf_counter()
    stages.solve_first_round(config, args.first / stages.MODEL, first, hooks=Hooks())
    seconds["solve_first"] = time.perf_counter() - t
    t = time.perf_counter()
    stages.plan(config, args.first / stages.DATASET, first / stages.OCP, out)
    seconds["plan"] = time.perf_counter() - t
    if args.arm == "warm":
        start = load(args.first / stages.MODEL)[0].state_dict()
        fresh = fit.new_model

        def new_model(dataset, *, kind, config, ppann_config=None):
            model = fresh(dataset, kind=kind, config=config, ppann_config=ppann_config)
            if kind == "ppann":
                model.load_state_dict(start)
            return model

        fit.new_model = new_model
    t = time.perf_counter()
    report = stages.train(config, out / stages.PLAN_DATASET, out, hooks=Hooks(), baselines=False)
    seconds["train"] = time.perf_counter() - t
    t = time.perf_counter()
    stages.solve(config, out / stages.MODEL, out, hooks=Hooks())
    seconds["solve"] = time.perf_counter() - t
    entry = report["models"]["ppann"]
    summary = {
        "seed": args.seed,
        "arm": args.arm,
        "seconds": seconds,
        "epochs": entry["epochs"],
        "best_epoch": entry["best_epoch"],
    }
    (out / "round.json").write_text(json.dumps(summary, indent=1))
    print(summary)


if __name__ == "__main__":
    main()
