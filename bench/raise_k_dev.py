"""Development (no machines drawn): each task solved as `crank solve` decides it, on one model over
Monte-Carlo seeds, and the robust profile's own-tail checks (k, own rate, trajectories drawn) —
how bench/raise_k.md part A compared the raise of k before and after control/raise_k.py (run
from a worktree of each commit).

    python bench/raise_k_dev.py --model logs/<run>/model.pt --out raise.json [--mc-seeds 0-4]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from common.errors import ConfigError, CrankError
from control.config import OCPConfig
from control.profiles import solve_profiles
from crank.study import parse_seeds
from ppann.checkpoint import load

TASKS: dict[str, dict] = {
    "paper": {},
    "height 0.085": {"height": 0.085},
    "samples 60, 90": {"constraint_samples": (60, 90)},
    "horizon 200": {"horizon": 200, "constraint_samples": (70, 130)},
}
"""The tasks a default model raises k on (the stroke's edge is refused whatever the raise)."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", required=True)
    parser.add_argument("--out", required=True, help="JSON file of one row per task and seed")
    parser.add_argument("--mc-seeds", default="0-4")
    args = parser.parse_args()
    try:
        seeds = parse_seeds(args.mc_seeds, option="--mc-seeds")
    except ConfigError as exc:
        raise SystemExit(f"raise_k_dev: {exc}") from None
    torch.set_num_threads(1)
    model, _ = load(args.model)
    rows = []
    for name, task in TASKS.items():
        for seed in seeds:
            started = time.perf_counter()
            try:
                solved = solve_profiles(model, OCPConfig(**task, mc_seed=seed))
            except CrankError as exc:
                checks, error = [], str(exc)
            else:
                robust = solved.results.get("robust")
                tail = robust.tail_checks if robust else ()
                checks = [(c.k_sigma, c.rate, c.draws) for c in tail]
                error = None if robust else str(solved.refused.get("robust"))
            row = {"task": name, "mc_seed": seed, "checks": checks, "error": error}
            rows.append(row | {"seconds": time.perf_counter() - started})
            print(json.dumps(row), flush=True)
    Path(args.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
