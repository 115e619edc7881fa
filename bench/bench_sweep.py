"""Benchmark: a sweep of 4 short chains (seeds 0-3) on a local Ray with 2 workers, against the
same sweep run step by step in one process (the sequential executor, torch on its default
threads), in the same run. Target: Ray's speed-up >= 1.7x on 2 cores. Also prints Ray's overhead:
starting the local instance, the round trip of an empty task, and the time the workers were not
running a step (wall x workers - the steps' own seconds) per step.

    python bench/bench_sweep.py [--seconds 30] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SPEC = """
[base]
heldout_runs = 200
baselines = false
[base.generation]
seconds = {seconds}
episode_seconds = 5.0
[base.train]
max_epochs = 20
sigma_epochs = 100
[base.ocp]
k_sigma = 0.5
height = 0.07
mc_samples = 300
confidence = 0.0
[base.replay]
runs = 20

[grid]
seed = [0, 1, 2, 3]
"""


def _step_seconds(out: Path) -> dict[str, float]:
    """The steps' own seconds, summed per kind, from their result.json files."""
    seconds: dict[str, float] = {}
    for path in out.glob("*/*/result.json"):
        result = json.loads(path.read_text())
        seconds[result["kind"]] = seconds.get(result["kind"], 0.0) + result["seconds"]
    return seconds


def _two_at_once(tmp: Path) -> float:
    """The machine's own parallel capacity for this work, without Ray: seeds 0-1 and 2-3 as two
    sequential sweeps in two processes at once, torch on one thread each."""
    env = os.environ | {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    started = time.perf_counter()
    processes = []
    for half in ("[0, 1]", "[2, 3]"):
        spec = tmp / f"half-{half[1]}.toml"
        spec.write_text((tmp / "bench.toml").read_text().replace("[0, 1, 2, 3]", half))
        command = [sys.executable, "-m", "crank", "sweep", str(spec), "--executor", "sequential"]
        command += ["--out", str(tmp / f"half-{half[1]}")]
        processes.append(subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL))
    if any(p.wait() != 0 for p in processes):
        sys.exit("a sequential half-sweep failed")
    return time.perf_counter() - started


def _noop() -> None:
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0, help="dataset length per chain")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    import ray
    import torch

    from crank.sweep import run_sweep

    with tempfile.TemporaryDirectory() as tmp:
        spec = Path(tmp) / "bench.toml"
        spec.write_text(SPEC.format(seconds=args.seconds))
        walls, rows, steps = {}, {}, {}
        runs = (("sequential", None), ("sequential, torch 1 thread", 1), ("ray", None))
        for label, threads in runs:
            out = Path(tmp) / label.replace(", ", "-").replace(" ", "-")
            default = torch.get_num_threads()
            torch.set_num_threads(threads or default)
            started = time.perf_counter()
            sweep = run_sweep(spec, out, executor=label.split(",")[0], workers=args.workers)
            walls[label] = time.perf_counter() - started
            torch.set_num_threads(default)
            rows[label] = sweep["rows"]
            steps[label] = _step_seconds(out)
        count = sum(sweep["step_counts"].values())
        walls["two sequential sweeps at once"] = _two_at_once(Path(tmp))
        t0 = time.perf_counter()
        ray.init(num_cpus=args.workers, include_dashboard=False, logging_level="ERROR")
        init_s = time.perf_counter() - t0
        task = ray.remote(num_cpus=1)(_noop)
        ray.get([task.remote() for _ in range(args.workers)])  # workers started
        t0 = time.perf_counter()
        for _ in range(50):
            ray.get(task.remote())
        trip_s = (time.perf_counter() - t0) / 50
        ray.shutdown()
    failed = sorted({f"{r['leaf']}: {r['error']}" for e in rows for r in rows[e] if r.get("error")})
    same = [
        {k: v for k, v in a.items() if not k.endswith(("_s", "error"))}
        == {k: v for k, v in b.items() if not k.endswith(("_s", "error"))}
        for a, b in zip(rows["sequential, torch 1 thread"], rows["ray"], strict=True)
    ]
    speedup = walls["sequential"] / walls["ray"]
    one_thread = walls["sequential, torch 1 thread"]
    busy = sum(steps["ray"].values())
    idle = (walls["ray"] * args.workers - busy) / count
    print(f"sweep of 4 chains ({count} steps, {args.seconds:g} s datasets), {args.workers} cores:")
    for label in walls:
        kinds = ", ".join(f"{k} {v:.1f}" for k, v in steps.get(label, {}).items())
        own = f"; steps' own s: {kinds}" if kinds else ""
        print(f"  {label:<30} {walls[label]:6.1f} s wall{own}")
    print(
        f"  speed-up over sequential {speedup:.2f}x (target >= 1.7x): "
        f"{'met' if speedup >= 1.7 else 'NOT met'}; over sequential at 1 thread "
        f"{walls['sequential, torch 1 thread'] / walls['ray']:.2f}x; the machine's own with two "
        f"processes and no Ray: {one_thread / walls['two sequential sweeps at once']:.2f}x"
    )
    print(
        f"  ray overhead: init {init_s:.1f} s, empty task round trip {1e3 * trip_s:.1f} ms, "
        f"workers idle or in Ray {idle:.2f} s per step"
    )
    print(
        f"  leaves with the same figures on ray and sequential at 1 thread: {sum(same)}/{len(same)}"
    )
    for line in failed:
        print(f"  failed: {line}")


if __name__ == "__main__":
    main()
