"""Benchmark: a raise's Monte-Carlo drawn again at the raised k (before session 57) against
`at_k` (control/tightening.py), both on the nominal plan of a trained model, in the same run
(median of `--repeat`).

    python bench/at_k_time.py --model logs/<run>/model.pt [--repeat 20]
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import replace

from control.config import OCPConfig
from control.ocp import NominalOCP
from control.tightening import at_k, slider_uncertainty
from ppann.checkpoint import load
from ppann.heads import FusedHeads


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", required=True, help="PPANN checkpoint")
    parser.add_argument("--repeat", type=int, default=20)
    args = parser.parse_args()
    model, _ = load(args.model)
    heads = FusedHeads(model)
    config = OCPConfig()
    solution = NominalOCP(model, config).solve()
    draft = slider_uncertainty(heads, solution, config, constraints_only=True)
    raised = replace(config, k_sigma=config.k_sigma + 0.2)
    drawn, moved = [], []
    for _ in range(args.repeat):
        started = time.perf_counter()
        slider_uncertainty(heads, solution, raised, constraints_only=True)
        drawn.append(time.perf_counter() - started)
        started = time.perf_counter()
        at_k(heads, solution, draft, raised)
        moved.append(time.perf_counter() - started)
    print(
        f"a draft's Monte-Carlo ({config.mc_samples} trajectories) drawn again at the raised k: "
        f"median {1e3 * statistics.median(drawn):.1f} ms; at_k: "
        f"{1e3 * statistics.median(moved):.2f} ms"
    )


if __name__ == "__main__":
    main()
