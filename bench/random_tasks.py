"""Draw tasks nobody chose and write them as a `crank sweep` spec (bench/random_tasks.md).

The five tasks nobody tuned (README) were picked by hand. This draws tasks from a seed instead,
each on its own training seed, so that the robust torque is judged on tasks no session has seen:
horizon N uniform in 120..220 samples; 1 to 3 constraint samples, distinct, at least 10 apart,
uniform in [0.3 N, 0.7 N] (the crank turns once, pi to 3 pi, so the slider passes its top mid-way);
height uniform in [0.075, 0.085] m, to 0.1 mm. Task i runs on training seed i.

    python bench/random_tasks.py --root 20261284 --tasks 8 --heldout-seed 20261285 \
        --out bench/random_tasks_sweep.toml
"""

from __future__ import annotations

import argparse
import itertools
import math
import re
from pathlib import Path

import numpy as np

HORIZON = (120, 220)
SAMPLES = (1, 3)
WINDOW = (0.3, 0.7)
MIN_GAP = 10
HEIGHT = (0.075, 0.085)


def draw_tasks(root: int, count: int) -> list[dict]:
    """`count` tasks drawn from the stream of `root` (the module docstring's ranges)."""
    rng = np.random.default_rng(np.random.SeedSequence(root))
    tasks = []
    for _ in range(count):
        horizon = int(rng.integers(HORIZON[0], HORIZON[1] + 1))
        m = int(rng.integers(SAMPLES[0], SAMPLES[1] + 1))
        low, high = math.ceil(WINDOW[0] * horizon), math.floor(WINDOW[1] * horizon)
        while True:
            samples = sorted(int(k) for k in rng.choice(np.arange(low, high + 1), m, replace=False))
            if all(b - a >= MIN_GAP for a, b in itertools.pairwise(samples)):
                break
        height = round(float(rng.uniform(*HEIGHT)), 4)
        tasks.append({"horizon": horizon, "constraint_samples": samples, "height": height})
    return tasks


def task_name(i: int, task: dict) -> str:
    """Task `i`'s name: its case in the sweep spec, its row in bench/bench_tasks.py --drawn."""
    samples = ", ".join(str(k) for k in task["constraint_samples"])
    return f"task {i}: horizon {task['horizon']}, samples {samples}, height {task['height']}"


def task_of(name: str) -> tuple[int, dict]:
    """(i, task) of a name task_name wrote: the inverse of task_name."""
    found = re.fullmatch(r"task (\d+): horizon (\d+), samples ([\d, ]+), height (\S+)", name)
    if found is None:
        raise ValueError(f"not a drawn task's name: {name!r}")
    i, horizon, samples, height = found.groups()
    task = {
        "horizon": int(horizon),
        "constraint_samples": [int(k) for k in samples.split(", ")],
        "height": float(height),
    }
    return int(i), task


def task_index(name: str) -> int:
    """i of a name task_name wrote ("task i: ...")."""
    return task_of(name)[0]


def spec(tasks: list[dict], *, root: int, heldout_seed: int) -> str:
    """The sweep spec: the shipped default chain, task i on training seed i, the staged verdict
    on 1000 + 9000 machines of `heldout_seed`."""
    lines = [
        f"# Session 97 (bench/random_tasks.md, pre-registered before any step ran): "
        f"{len(tasks)} tasks drawn by",
        f"# `python bench/random_tasks.py --root {root} --tasks {len(tasks)} "
        f"--heldout-seed {heldout_seed}`,",
        "# task i on training seed i, the shipped default chain (both rounds, plan_fit); every",
        "# final robust torque judged by the staged verdict: 1000 machines of root "
        f"{heldout_seed} and,",
        "# where those cannot decide, 9000 more of the same draw.",
        "[base]",
        "heldout_runs = 1000",
        "heldout_second_stage = 9000",
        "baselines = false",
        "plan = { episodes = 240 }",
        "train = { mean_wrap = true, plan_fit = true }",
        "",
        "[grid]",
        f"heldout_seed = [{heldout_seed}]",
    ]
    for i, task in enumerate(tasks):
        samples = ", ".join(str(k) for k in task["constraint_samples"])
        lines += [
            "",
            "[[cases]]",
            f'name = "{task_name(i, task)}"',
            f"seed = {i}",
            f"ocp = {{ horizon = {task['horizon']}, constraint_samples = [{samples}], "
            f"height = {task['height']} }}",
        ]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=int, required=True, help="seed of the task draw")
    parser.add_argument("--tasks", type=int, default=8)
    parser.add_argument("--heldout-seed", type=int, required=True)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    tasks = draw_tasks(args.root, args.tasks)
    args.out.write_text(spec(tasks, root=args.root, heldout_seed=args.heldout_seed))
    for i, task in enumerate(tasks):
        print(f"task {i} (seed {i}): {task}")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
