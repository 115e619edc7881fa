"""Benchmark: where the test suite's time goes. Runs the suite (`python -m pytest -q`, the README's
second command's pytest) with bench/suite_work/sitecustomize.py loaded in every process it starts,
which times each dataset generated, model trained, OCP solver built and figure saved; then prints,
for each kind of work, its calls and seconds summed over all processes (the suite's wall time
beside it: two workers on two cores), the tests that spent most on it, and the work done again on
the same inputs (the same dataset bytes and training config and torch threads; the same NLP by
control/solvers.py's key; the same generation config and MJCF) beyond its first time.

    python bench/suite_work.py [--log work.jsonl] [extra pytest arguments]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

HERE = Path(__file__).resolve().parent


def summary(lines: list[dict], wall: float) -> str:
    """The report of the logged calls `lines` of a suite that took `wall` seconds."""
    out = [f"{wall:.0f} s wall; summed over every process the suite started:"]
    kinds: dict[str, list[dict]] = defaultdict(list)
    for line in lines:
        kinds[line["what"]].append(line)
    for what, calls in sorted(kinds.items(), key=lambda item: -sum(c["s"] for c in item[1])):
        seconds = sum(c["s"] for c in calls)
        by_key: dict[str, list[float]] = defaultdict(list)
        by_test: dict[str, float] = defaultdict(float)
        for call in calls:
            by_key[call["key"]].append(call["s"])
            by_test[call["test"] or "(outside a test)"] += call["s"]
        if what == "figure":  # keyed by file name: the same name is not the same inputs
            names = sorted(by_key.items(), key=lambda item: -sum(item[1]))[:5]
            out.append(f"  figure: {len(calls)} calls, {seconds:.0f} s; the costliest names:")
            out += [f"      {sum(t):6.1f} s  {len(t)} x {name}" for name, t in names]
        else:
            again = [times for times in by_key.values() if len(times) > 1]
            calls_again = sum(len(times) - 1 for times in again)
            repeated = sum(sum(times) - sum(times) / len(times) for times in again)
            out.append(
                f"  {what}: {len(calls)} calls, {seconds:.0f} s; {len(by_key)} distinct inputs, "
                f"{calls_again} calls again on inputs done before (~{repeated:.0f} s)"
            )
        out.append("    the tests that spent most on it:")
        for test, spent in sorted(by_test.items(), key=lambda item: -item[1])[:5]:
            out.append(f"      {spent:6.1f} s  {test}")
    return "\n".join(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--log", type=Path, help="Keep the JSON lines here (default: a temp file).")
    args, pytest_args = parser.parse_known_args()
    with tempfile.TemporaryDirectory() as tmp:
        log = args.log or Path(tmp) / "work.jsonl"
        log.unlink(missing_ok=True)
        log.touch()
        paths = [str(HERE / "suite_work"), *filter(None, [os.environ.get("PYTHONPATH")])]
        env = {**os.environ, "CRANK_WORKLOG": str(log), "PYTHONPATH": os.pathsep.join(paths)}
        started = time.perf_counter()
        suite = subprocess.run(
            [sys.executable, "-m", "pytest", "-q", *pytest_args], env=env, check=False
        )
        wall = time.perf_counter() - started
        lines = [json.loads(text) for text in log.read_text().splitlines() if text]
    print(f"suite: exit {suite.returncode}, " + summary(lines, wall))
    sys.exit(suite.returncode)


if __name__ == "__main__":
    main()
