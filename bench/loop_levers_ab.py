"""Development (session 49, bench/loop_levers.md): the wall time of `crank solve`'s decided
robust profile with IPOPT's barrier started lower, A/B in one process. Needs
bench/loop_levers_barrier.patch applied (the variants' mu_init read from WARMMU and DRAFTMU when
NominalOCP is built): two or more NominalOCPs of the same model built with other values,
alternated per repeat (5 each), on the five default models of training seeds 0-4 (the
session-45 ones; the paths are this machine's) at Monte-Carlo seeds FIRST-LAST. Each line: the
median decided wall time over a nominal solve timed after them (5 solves), per variant.

    PYTHONPATH=. python bench/loop_levers_ab.py 5 9 1e-3/1e-6 1e-7/1e-7 1e-5/1e-7
"""

from __future__ import annotations

import os
import statistics
import sys
import time

from aware_residuals import MODELS, decided, load_default  # the script's folder is on the path

from control.config import OCPConfig
from control.ocp import NominalOCP
from ppann.heads import FusedHeads

REPEAT = 5


def main() -> None:
    first, last, *named = sys.argv[1:]
    variants = [tuple(v.split("/")) for v in named]  # warm full solves' mu_init / drafts'
    total = dict.fromkeys(variants, 0.0)
    for key in MODELS:
        model = load_default(key)
        heads = FusedHeads(model)
        ocps = {}
        for warm, draft in variants:
            os.environ["WARMMU"], os.environ["DRAFTMU"] = warm, draft
            ocps[(warm, draft)] = NominalOCP(model, OCPConfig())
        reference = ocps[variants[0]]
        nominal = reference.solve()
        for seed in range(int(first), int(last) + 1):
            times: dict[tuple[str, ...], list[float]] = {v: [] for v in ocps}
            for _ in range(REPEAT):
                for variant, ocp in ocps.items():
                    result = decided(model, ocp, nominal=nominal, heads=heads, seed=seed)
                    times[variant].append(result.wall_time)
            started = time.perf_counter()
            for _ in range(REPEAT):
                reference.solve()
            spent = (time.perf_counter() - started) / REPEAT
            median = {v: statistics.median(t) for v, t in times.items()}
            for variant, value in median.items():
                total[variant] += value
            ratios = " ".join(f"{w}/{d} {m / spent:.2f}" for (w, d), m in median.items())
            print(key[:3], seed, f"nominal {1e3 * spent:.0f} ms", ratios, flush=True)
    print("total", {f"{w}/{d}": round(t, 3) for (w, d), t in total.items()})


if __name__ == "__main__":
    main()
