"""Benchmark: `crank run` end to end (generate, train, solve, replay, report) on this machine.

Runs the README's main job in a fresh interpreter into a temporary logs folder and prints its wall
time beside the per-step times it recorded in report.json, each with the range crank.estimate
gave before the run. Target: <= 5 min on 2 cores.

    python bench/bench_run.py [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        started = time.perf_counter()
        result = subprocess.run(
            [
                sys.executable,
                "-m",
                "crank",
                "run",
                "--seed",
                str(args.seed),
                "--logs",
                tmp,
                "--name",
                "bench",
            ],
            capture_output=True,
            text=True,
            check=False,
        )
        wall = time.perf_counter() - started
        if result.returncode != 0:
            sys.exit(f"crank run failed ({result.returncode}): {result.stderr.strip()[-500:]}")
        report = json.loads((Path(tmp) / "bench" / "report.json").read_text())
    estimated = report["estimated_seconds"]
    steps = ", ".join(
        f"{k} {v:.1f} s (estimated {estimated[k][0]:.0f}-{estimated[k][1]:.0f})"
        for k, v in report["wall_seconds"].items()
    )
    print(f"crank run --seed {args.seed}: {wall:.1f} s wall ({wall / 60:.2f} min, target <= 5 min)")
    print(f"  steps: {steps}")
    print(f"  claim: {report['replay']['claim']}")


if __name__ == "__main__":
    main()
