"""Benchmark: where one robust decision's time goes (`crank solve`'s, control/profiles.py
solve_decided, the default OCPConfig), on a trained model, beside the nominal solve timed just
before it in the same process: CasADi's calls (IPOPT's solves), the compiled Monte-Carlo's
rollouts (ppann/kernel.py), waits on threads (the draft's check beside the loop), and the rest
(NumPy and Python). Each decision runs under cProfile, which slows the Python parts: the ratio
reads ~15 % above bench_solve.py's on the same model (2.55 against 2.16 in session 68), so the
shares of the C calls (CasADi, the kernel) are if anything understated.

bench_solve.py gives the ratio this splits: the decision against the nominal solve (target
<= 3). The split says how the ratio moves on a machine whose IPOPT is quicker than its
Monte-Carlo (README, *Benchmarks*: the Intel kind's nominal solve was ~3x quicker than the AMD
kind's, its Monte-Carlo ~2x).

    python bench/decision_parts.py --model logs/<run>/model.pt [--mc-seeds 0-4]

The first decision of a process also builds the aware OCP (~3 s): a warm-up decision on
Monte-Carlo seed 0 runs first and is not counted.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import statistics
import time

from control.config import OCPConfig
from control.ocp import NominalOCP
from control.profiles import solve_decided
from crank.study import parse_seeds
from ppann.checkpoint import load
from ppann.heads import FusedHeads

PARTS = {
    "casadi": lambda name, _file: "casadi._casadi" in name or "Function_call" in name,
    "kernel": lambda name, file: file.endswith("ppann/kernel.py") and name == "run",
    "waits": lambda name, _file: "acquire" in name and "lock" in name,
}
"""Which profiled functions' own time counts in each part (their tottime)."""


def parts(stats: pstats.Stats) -> dict[str, float]:
    """Seconds of own time per part (PARTS) in a profile."""
    out = dict.fromkeys(PARTS, 0.0)
    for (file, _line, name), (_cc, _nc, tottime, _ct, _callers) in stats.stats.items():  # type: ignore[attr-defined]
        for part, matches in PARTS.items():
            if matches(name, file):
                out[part] += tottime
                break
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", required=True, help="a trained PPANN checkpoint")
    parser.add_argument("--mc-seeds", default="0-4", help="Monte-Carlo seeds (default 0-4)")
    args = parser.parse_args()
    model, _ = load(args.model)
    seeds = parse_seeds(args.mc_seeds)
    ocp = NominalOCP(model, OCPConfig())
    heads = FusedHeads(model)
    solve_decided(
        model, OCPConfig(mc_seed=0), profile="robust", ocp=ocp, nominal=ocp.solve(), heads=heads
    )  # warm-up: builds the aware OCP
    ratios = []
    for seed in seeds:
        started = time.perf_counter()
        nominal = ocp.solve()
        nominal_s = time.perf_counter() - started
        profile = cProfile.Profile()
        started = time.perf_counter()
        profile.enable()
        solve_decided(
            model,
            OCPConfig(mc_seed=seed),
            profile="robust",
            ocp=ocp,
            nominal=nominal,
            heads=heads,
        )
        profile.disable()
        whole = time.perf_counter() - started
        split = parts(pstats.Stats(profile))
        rest = whole - sum(split.values())
        ratios.append(whole / nominal_s)
        shares = ", ".join(f"{k} {1e3 * v:.0f} ms ({v / whole:.0%})" for k, v in split.items())
        print(
            f"Monte-Carlo seed {seed}: nominal {1e3 * nominal_s:.0f} ms, decision "
            f"{1e3 * whole:.0f} ms (ratio {whole / nominal_s:.2f}): {shares}, "
            f"rest {1e3 * rest:.0f} ms ({rest / whole:.0%})"
        )
    print(f"ratio under the profiler: median {statistics.median(ratios):.2f}")


if __name__ == "__main__":
    main()
