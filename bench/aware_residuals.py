"""Development measurement (session 48, bench/antithetic_lines.md): the aware loop's residual
(tightening - margin, mm, at each constraint sample) after every solve, with the k it was at and
its IPOPT iterations, for the robust profile as `crank solve` decides it, on the five default
models of training seeds 0-4 (the session-45 ones; the paths are this machine's) at Monte-Carlo
seeds 0-4. One line per pair: d = draft, F = full solve, k(residual at 50, at 100)iterations.

    PYTHONPATH=. python bench/aware_residuals.py > bench/antithetic_lines_loops.log
    PYTHONPATH=. python bench/aware_residuals.py --mc-seeds 5-9   # other seeds (development)
"""

from __future__ import annotations

import argparse

import numpy as np

from common.errors import ConfigError
from control import profiles
from control.config import OCPConfig
from control.ocp import NominalOCP, Solution
from control.robust import RobustResult
from crank.study import parse_seeds
from ppann.checkpoint import load
from ppann.heads import FusedHeads
from ppann.model import PPANN

MODELS = ("fcc9b1e17707", "ed08465aeaa3", "5800e00574e0", "a1129f30b6a7", "d761a73494ec")
"""The five default models' keys (session 45's, training seeds 0-4; bench/loop_levers_ab.py's
too)."""


def load_default(key: str) -> PPANN:
    """One of MODELS from this machine's session-45 sweep folder."""
    return load(f"/work/e45/s10/model/{key}/model.pt")[0]


def decided(
    model: PPANN, ocp: NominalOCP, *, nominal: Solution, heads: FusedHeads, seed: int
) -> RobustResult:
    """The robust profile as `crank solve` decides it at Monte-Carlo seed `seed`."""
    return profiles.solve_decided(
        model, OCPConfig(mc_seed=seed), profile="robust", ocp=ocp, nominal=nominal, heads=heads
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mc-seeds", default="0-4", help="Monte-Carlo seeds, e.g. 0-4 or 0,3")
    try:
        seeds = parse_seeds(parser.parse_args().mc_seeds, option="--mc-seeds")
    except ConfigError as exc:
        parser.error(str(exc))
    for key in MODELS:
        model = load_default(key)
        ocp = NominalOCP(model, OCPConfig())
        heads, nominal = FusedHeads(model), ocp.solve()
        for seed in seeds:
            result = decided(model, ocp, nominal=nominal, heads=heads, seed=seed)
            steps = []
            for it in result.iterations:
                res = 1e3 * (np.asarray(it.tightening) - np.asarray(it.margin))
                kind = "d" if it.draft else "F"
                steps.append(
                    f"{kind}{it.k_sigma:g}({res[0]:+.2f},{res[1]:+.2f}){it.ipopt_iterations}"
                )
            print(key[:3], seed, " ".join(steps), flush=True)


if __name__ == "__main__":
    main()
