"""Benchmark: the online MPC's per-step compute time (median, p99, max; target median < 2 ms, real
time at 500 Hz) at several horizons, beside one IPOPT nominal solve of the same model in the same
run, and the MPC campaign on the twin against the LQR closed loop and open loop.

    python bench/bench_mpc.py --ocp logs/<run>/ocp.json [--model logs/<run>/model.pt]
                              [--horizons 10,30,60] [--runs 20] [--no-do-mpc]

With do-mpc installed (`pip install -e ".[bench]"`; bench/dompc_ocp.py), the same nominal OCP is
also solved by do-mpc, beside the project's first IPOPT pass (the same NLP from the same initial
guess) and its full solve (turn passes included): the issue's target is the project's solve at
least 2x faster than do-mpc's. do-mpc is given the PPANN twice: as its networks (what a do-mpc
user writes) and as the project's angle splines (control/dynamics.py; like for like).

The per-step times are of one machine's controller (one RTI step: the rollout with sensitivities,
compiled to C — and at the second horizon also on CasADi's virtual machine, the fallback without
a compiler —, the condensed QP and its box active set in NumPy), measured as the twin's closed
loop calls it, on this process's one thread; nothing else should run beside it.
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import replace

import numpy as np

from control.dynamics import CasadiPPANN
from control.mpc_config import MPCConfig
from control.ocp import NominalOCP
from control.ocp_file import read_ocp
from ppann.model import PPANN
from replay.campaign import draw_machines, play
from replay.config import ReplayConfig
from replay.files import ocp_variability, plan_model
from replay.statistics import mpc_timing
from twin.physics import SliderCrank, load_model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ocp", required=True, help="ocp.json of a crank run")
    parser.add_argument("--model", default=None, help="its PPANN (default: the one it names)")
    parser.add_argument("--horizons", default="10,30,60")
    parser.add_argument("--runs", type=int, default=20, help="machines per campaign")
    parser.add_argument("--repeat", type=int, default=3, help="IPOPT solves (median)")
    parser.add_argument("--no-do-mpc", action="store_true", help="skip the do-mpc comparison")
    parser.add_argument("--profile", default="robust", help="the ocp.json profile played")
    args = parser.parse_args()
    model = plan_model(args.ocp, override=args.model)
    ocp = read_ocp(args.ocp)
    horizons = [int(h) for h in args.horizons.split(",")]
    if args.profile not in ocp.profiles:
        parser.error(
            f"{args.ocp} has no profile {args.profile!r} (it has {', '.join(ocp.profiles)}): "
            "choose one with --profile"
        )
    if len(horizons) < 2:
        parser.error("--horizons needs two or more (the second runs on the VM too)")
    physics = SliderCrank(load_model()[0])

    solvers = {}
    for label, compiled in (("CasADi VM, the default", False), ("--compiled", True)):
        started = time.perf_counter()
        nominal = NominalOCP(model, replace(ocp.config, compiled=compiled))
        build = time.perf_counter() - started
        solves, iterations = [], 0
        for _ in range(args.repeat):
            started = time.perf_counter()
            solution = nominal.solve()
            solves.append(time.perf_counter() - started)
            iterations = solution.iterations
        full = statistics.median(solves)
        solvers[f"{label}, {nominal.engine}"] = (nominal, full)
        print(
            f"IPOPT nominal solve ({label}: {nominal.engine}, build {build:.1f} s), full, cold "
            f"start, median of {args.repeat}: {full * 1e3:.0f} ms, {iterations} iterations, "
            f"{full / max(iterations, 1) * 1e3:.1f} ms per iteration"
        )
    ipopt = next(iter(solvers.values()))[1]
    print(f"model: {args.ocp} (horizon {ocp.horizon}, profile {args.profile})")
    if not args.no_do_mpc:
        compare_do_mpc(solvers, model, repeat=args.repeat)

    base = ReplayConfig(runs=args.runs, seed=1, variability=ocp_variability(args.ocp))
    machines = draw_machines(base, ocp.horizon)
    rows = []
    for mode in ("open", "closed"):
        config = replace(base, modes=(mode,))
        started = time.perf_counter()
        replay = play(
            physics, ocp, profile=args.profile, mode=mode, machines=machines, config=config
        )
        rows.append((mode, time.perf_counter() - started, replay, None))
    runs = [(h, True) for h in horizons]
    runs.append((horizons[1], False))  # the second horizon on the VM too
    for horizon, compiled in runs:
        config = replace(base, modes=("mpc",), mpc=MPCConfig(horizon=horizon, compiled=compiled))
        started = time.perf_counter()
        replay = play(
            physics,
            ocp,
            profile=args.profile,
            mode="mpc",
            machines=machines,
            config=config,
            model=model,
        )
        timing = mpc_timing(replay)
        label = f"mpc H={horizon}" + (" vm" if timing and timing["engine"] == "vm" else "")
        rows.append((label, time.perf_counter() - started, replay, timing))
    print(
        f"\n{'loop':<10} {'campaign s':>10} {'step median ms':>15} {'p99 ms':>8} {'max ms':>8} "
        f"{'misses':>7} {'IPOPT/step':>10} {'θ rms mrad':>11} {'lowest mm':>10}"
    )
    c = ocp.config
    for label, seconds, replay, timing in rows:
        lowest = min(replay.slider_position[:, k - 1].min() for k in c.constraint_samples)
        rms = 1e3 * float(np.sqrt(np.mean((replay.theta - ocp.profiles[args.profile].theta) ** 2)))
        if timing is None:
            cells = f"{'':>15} {'':>8} {'':>8} {'':>7} {'':>10}"
        else:
            cells = (
                f"{timing['median_ms']:>15.3f} {timing['p99_ms']:>8.3f} {timing['max_ms']:>8.3f} "
                f"{timing['deadline_misses']:>7} {ipopt * 1e3 / timing['median_ms']:>9.0f}×"
            )
        print(f"{label:<10} {seconds:>10.2f} {cells} {rms:>11.1f} {1e3 * lowest:>10.1f}")
    print(
        f"\n{args.runs} machines × {ocp.horizon - 1} steps per campaign; deadline "
        f"{1e3 * MPCConfig().deadline:g} ms; the IPOPT column is one nominal solve over the "
        "median MPC step."
    )


def _first_pass(nominal: NominalOCP, repeat: int) -> tuple[float, int, np.ndarray]:
    """The project's first IPOPT pass from its initial guess (median seconds, iterations, u)."""
    c, n = nominal.config, nominal.config.horizon
    guess = nominal.initial_guess()
    turns = np.floor(guess[0 : 2 * (n - 1) : 2] / (2 * np.pi))
    bounds = nominal.bounds(np.full(len(c.constraint_samples), c.height))
    times = []
    for _ in range(repeat):
        started = time.perf_counter()
        result = nominal._solver(x0=guess, p=turns, **bounds)
        times.append(time.perf_counter() - started)
    iterations = int(nominal._solver.stats()["iter_count"])
    return statistics.median(times), iterations, result["x"].full().ravel()[2 * n : 3 * n - 1]


def compare_do_mpc(
    solvers: dict[str, tuple[NominalOCP, float]], model: PPANN, *, repeat: int
) -> None:
    """do-mpc's solve of the same OCP, given the networks and given the angle splines, beside each
    project solver's first pass and full solve (`solvers`: label -> (the OCP, its median full
    solve in s))."""
    try:
        from dompc_ocp import DoMPCOCP  # bench/, beside this script
    except ImportError as exc:
        print(f"do-mpc: not installed ({exc}); pip install -e '.[bench]'")
        return
    reference = next(iter(solvers.values()))[0]
    dompc_seconds = {}
    for given, dynamics in (
        ("the networks", CasadiPPANN(model, splines=False)),
        ("the splines", reference.dynamics),
    ):
        started = time.perf_counter()
        dompc = DoMPCOCP(reference, dynamics=dynamics)
        build = time.perf_counter() - started
        dompc.solve()  # do-mpc's first call also sets itself up: not timed
        runs = [dompc.solve() for _ in range(repeat)]
        dompc_seconds[given] = seconds = statistics.median(r[0] for r in runs)
        _, iterations, status, tau = runs[-1]
        print(
            f"do-mpc 5.0.1 given {given}, the same OCP (build {build:.1f} s): "
            f"{seconds * 1e3:.0f} ms, {iterations} iterations, {status}, Σu² {np.sum(tau**2):.1f}"
        )
    for label, (nominal, full) in solvers.items():
        one, first_iterations, ours = _first_pass(nominal, repeat)
        ratios = "; ".join(
            f"do-mpc given {given} / project: first pass {seconds / one:.2f}, "
            f"full solve {seconds / full:.2f}"
            for given, seconds in dompc_seconds.items()
        )
        print(
            f"project ({label}): first IPOPT pass (the same NLP) {one * 1e3:.0f} ms, "
            f"{first_iterations} iterations, Σu² {np.sum(ours**2):.1f}; full solve with turn "
            f"passes {full * 1e3:.0f} ms. {ratios} (target: full solve >= 2)"
        )


if __name__ == "__main__":
    main()
