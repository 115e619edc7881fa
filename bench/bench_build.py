"""Benchmark: building an OCP's IPOPT solvers (control/solvers.py `build`) as the OCPs pose them,
beside the same build with CasADi's gradient of the Lagrangian (`nlp_grad`, which control/ocp.py
no longer asks for), in turn on the same NLPs in one run: the nominal NLP and the aware one
(control/aware.py) of a trained model. Prints each build's median seconds, the ratio, and
whether a nominal solve on either gives the same torque to the last bit.

    python bench/bench_build.py --model logs/<run>/model.pt [--repeat 3]
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import numpy as np

from control import solvers as solvers_module
from control.aware import SURROGATE, aware_ocp
from control.config import OCPConfig
from control.ocp import NominalOCP
from ppann.checkpoint import load


def _posed(model: Any, config: OCPConfig) -> dict[str, tuple[dict, dict]]:
    """The nominal and aware NLPs of `model` and their options, as the OCPs pass them."""
    posed: list[tuple[dict, dict]] = []
    built = solvers_module.build

    def capture(nlp: dict, options: dict, *, compiled: bool) -> solvers_module.Solvers:
        posed.append((nlp, options))
        return built(nlp, options, compiled=compiled)

    solvers_module.build = capture
    try:
        ocp = NominalOCP(model, config)
        aware_ocp(model, ocp, samples=SURROGATE)  # the surrogate's size, as any Monte-Carlo
    finally:
        solvers_module.build = built
    return {"nominal": posed[0], "aware": posed[-1]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", required=True, help="A PPANN checkpoint (crank run's model.pt).")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    model = load(args.model)[0]
    config = OCPConfig()
    for name, (nlp, options) in _posed(model, config).items():
        seconds: dict[bool, list[float]] = {True: [], False: []}
        for _ in range(args.repeat):
            for without in (True, False):  # in turn, so that the host's pace falls on both
                started = time.perf_counter()
                solvers_module.build(nlp, {**options, "no_nlp_grad": without}, compiled=False)
                seconds[without].append(time.perf_counter() - started)
        today, before = (statistics.median(seconds[k]) for k in (True, False))
        print(
            f"{name} NLP: build {today:.2f} s without nlp_grad (the OCPs'), {before:.2f} s with "
            f"it: {today / before:.2f}x (median of {args.repeat}, in turn)"
        )
    ocp = NominalOCP(model, config)
    without = ocp.solve()
    built = solvers_module.build
    solvers_module.build = lambda n, o, *, compiled: built(
        n, {**o, "no_nlp_grad": False}, compiled=compiled
    )
    try:
        with_gradient = NominalOCP(model, config).solve()
    finally:
        solvers_module.build = built
    same = np.array_equal(without.tau, with_gradient.tau) and without.cost == with_gradient.cost
    print(f"nominal solve on either: the same torque to the last bit: {'yes' if same else 'NO'}")


if __name__ == "__main__":
    main()
