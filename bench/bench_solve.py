"""Benchmark: nominal OCP solve against the whole robust loop (every re-solve and Monte-Carlo),
measured in the same run (target: robust loop <= 3 × the nominal solve), with today's default
Monte-Carlo (1000 mixed trajectories, centred tightening, the line allowance at confidence 0.95),
with its margins by the aware scheme (control/aware.py) and by the bracketed loop, the same at
confidence 0, the same sized for the LQR closed loop (robust-fb, a tube) and for the
fixed PD (robust-pd, a tube), for
reference in the same run the paper's (100 step trajectories, confidence 0), and the default with
the NLP compiled to C (`--compiled`: every solve ~3x faster, the Monte-Carlo not, so the ratio
rises); last, one draft's Monte-Carlo with the rollout compiled (ppann/kernel.py, the default
where a C compiler is found) on every core (the kernel's threads) and on one, beside the NumPy
rollout, in the same run.

    python bench/bench_solve.py [--model logs/<run>/model.pt] [--repeat 3] [--mc-seeds 0-4]
        [--seeds-only] [--tail-sampling plain|lines]

Last, the default again on each of `--mc-seeds` (OCPConfig.mc_seed; the chain takes the
training seed): the loop's path (drafts, full solves, IPOPT iterations) depends on the
Monte-Carlo's draws, and one seed is one sample of it. Each seed's line also gives the ratio of
the profile as `crank solve` decides it (control/profiles.py solve_decided: the verdict's
re-decisions, then the torque's own tail check, one Monte-Carlo of 20 000 trajectories, and
where that is above its target the remedy, a raised k or the quantile tightening). The draft's
check runs beside the loop's next draft where the process has the cores (control/beside.py;
`CRANK_ROLLOUT_THREADS=1` keeps it in line, bench/beside_ab.py compares the two); the line says
which, and counts in "the own tail's checks in line" only the checks the loop waited for.

Without --model it solves on a PPANN with constant networks (the test suite's: prior J_m, B_m,
K_m, z_K = -0.9, z_sigma = 0.03, 0.05, 0.05), so it needs no training run; its nominal solve
(~12 ms) is shorter than one Monte-Carlo (~10 ms) times the loop's ~6, so the ratio target is
judged on a trained model (`crank run` writes logs/<run>/model.pt). The CasADi/IPOPT build
(expanding the networks into SX, once per model) is printed apart: it is paid once per
`crank solve`, not per solve.

The host's pace is printed first and last (bench/suite_time.py's reference: microseconds per
physics step of a bare one-thread rollout of the twin): the nominal solve and the loop's parts
speed up unequally with it (session 85: the nominal solve 92 ms at 2.9 us where session 72's
host gave 187 ms), so a ratio is read beside the pace it ran at.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

from suite_time import reference_us  # the script's folder is on the path

from common.errors import ConfigError
from common.threads import rollout_threads, set_rollout_threads
from control.beside import wanted
from control.config import TAIL_SAMPLINGS, OCPConfig
from control.ocp import NominalOCP, Solution
from control.profiles import solve_decided
from control.records import RobustResult
from control.robust import solve_robust
from control.tightening import slider_uncertainty
from crank.study import parse_seeds
from ppann import kernel
from ppann.checkpoint import load
from ppann.heads import FusedHeads
from ppann.model import PPANN, constant_ppann


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=None, help="PPANN checkpoint (default: constant nets)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--mc-seeds", default="0-4", help="Monte-Carlo seeds, e.g. 0-4 or 0,3")
    parser.add_argument(
        "--seeds-only", action="store_true", help="only the last section, per Monte-Carlo seed"
    )
    parser.add_argument(
        "--tail-sampling",
        default=OCPConfig().tail_sampling,
        choices=TAIL_SAMPLINGS,
        help="the own-tail check's draws",
    )
    args = parser.parse_args()
    try:
        mc_seeds = parse_seeds(args.mc_seeds, option="--mc-seeds")
    except ConfigError as exc:
        raise SystemExit(f"bench_solve: {exc}") from None
    if args.model:
        model, _ = load(args.model)
        source = args.model
    else:
        model = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))
        source = "constant networks"
    configs = {
        "default (1000 mixed, centred, confidence 0.95, aware margins)": (OCPConfig(), "robust"),
        "the same with the bracketed margin loop (margin_scheme bracket)": (
            OCPConfig(margin_scheme="bracket"),
            "robust",
        ),
        "default at confidence 0": (OCPConfig(confidence=0.0), "robust"),
        "default for the LQR closed loop (robust-fb, a tube)": (OCPConfig(), "robust-fb"),
        "default for the fixed-PD closed loop (robust-pd, a tube)": (OCPConfig(), "robust-pd"),
        "paper (100 step, gaussian, confidence 0)": (
            OCPConfig(mc_samples=100, mc_mode="step", confidence=0.0, tightening="gaussian"),
            "robust",
        ),
        "paper, bracketed margin loop": (
            OCPConfig(
                mc_samples=100,
                mc_mode="step",
                confidence=0.0,
                tightening="gaussian",
                margin_scheme="bracket",
            ),
            "robust",
        ),
        "default, NLP compiled to C (--compiled)": (OCPConfig(compiled=True), "robust"),
    }
    print(f"host: {reference_us():.2f} us per physics step (bench/suite_time.py's reference)")
    try:
        run(model, source, configs, mc_seeds, args)
    finally:
        print(f"host after: {reference_us():.2f} us per physics step")


def run(
    model: PPANN,
    source: str,
    configs: dict[str, tuple[OCPConfig, str]],
    mc_seeds: tuple[int, ...],
    args: argparse.Namespace,
) -> None:
    """Every section of the bench (only the seeds' with --seeds-only) on `model`."""
    started = time.perf_counter()
    ocps = {False: NominalOCP(model, OCPConfig())}
    build = time.perf_counter() - started
    if args.seeds_only:
        print(f"model: {source}\nbuild (SX expansion + IPOPT setup, once): {build:.2f} s")
        seed_paths(
            model, ocps[False], mc_seeds, repeat=args.repeat, tail_sampling=args.tail_sampling
        )
        return
    started = time.perf_counter()
    ocps[True] = NominalOCP(model, OCPConfig(compiled=True))
    build_compiled = time.perf_counter() - started
    print(f"model: {source}")
    print(
        f"build (SX expansion + IPOPT setup, once): {build:.2f} s; compiled "
        f"({ocps[True].engine}): {build_compiled:.2f} s"
    )
    for label, (config, profile) in configs.items():
        ocp = ocps[config.compiled]
        nominal, robust, mc, solution, result = timed(model, ocp, config, profile, args.repeat)
        ratios = [b / a for a, b in zip(nominal, robust, strict=True)]
        n, r = statistics.median(nominal), statistics.median(robust)
        drafts = sum(it.draft for it in result.iterations)
        ipopt = sum(it.ipopt_iterations for it in result.iterations)
        print(f"-- {label}")
        print(
            f"nominal solve (cold start), median of {args.repeat}: {n * 1e3:.0f} ms, "
            f"{solution.iterations} IPOPT iterations"
        )
        print(
            f"robust loop ({drafts} draft + {len(result.iterations) - drafts} full solves, "
            f"{ipopt} IPOPT iterations, {len(result.iterations)} Monte-Carlo taking "
            f"{statistics.median(mc) * 1e3:.0f} ms), median: {r * 1e3:.0f} ms"
        )
        print(
            f"ratio robust / nominal: {r / n:.2f} (target <= 3); per repeat "
            f"{min(ratios):.2f}-{max(ratios):.2f}"
        )
        print(f"{profile} cost premium: {result.robust.cost / result.nominal.cost - 1:+.1%}")
    monte_carlo_paths(model, result.robust, OCPConfig(), repeat=args.repeat)
    seed_paths(model, ocps[False], mc_seeds, repeat=args.repeat, tail_sampling=args.tail_sampling)


def timed(
    model: PPANN, ocp: NominalOCP, config: OCPConfig, profile: str, repeat: int
) -> tuple[list[float], list[float], list[float], Solution, RobustResult]:
    """`repeat` times a cold nominal solve and, just after it, the robust loop of `profile`:
    the nominal times, the loops' times and their Monte-Carlos' times (s), the last nominal
    solution and the last robust result."""
    nominal, robust, mc = [], [], []
    for _ in range(repeat):
        started = time.perf_counter()
        solution = ocp.solve()
        nominal.append(time.perf_counter() - started)
        result = solve_robust(model, config, profile=profile, ocp=ocp)
        robust.append(result.wall_time)
        mc.append(sum(it.monte_carlo_time for it in result.iterations))
    return nominal, robust, mc, solution, result


def seed_paths(
    model: PPANN, ocp: NominalOCP, seeds: tuple[int, ...], *, repeat: int, tail_sampling: str
) -> None:
    """The default robust loop on each Monte-Carlo seed: its solves and the ratio (median of
    `repeat`, each robust loop against the nominal solve timed just before it); beside it the
    profile as `crank solve` decides it (control/profiles.py solve_decided: the verdict's
    re-decisions, the torque's own tail check and, where that is above its target, the
    remedy), against a nominal solve timed just before it too."""
    print(f"-- the default on Monte-Carlo seeds {', '.join(map(str, seeds))}")
    ratios, decided, solves = [], [], []
    heads = FusedHeads(model)
    beside = wanted(None)
    print(f"the draft's check {'beside the loop' if beside else 'in line'} (control/beside.py)")
    for seed in seeds:
        config = OCPConfig(mc_seed=seed, tail_sampling=tail_sampling)
        nominal, robust, _, _, result = timed(model, ocp, config, "robust", repeat)
        runs = [b / a for a, b in zip(nominal, robust, strict=True)]
        its = result.iterations
        drafts = sum(it.draft for it in its)
        ratios.append(statistics.median(runs))
        solves += nominal
        whole, checked = [], []
        for _ in range(repeat):
            started = time.perf_counter()
            solution = ocp.solve()
            spent = time.perf_counter() - started
            final = solve_decided(
                model, config, profile="robust", ocp=ocp, nominal=solution, heads=heads
            )
            solves.append(spent)
            whole.append(final.wall_time / spent)
            # the draft's check runs beside the loop where it can (control/beside.py): not a
            # part of the wall time then
            counted = [c for c in final.tail_checks if not (c.draft and beside)]
            checked.append(sum(c.wall_time for c in counted) / spent)
        decided.append(statistics.median(whole))
        checks = ", ".join(
            f"k {c.k_sigma:g} {100 * c.rate:.2f} % of {c.draws} in {c.wall_time:.2f} s"
            for c in final.tail_checks
        )
        print(
            f"seed {seed}: {drafts} draft + {len(its) - drafts} full solves, "
            f"{sum(it.ipopt_iterations for it in its)} IPOPT iterations, ratio {ratios[-1]:.2f} "
            f"(repeats {min(runs):.2f}-{max(runs):.2f}); as crank solve decides it "
            f"{decided[-1]:.2f} (repeats {min(whole):.2f}-{max(whole):.2f}, of which the own "
            f"tail's checks in line {statistics.median(checked):.2f}; own tail {checks}; "
            f"{final.tightening} at k {final.k_sigma:g}, premium "
            f"{final.robust.cost / final.nominal.cost - 1:+.1%})"
        )
    # the ratio's denominator in absolute terms: the same code reads 2.3 on a machine whose
    # IPOPT solves it in ~140 ms and 3.3 on one at ~85 ms (bench/study_linear.md)
    print(
        f"nominal solve (every timed one): median {1e3 * statistics.median(solves):.1f} ms, "
        f"{1e3 * min(solves):.1f}-{1e3 * max(solves):.1f}"
    )
    for what, values in (("", ratios), (" as crank solve decides it", decided)):
        print(
            f"ratio over the seeds{what}: median {statistics.median(values):.2f}, "
            f"{sum(r <= 3 for r in values)} of {len(values)} within 3"
        )


def monte_carlo_paths(model: PPANN, solution: Solution, config: OCPConfig, *, repeat: int) -> None:
    """One draft's Monte-Carlo (the robust loop's unit: simulation, transmission draws,
    tightening, line allowance) with the rollout compiled (ppann/kernel.py) on the process's
    rollout threads (every core), the same on one thread, and in NumPy."""
    heads = FusedHeads(model)
    times, before = {}, os.environ.get("CRANK_KERNEL")
    threads = rollout_threads()
    paths = (("threads", True, threads), ("one", True, 1), ("numpy", False, 1))
    for path, compiled, count in paths:
        os.environ["CRANK_KERNEL"] = "1" if compiled else "0"
        kernel.load.cache_clear()
        set_rollout_threads(count)
        slider_uncertainty(heads, solution, config, constraints_only=True)
        runs = []
        for _ in range(max(repeat, 5)):
            started = time.perf_counter()
            slider_uncertainty(heads, solution, config, constraints_only=True)
            runs.append(time.perf_counter() - started)
        times[path] = statistics.median(runs)
    set_rollout_threads(None)
    if before is None:
        os.environ.pop("CRANK_KERNEL")
    else:
        os.environ["CRANK_KERNEL"] = before
    kernel.load.cache_clear()
    print(
        f"-- one draft's Monte-Carlo ({config.mc_samples} {config.mc_mode}, "
        f"{max(config.constraint_samples) - 1} steps, with the allowances): compiled rollout on "
        f"{threads} threads {times['threads'] * 1e3:.1f} ms, on one "
        f"{times['one'] * 1e3:.1f} ms ({times['one'] / times['threads']:.2f}x), NumPy rollout "
        f"{times['numpy'] * 1e3:.1f} ms ({times['numpy'] / times['threads']:.2f}x)"
    )


if __name__ == "__main__":
    main()
