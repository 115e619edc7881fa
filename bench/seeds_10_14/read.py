"""bench/seeds_10_14.md part 1's table from its outputs: per training seed the robust torque's
held-out machines below (of 4000, root 20261218) with the exact 95 % bound, k, premium, the
nominal torque's machines below, phase 1's epochs and the σ ratio (mixed, slider) at samples 50
and 100 with its interval.

    python bench/seeds_10_14/read.py SOLVES MODELS > bench/seeds_10_14/summary.txt

SOLVES/<s>/{ocp.json, heldout.json} (crank solve, crank heldout) and MODELS/s<s>/model.report.json
(the training), for s in 10..14."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def main() -> None:
    solves, models = Path(sys.argv[1]), Path(sys.argv[2])
    below = runs = 0
    for seed in range(10, 15):
        held = json.loads((solves / str(seed) / "heldout.json").read_text())
        ocp = json.loads((solves / str(seed) / "ocp.json").read_text())
        ppann = json.loads((models / f"s{seed}" / "model.report.json").read_text())["models"]
        ppann = ppann["ppann"]
        robust = held["profiles"]["robust"]["open"]
        below, runs = below + robust["violating_runs"], runs + held["runs"]
        ratios = []
        for k in ("50", "100"):
            p = robust["samples"][k]["predicted"]["mixed"]
            ratios.append(
                f"{k}: {p['ratio']:.3f} ({p['ratio_ci95'][0]:.3f}-{p['ratio_ci95'][1]:.3f})"
            )
        print(
            f"seed {seed}: robust {robust['violating_runs']} of {held['runs']} below "
            f"(bound {100 * robust['rate_upper_95']:.2f} %), k {ocp['robust']['k_sigma']:g}, "
            f"premium {100 * (ocp['robust']['cost'] / ocp['nominal']['cost'] - 1):.2f} %, "
            f"nominal {held['profiles']['nominal']['open']['violating_runs']} of {held['runs']}; "
            f"phase 1 {ppann['epochs']} epochs (converged {ppann['phase1_converged']}); "
            f"σ ratio {', '.join(ratios)}; the model's own rate "
            f"{100 * robust['model_rate']['rate']:.3f} %"
        )
    print(f"all: {below} of {runs} below")


if __name__ == "__main__":
    main()
