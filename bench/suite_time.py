"""Benchmark: the test suite's wall time beside a reference workload timed on the same machine
just before and just after it.

The suite is the README's second command's pytest (`python -m pytest -q`: one worker per core,
pyproject.toml). The reference is one bare `mujoco.rollout` of the twin on one thread (20
machines x 250 samples x the twin's substeps, controls precomputed), in microseconds per physics
step: most of the suite is the twin's physics, CasADi and torch on one thread per worker. On the
AMD EPYC machine kind the host's load moved that reference from 7.3 to 4.6-4.9 us within one hour
(session 59), and the suite with it: a suite time means little without the reference beside it.

Prints the suite's wall time and exit code, the reference before and after, and the suite's
wall time per microsecond of reference. Target (README): wall time <= 900 s on 2 cores.

    python bench/suite_time.py [extra pytest arguments]
"""

from __future__ import annotations

import statistics
import subprocess
import sys
import time

from bench_generate import bare_rollout  # the script's folder is on the path

from twin.physics import SliderCrank, load_model

RUNS, SAMPLES = 20, 250


def reference_us(*, repeats: int = 3) -> float:
    """Median microseconds per physics step of a bare one-thread rollout of the twin."""
    physics = SliderCrank(load_model()[0])
    seconds = statistics.median(bare_rollout(physics, RUNS, SAMPLES, 1) for _ in range(repeats))
    return 1e6 * seconds / (RUNS * SAMPLES * physics.substeps)


def main() -> None:
    before = reference_us()
    started = time.perf_counter()
    suite = subprocess.run([sys.executable, "-m", "pytest", "-q", *sys.argv[1:]], check=False)
    wall = time.perf_counter() - started
    after = reference_us()
    mean = 0.5 * (before + after)
    print(f"suite: exit {suite.returncode}, {wall:.0f} s wall (target <= 900 s)")
    print(f"reference: {before:.2f} us per physics step before, {after:.2f} after")
    print(f"suite / reference: {wall / mean:.0f} s per us")
    sys.exit(suite.returncode)


if __name__ == "__main__":
    main()
