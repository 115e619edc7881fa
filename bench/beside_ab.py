"""The draft's own-tail check beside the aware loop (control/beside.py) against in line, A/B in
one process: `crank solve`'s decided robust profile on each model at each Monte-Carlo seed,
the two alternated per repeat, each decided wall time over a cold nominal solve timed just
before it (bench/bench_solve.py's ratio), the median of `--repeat`. Each line: the pair's
ratio in line and beside, and whether the two returned the same torque (they must: the
check's answer, not its timing, decides the path). Run it idle and alone: beside takes both
cores.

    PYTHONPATH=. python bench/beside_ab.py --model M.pt [--model M2.pt ...] [--mc-seeds 0-4]
        [--repeat 3] [--check-threads 1]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

import control.aware as aware
import control.beside as beside
from common.errors import ConfigError
from control.config import OCPConfig
from control.ocp import NominalOCP
from control.profiles import solve_decided
from crank.study import parse_seeds
from ppann.checkpoint import load
from ppann.heads import FusedHeads

WAYS = {"in line": False, "beside": True}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", action="append", required=True, help="PPANN checkpoint")
    parser.add_argument("--mc-seeds", default="0-4", help="Monte-Carlo seeds, e.g. 0-4 or 0,3")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument(
        "--check-threads", type=int, default=beside.CHECK_THREADS, help="the check's rollouts'"
    )
    args = parser.parse_args()
    try:
        seeds = parse_seeds(args.mc_seeds, option="--mc-seeds")
    except ConfigError as exc:
        parser.exit(2, f"beside_ab.py: {exc}\n")
    if args.repeat < 1 or args.check_threads < 1:
        parser.exit(2, "beside_ab.py: --repeat and --check-threads must be >= 1\n")
    beside.CHECK_THREADS = args.check_threads
    within = dict.fromkeys(WAYS, 0)
    pairs = 0
    for path in args.model:
        model = load(path)[0]
        ocp, heads = NominalOCP(model, OCPConfig()), FusedHeads(model)
        ocp.solve()  # the IPOPT build and first-call costs out of the timings
        print(f"== {path}", flush=True)
        for seed in seeds:
            config = OCPConfig(mc_seed=seed)
            ratios: dict[str, list[float]] = {way: [] for way in WAYS}
            torques = {}
            for _ in range(args.repeat):
                for way, on in WAYS.items():
                    aware.wanted = lambda given, on=on: on
                    started = time.perf_counter()
                    nominal = ocp.solve()
                    spent = time.perf_counter() - started
                    result = solve_decided(
                        model, config, profile="robust", ocp=ocp, nominal=nominal, heads=heads
                    )
                    ratios[way].append(result.wall_time / spent)
                    torques[way] = result.robust.tau
            same = np.array_equal(*torques.values())
            median = {way: statistics.median(r) for way, r in ratios.items()}
            pairs += 1
            for way, value in median.items():
                within[way] += value <= 3
            print(
                f"seed {seed}: "
                + ", ".join(
                    f"{way} {median[way]:.2f} ({min(r):.2f}-{max(r):.2f})"
                    for way, r in ratios.items()
                )
                + f"; the same torque: {same}",
                flush=True,
            )
            if not same:
                sys.exit("beside_ab.py: the two ways returned different torques")
    print(", ".join(f"{way}: {n} of {pairs} within 3" for way, n in within.items()))


if __name__ == "__main__":
    main()
