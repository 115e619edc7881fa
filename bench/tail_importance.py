"""Development probe (issue 11, session 45; no machines drawn): would importance sampling of the
machine draws cut the own-tail check's cost? The check (control/tail.py) estimates a torque's
own rate near 0.5 % from plain Monte-Carlo draws, 80 000 of them where the rate sits within two
standard errors of the target, which is what keeps bench_solve's ratio above 3.

For one torque (a default model's k-3 robust torque at a Monte-Carlo seed) this draws the
check's trajectories (the line's allowance for the machine spread, counter normals, the
transmission, the population drop), then:
1. which side of top dead centre, and which machine normals, the draws below each constraint
   sample come from;
2. a one-shift importance sampling of the machine normals (cross-entropy: the mean normal of the
   draws below), and a defensive mixture of the nominal and one shift per constraint sample;
   each on 20 000 draws, four repeats: estimate, standard error, and the variance reduction
   against plain draws at the same count.

    python bench/tail_importance.py --model <model.pt> [--mc-seed 1]
"""

from __future__ import annotations

import argparse

import numpy as np

from control.config import OCPConfig
from control.ocp import NominalOCP
from control.profiles import decide
from control.tail import lowered_sliders
from control.tightening import line_allowance
from ppann.checkpoint import load
from ppann.counter import key_of
from ppann.heads import FusedHeads
from ppann.montecarlo import rollout
from ppann.transmission import draw

DRAWS, REPEATS = 20_000, 4


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", required=True)
    parser.add_argument("--mc-seed", type=int, default=1)
    args = parser.parse_args()
    model, _ = load(args.model)
    config = OCPConfig(mc_seed=args.mc_seed)
    ocp, heads = NominalOCP(model, config), FusedHeads(model)
    result = decide(model, config, profile="robust", ocp=ocp, nominal=ocp.solve(), heads=heads)
    spread, _ = line_allowance(heads, config)
    population = result.robust_uncertainty.population
    index = np.array(config.constraint_samples) - 1
    kept = np.unique(index)
    tau = np.asarray(result.robust.tau)[: index.max()]
    rng = np.random.default_rng(20261129)
    keys = np.random.SeedSequence(20261129)

    def below(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each draw's crank angle at the constraint samples and whether it went below."""
        states = rollout(
            heads,
            result.robust.states[0],
            tau,
            n_samples=len(z),
            factors=np.exp(spread * z),
            key=key_of(keys.spawn(1)[0]),
            at=kept,
        )
        delta = draw(heads.transmission, (len(z),), rng)
        angle = states[:, np.searchsorted(kept, index), 0] + delta[:, None]
        return angle, ~(lowered_sliders(heads.geometry, angle, population) >= config.height)

    n = 4 * DRAWS
    z = rng.standard_normal((n, 3))
    angle, down = below(z)
    rate = down.any(axis=1).mean()
    print(f"k {result.k_sigma:g}, plain {n} draws: {100 * rate:.3f} % below")
    phase = np.remainder(angle + np.pi, 2 * np.pi) - np.pi  # top dead centre at 0
    for j, sample in enumerate(config.constraint_samples):
        d = down[:, j]
        normals = ", ".join(f"{name} {z[d, i].mean():+.2f}" for i, name in enumerate("JBK"))
        print(
            f"sample {sample}: {d.sum()} below, {np.mean(phase[d, j] < 0):.2f} of them before top "
            f"dead centre; their mean machine normals {normals}"
        )
    plain_se = np.sqrt(rate * (1 - rate) / DRAWS)
    shifts = [z[down[:, j]].mean(axis=0) for j in range(down.shape[1])]
    one = z[down.any(axis=1)].mean(axis=0)
    schemes = {
        f"one shift {np.round(one, 2).tolist()}": [(1.0, one)],
        "mixture: 0.2 nominal, 0.4 per sample's shift": [(0.2, np.zeros(3))]
        + [(0.4, s) for s in shifts],
    }
    for name, parts in schemes.items():
        estimates = []
        for _ in range(REPEATS):
            weights = np.array([w for w, _ in parts])
            centres = np.array([c for _, c in parts])
            zz = rng.standard_normal((DRAWS, 3)) + centres[rng.choice(len(parts), DRAWS, p=weights)]
            density = sum(w * np.exp(-0.5 * ((zz - c) ** 2).sum(axis=1)) for w, c in parts)
            y = np.exp(-0.5 * (zz**2).sum(axis=1)) / density * below(zz)[1].any(axis=1)
            estimates.append((y.mean(), y.std() / np.sqrt(DRAWS)))
        est = np.array(estimates)
        values = ", ".join(f"{100 * e:.3f}" for e in est[:, 0])
        print(
            f"{name}: {DRAWS} draws x {REPEATS}: {values} %,"
            f" se {100 * est[:, 1].mean():.4f} points (plain {100 * plain_se:.4f}); variance "
            f"reduction {plain_se**2 / np.mean(est[:, 1] ** 2):.1f}x"
        )


if __name__ == "__main__":
    main()
