"""Do the calibrated spread bounds miss less with the product's 2000 lines a candidate than with
the bench's 500? The lines of a bench/calibrated_coverage.py file that missed, or whose bound
lay within `--near` of the truth (the lines that could flip), calibrated again from their own
fit with `--inner` lines a candidate (the product's CALIBRATION_LINES by default): which misses
persist, which near misses become misses.

    python bench/inner_lines.py --model logs/<run>/model.pt --machines 5 \\
        --rows bench/calibrated_coverage_m5.jsonl --seed 20261211 [--near 1.2] \\
        [--worker 0 --workers 2]

A line's calibration is drawn from its own stream, as the rows' (so a different draw at another
count); lines whose bound lay further above the truth are not read (the change of the bound
between the two counts is printed, to judge that). Session 83: ~40 s a line of five machines.
"""

from __future__ import annotations

import numpy as np
import torch
from bound_coverage import PICK_SEED, kept_machines, setup
from calibrated_coverage import calibrated_line, read_rows, rows_parser

from ppann.confidence import DEFAULT_CONFIDENCE, bound_level
from ppann.inversion import CALIBRATION_LINES, calibrated_upper
from ppann.model import Z_NAMES


def main() -> None:
    parser = rows_parser(__doc__)
    parser.set_defaults(inner=CALIBRATION_LINES)
    parser.add_argument("--near", type=float, default=1.2, help="bounds below near x truth")
    parser.add_argument("--worker", type=int, default=0)
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(1)
    kept = kept_machines(setup(args.model), args.machines, np.random.default_rng(PICK_SEED))
    rows = read_rows(args.rows)
    truth = kept.sigma.numpy()
    read = sorted(i for i, r in rows.items() if np.any(np.asarray(r["upper"]) < args.near * truth))
    mine = read[args.worker :: args.workers]
    print(f"{len(read)} of {len(rows)} lines below {args.near} x the truth; {len(mine)} here")
    tail = 1 - bound_level(DEFAULT_CONFIDENCE)
    for index in mine:
        _, _, profile, found = calibrated_line(kept, index, args.inner, args.seed)
        upper = calibrated_upper(profile, found.candidates, found.rise_tail, tail)
        before = np.asarray(rows[index]["upper"])
        print(
            f"line {index}: missed {(before < truth).astype(int)} with the rows' count, "
            f"{(upper < truth).astype(int)} with {args.inner}; bound / the rows' "
            + " ".join(f"{z} {u / v:.3f}" for z, u, v in zip(Z_NAMES, upper, before, strict=True)),
            flush=True,
        )


if __name__ == "__main__":
    main()
