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
With `--record` (a passing run of the whole suite), it also writes the seconds each test file
took, from pytest's JUnit XML, to tests/file_seconds.json: the suite runs its files longest
first by it (tests/order.py), so record again after adding or much changing a long file.

    python bench/suite_time.py [--record | extra pytest arguments]
"""

from __future__ import annotations

import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests.order

from bench_generate import bare_rollout  # the script's folder is on the path

from tests.order import RECORD, junit_seconds, write_record
from twin.physics import SliderCrank, load_model

RUNS, SAMPLES = 20, 250


def reference_us(*, repeats: int = 3) -> float:
    """Median microseconds per physics step of a bare one-thread rollout of the twin."""
    physics = SliderCrank(load_model()[0])
    seconds = statistics.median(bare_rollout(physics, RUNS, SAMPLES, 1) for _ in range(repeats))
    return 1e6 * seconds / (RUNS * SAMPLES * physics.substeps)


def main() -> None:
    args = sys.argv[1:]
    record = "--record" in args
    args = [a for a in args if a != "--record"]
    if record and args:
        print(
            f"--record times the whole suite as the README runs it; got also {args}",
            file=sys.stderr,
        )
        sys.exit(2)
    with tempfile.TemporaryDirectory() as tmp:
        junit = Path(tmp) / "junit.xml"
        before = reference_us()
        started = time.perf_counter()
        command = [sys.executable, "-m", "pytest", "-q", *args]
        suite = subprocess.run(command + ([f"--junitxml={junit}"] if record else []), check=False)
        wall = time.perf_counter() - started
        after = reference_us()
        mean = 0.5 * (before + after)
        print(f"suite: exit {suite.returncode}, {wall:.0f} s wall (target <= 900 s)")
        print(f"reference: {before:.2f} us per physics step before, {after:.2f} after")
        print(f"suite / reference: {wall / mean:.0f} s per us")
        if record and suite.returncode == 0:
            seconds = junit_seconds(junit)
            write_record(seconds, reference_us=mean, wall_s=wall)
            print(f"recorded {len(seconds)} files, {sum(seconds.values()):.0f} s summed: {RECORD}")
        elif record:
            print(f"not recorded: the suite did not pass; {RECORD} unchanged")
    sys.exit(suite.returncode)


if __name__ == "__main__":
    main()
