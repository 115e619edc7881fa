"""Benchmark: the open-loop robust loop with the aware margin scheme (control/aware.py, the
default) against the bracketed one (control/robust.py), on the same models and tasks, each timed
in the same run against the nominal solve (issue 11's ratio, target <= 3).

    python bench/bench_aware.py --model M [--model M2 ...] [--only "horizon 200"] [--repeat 3]

Per model and task (bench/bench_tasks.py's): the nominal solve (cold start),
each scheme's loop (drafts + full solves, IPOPT iterations; the loop as solve_robust times it,
from after the nominal's Monte-Carlo; the aware NLP's build, once per task like the nominal's,
outside it), their ratios to the nominal, the premiums, the margins at the constraint samples and
the slack margin - tightening of the returned torque by its own Monte-Carlo (>= -0.1 mm, the
tolerance, for both schemes). Median of `repeat`.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from bench_tasks import TASKS  # the script's folder is on the path

from control.config import OCPConfig
from control.ocp import NominalOCP
from control.records import RobustResult
from control.robust import RobustError, solve_robust
from ppann.checkpoint import load

SCHEMES = ("bracket", "aware")


def _row(model_path: str, task: str, *, repeat: int) -> None:
    model, _ = load(model_path)
    configs = {s: OCPConfig(**TASKS[task], margin_scheme=s) for s in SCHEMES}
    ocp = NominalOCP(model, configs["aware"])
    times: dict[str, list[float]] = {"nominal": [], **{s: [] for s in SCHEMES}}
    results: dict[str, RobustResult] = {}
    for _ in range(repeat):
        started = time.perf_counter()
        nominal = ocp.solve()
        times["nominal"].append(time.perf_counter() - started)
        for scheme, config in configs.items():
            try:
                results[scheme] = solve_robust(model, config, ocp=ocp, nominal=nominal)
            except RobustError as exc:
                print(f"| {task} | refused by the {scheme} scheme: {exc} |", flush=True)
                return
            times[scheme].append(results[scheme].wall_time)
    t = {k: statistics.median(v) for k, v in times.items()}
    cells = [task, f"{t['nominal'] * 1e3:.0f}"]
    for scheme in SCHEMES:
        its = results[scheme].iterations
        drafts = sum(it.draft for it in its)
        ipopt = sum(it.ipopt_iterations for it in its)
        cells.append(f"{t[scheme] * 1e3:.0f} ({drafts}+{len(its) - drafts}, {ipopt})")
    cells += [f"{t[s] / t['nominal']:.2f}" for s in SCHEMES]
    index = np.array(configs["aware"].constraint_samples) - 1
    height = configs["aware"].height
    margins = {s: r.robust.slider[index] - height for s, r in results.items()}
    cells.append(" / ".join(f"{r.robust.cost / nominal.cost - 1:+.2%}" for r in results.values()))
    cells.append(" / ".join(_mm(margins[s]) for s in SCHEMES))
    slack = [margins[s] - results[s].robust_uncertainty.tightening for s in SCHEMES]
    cells.append(" / ".join(_mm(v) for v in slack))
    print("| " + " | ".join(cells) + " |", flush=True)


def _mm(values: np.ndarray) -> str:
    return ", ".join(f"{1e3 * v:.2f}" for v in values)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", action="append", required=True, help="PPANN checkpoint(s)")
    parser.add_argument("--only", default="", help="run the tasks whose name contains this")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    tasks = [t for t in TASKS if args.only in t]
    if not tasks:
        parser.error(f"no task's name contains {args.only!r}; the tasks: {'; '.join(TASKS)}")
    print(
        "| task | nominal ms | bracket loop ms (drafts+full, IPOPT it.) | aware loop ms | "
        "ratio, bracket | ratio, aware | premium, bracket / aware | margins mm | "
        "slack (margin - tightening) mm |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for path in args.model:
        print(f"| {path} | | | | | | | | |", flush=True)
        for task in tasks:
            _row(path, task, repeat=args.repeat)


if __name__ == "__main__":
    main()
