"""What decides a raise: each model's torque at each Monte-Carlo seed (k as configured, no tail
check), checked under several check seeds (control/tail.py's stream follows OCPConfig.mc_seed).
Prints each torque's own rate per check seed, and the means per torque and per check seed: the
spread along a row is the check's own noise, down a column the loop's. Each check draws
TAIL_DRAWS trajectories in one stage (the count its figures were taken at, session 33), not
the stages `crank solve` draws.

    python bench/tail_check_seeds.py MODEL.pt [MODEL.pt ...] [--mc-seeds 0-4] [--check-seeds 0-9]
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from common.errors import ConfigError
from control.config import OCPConfig
from control.ocp import NominalOCP
from control.profiles import decide, own_tail
from control.tail import TAIL_DRAWS
from crank.study import parse_seeds
from ppann.checkpoint import load
from ppann.heads import FusedHeads


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="+", help="PPANN checkpoints")
    parser.add_argument("--mc-seeds", default="0-4", help="Monte-Carlo seeds of the loop")
    parser.add_argument("--check-seeds", default="0-9", help="seeds of the check's draws")
    args = parser.parse_args()
    try:
        mc_seeds = parse_seeds(args.mc_seeds, option="--mc-seeds")
        check_seeds = parse_seeds(args.check_seeds, option="--check-seeds")
    except ConfigError as exc:
        raise SystemExit(f"tail_check_seeds: {exc}") from None
    rows = []
    for path in args.models:
        model, _ = load(path)
        heads = FusedHeads(model)
        for seed in mc_seeds:
            config = OCPConfig(mc_seed=seed)
            ocp = NominalOCP(model, config)
            result = decide(model, config, profile="robust", ocp=ocp, nominal=ocp.solve())
            rates = [
                own_tail(
                    heads,
                    result,
                    replace(config, mc_seed=c),
                    profile="robust",
                    draws=TAIL_DRAWS,
                ).rate
                for c in check_seeds
            ]
            rows.append(rates)
            line = " ".join(f"{100 * r:.3f}" for r in rates)
            print(f"{path} Monte-Carlo seed {seed}: own rate % per check seed {line}", flush=True)
    table = 100 * np.array(rows)
    print("mean per torque (%):", " ".join(f"{v:.3f}" for v in table.mean(axis=1)))
    print("mean per check seed (%):", " ".join(f"{v:.3f}" for v in table.mean(axis=0)))
    print(f"mean of all: {table.mean():.3f} %")


if __name__ == "__main__":
    main()
