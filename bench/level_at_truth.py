"""The spread level that would make each machine-spread bound exact through phase 2's own fit:
the 1 - 1/60 quantile of the profile rise at the true spread over lines drawn at the truth
(bench/bound_coverage.py's lines and fit), beside ppann/confidence.py's exact-for-direct level
and how often that one misses. What a test inversion by simulation would use at the truth
(bench/bound_coverage.md).

    python bench/level_at_truth.py --model logs/<run>/model.pt [--machines 8] [--lines 16000]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from bound_coverage import MISS, PICK_SEED, adam_fit, kept_machines, setup, simulate

from ppann.confidence import DEFAULT_CONFIDENCE, spread_level
from ppann.inversion import one_sided_rises
from ppann.model import Z_NAMES


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=Path, required=True)
    parser.add_argument("--machines", type=int, default=0)
    parser.add_argument("--lines", type=int, default=16000)
    parser.add_argument("--seed", type=int, default=20261207)
    args = parser.parse_args()
    torch.set_num_threads(2)
    full = setup(args.model)
    kept = kept_machines(full, args.machines, np.random.default_rng(PICK_SEED))
    rng, rises, done = np.random.default_rng(args.seed), [], 0
    while done < args.lines:
        n = min(4000, args.lines - done)
        b = simulate(kept, n, rng)
        log_s, c = adam_fit(kept, b)
        rises.append(one_sided_rises(kept.info, b, log_s, c, kept.sigma.expand(n, 3)))
        done += n
    rise = torch.cat(rises)
    m = kept.info.shape[0]
    exact = spread_level(DEFAULT_CONFIDENCE, m)
    level = torch.quantile(rise, 1 - MISS, dim=0)
    missed = (rise > exact).double().mean(0)
    print(f"{args.model}, {m} machines, {args.lines} lines; exact level {exact:.2f}")
    for name, q, rate in zip(Z_NAMES, level.tolist(), missed.tolist(), strict=True):
        print(
            f"  {name}: the level at the truth {q:.2f}; the exact level misses {100 * rate:.2f} %"
        )


if __name__ == "__main__":
    main()
