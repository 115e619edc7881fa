"""Why do the calibrated spread bounds of bench/calibrated_coverage.py miss where they do? The
misses of a file of its rows taken apart: the test at the truth itself (is the truth rejected?)
under the calibration's law, whose other components sit at each line's estimates, and under
the exact law (every component at the truth: the oracle, whose size is the tail by
construction, so its rate on the same lines says how extreme those lines are); what is left
is a bound below a truth a fresh test did not reject (session 82 read it as the interpolation
between candidates; session 83 found it mostly not: bench/read_between.py, inner_lines.py).

    python bench/calibration_size.py --model logs/<run>/model.pt --machines 3 \\
        --rows bench/calibrated_coverage_m3.jsonl [--seed 20261209] [--inner 500]

Each row's line is drawn again (its seed and index, as calibrated_coverage.py draws it) and
fitted by phase 2's Adam; `--inner` lines a component at each line's law, 20 000 at the oracle's.
Session 82: ~5 min for 800 lines of 2 or 3 machines on one core.
"""

from __future__ import annotations

import sys

import numpy as np
import torch
from bound_coverage import MISS, PICK_SEED, adam_fit, kept_machines, setup
from calibrated_coverage import drawn_line, read_rows, rows_parser

from ppann import inversion

ORACLE_LINES = 20_000
LAWS_KEY = 1_000_000
"""The laws' stream: the seed's child at this key, beyond any line's index."""
CHUNK = 16
"""Lines whose laws are simulated at once (16 x 3 x 500 = 24 000 fitted lines)."""


def main() -> None:
    args = rows_parser(__doc__).parse_args()
    torch.set_num_threads(1)
    kept = kept_machines(setup(args.model), args.machines, np.random.default_rng(PICK_SEED))
    rows = read_rows(args.rows)
    index = sorted(rows)
    b = torch.cat([drawn_line(kept, i, args.seed)[1] for i in index])
    log_s, c = adam_fit(kept, b)
    truth = kept.sigma.numpy()
    at_truth = kept.sigma[None].expand(len(index), 3)
    observed = inversion.one_sided_rises(kept.info, b, log_s, c, at_truth).clamp_min(0).numpy()
    tail = MISS
    rng = np.random.default_rng(np.random.SeedSequence(args.seed, spawn_key=(LAWS_KEY,)))
    many = kept.sigma[None].expand(ORACLE_LINES, 3)
    drawn = inversion.simulate(kept.info, many, kept.common[None].expand(ORACLE_LINES, 3), rng)
    ls, cs = adam_fit(kept, drawn)
    rises = inversion.one_sided_rises(kept.info, drawn, ls, cs, many).clamp_min(0).numpy()
    oracle = np.quantile(rises, 1 - tail, axis=0)
    estimate = log_s.exp().numpy()
    critical = np.zeros((len(index), 3))
    for first in range(0, len(index), CHUNK):
        part = list(range(first, min(first + CHUNK, len(index))))
        laws = [np.where(np.arange(3) == i, truth, estimate[j]) for j in part for i in range(3)]
        spread = torch.from_numpy(np.repeat(np.array(laws), args.inner, axis=0))
        mean = torch.from_numpy(np.repeat(c.numpy()[part], 3 * args.inner, axis=0))
        drawn = inversion.simulate(kept.info, spread, mean, rng)
        ls, cs = adam_fit(kept, drawn)
        rises = inversion.one_sided_rises(kept.info, drawn, ls, cs, spread).clamp_min(0).numpy()
        rises = rises.reshape(len(part), 3, args.inner, 3)
        for a, j in enumerate(part):
            critical[j] = [np.quantile(rises[a, i, :, i], 1 - tail) for i in range(3)]
        print(f"{part[-1] + 1}/{len(index)} lines", file=sys.stderr, flush=True)
    missed = np.array([rows[i]["spread_miss"] for i in index])
    rejected = observed > critical
    print(
        f"{len(index)} lines of {args.machines} machines; each bound stands for {100 * tail:.2f} %"
    )
    print(f"{'':44}" + "".join(f"{z:>8}" for z in ("J", "B", "K")))
    for name, rate in (
        ("bound missed (the rows)", missed.mean(0)),
        ("truth rejected, others at the line's estimate", rejected.mean(0)),
        ("truth rejected, all at the truth (oracle)", (observed > oracle).mean(0)),
        ("missed, truth not rejected", (missed & ~rejected).mean(0)),
        ("rejected, not missed", (rejected & ~missed).mean(0)),
    ):
        print(f"{name:44}" + "".join(f"{100 * v:7.2f}%" for v in rate))


if __name__ == "__main__":
    main()
