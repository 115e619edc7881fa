"""Development measurement (session 47, bench/draft_check.md): antithetic lines. On three
default torques (the session-45 models of training seeds 1, 0 and 4 at Monte-Carlo seeds 3, 2
and 1; the model paths are this machine's), each line's probability for a draw u and for -u,
against 4000 independent lines: the standard error of 2000 antithetic pair means against that
of 4000 lines.

    PYTHONPATH=. python bench/antithetic_lines.py
"""

from __future__ import annotations

import numpy as np

from control import profiles
from control import tail_lines as lines
from control.config import OCPConfig
from control.ocp import NominalOCP
from control.tightening import line_allowance
from ppann.checkpoint import load
from ppann.heads import FusedHeads

MODELS = (("ed08465aeaa3", 3), ("fcc9b1e17707", 2), ("d761a73494ec", 1))


def main() -> None:
    for key, seed in MODELS:
        model, _ = load(f"/work/e45/s10/model/{key}/model.pt")
        config = OCPConfig(mc_seed=seed)
        ocp = NominalOCP(model, config)
        heads = FusedHeads(model)
        result = profiles.solve_decided(
            model, config, profile="robust", ocp=ocp, nominal=ocp.solve(), heads=heads
        )
        spread, _ = line_allowance(heads, OCPConfig(mc_seed=seed, k_sigma=result.k_sigma))
        index = np.array(config.constraint_samples) - 1
        simulator = lines.Simulator(
            heads,
            np.asarray(result.robust.states[0]),
            np.asarray(result.robust.tau),
            lines.layout(heads, config.mc_mode, int(index.max())),
            spread,
            index,
            None,
        )
        found = lines.direction(simulator)
        reach = heads.geometry.crank_reach(config.height + result.robust_uncertainty.population)
        u = np.random.default_rng(7).standard_normal((2000, simulator.layout.size))
        other = np.random.default_rng(8).standard_normal((2000, simulator.layout.size))
        plus = lines.crossings(simulator, found, u, reach).probabilities()
        minus = lines.crossings(simulator, found, -u, reach).probabilities()
        apart = np.concatenate(
            [plus, lines.crossings(simulator, found, other, reach).probabilities()]
        )
        pairs = 0.5 * (plus + minus)
        print(
            f"{key} Monte-Carlo seed {seed}, k {result.k_sigma:g}: 4000 independent lines "
            f"{100 * apart.mean():.4f} ± {100 * apart.std(ddof=1) / np.sqrt(4000):.4f} %; "
            f"2000 antithetic pairs {100 * pairs.mean():.4f} ± "
            f"{100 * pairs.std(ddof=1) / np.sqrt(2000):.4f} %; "
            f"correlation {np.corrcoef(plus, minus)[0, 1]:.3f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
