"""Does a robust verdict depend on the Monte-Carlo seed? (issue 11, session 27)

    python bench/mc_seed_verdicts.py --model M/model.pt [--seeds 0-4]

Solves the robust OCP of the paper task and the four untuned tasks of the README (height 0.085;
samples 60, 90; horizon 200 with samples 70, 130; height 0.075 with samples 40, 120) with each
Monte-Carlo seed, and prints per task and seed the margins it keeps at the constraint samples
(least / most, mm) and the cost premium, or the one-line reason it refused. Solves only: whether
a returned torque holds is the sweeps' held-out check. ~10 s a solve on one core.
"""

from __future__ import annotations

import argparse

from common.errors import CrankError
from control.config import OCPConfig
from control.robust import solve_robust
from ppann.checkpoint import load

TASKS: dict[str, dict] = {
    "paper": {},
    "height 0.085": {"height": 0.085},
    "samples 60, 90": {"constraint_samples": (60, 90)},
    "horizon 200, samples 70, 130": {"horizon": 200, "constraint_samples": (70, 130)},
    "height 0.075, samples 40, 120": {"height": 0.075, "constraint_samples": (40, 120)},
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", required=True)
    parser.add_argument("--seeds", default="0-4", help="Monte-Carlo seeds, first-last")
    args = parser.parse_args()
    try:
        first, last = (int(part) for part in args.seeds.split("-"))
    except ValueError:
        parser.error(f"--seeds must be first-last, e.g. 0-4, got {args.seeds!r}")
    model, _ = load(args.model)
    for name, task in TASKS.items():
        cells = []
        for seed in range(first, last + 1):
            config = OCPConfig(**task, mc_seed=seed)
            try:
                result = solve_robust(model, config)
            except CrankError as exc:
                cells.append(f"refused ({str(exc)[:60]}…)")
                continue
            margin = 1e3 * (result.robust.heights - config.height)
            premium = 100 * (result.robust.cost / result.nominal.cost - 1)
            cells.append(f"{margin.min():.2f}/{margin.max():.2f} mm +{premium:.1f} %")
        print(f"{name}: " + " | ".join(cells), flush=True)


if __name__ == "__main__":
    main()
