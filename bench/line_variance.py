"""Experiment (session 53, development): where the variance of the own-tail check's lines comes
from, and whether a control variate or a stratification could take it out.

control/tail_lines.py reads a torque's own rate below the height as the mean of each line's
probability p_i (a draw u_i moved along the direction the crank runs ahead or behind). Its
standard error is the pairs' spread over sqrt(pairs); halving it would let the check's first
stage (500 lines) decide where today a second (2000) is drawn: the last pair above 3 in
bench/bench_solve.py is such a check. This script decides the torque as `crank solve` does
(`solve_decided`), draws 2000 mirrored lines on it and measures, per line:

1. a linear control variate: the crank angle at each constraint sample linearised in all of u
   (the central differences `direction` takes, the gradient kept whole), each line's
   probability under that linear model in closed form, its mean over 10^6 lines; the variance
   of the pairs' means with the variate against without (the factor the lines would shrink by);
2. how much of p_i a quadratic in the machine's three normals and the transmission's explains
   (R^2; a stratification over them could remove at most that share);
3. the same for the m gradient components orthogonal to the direction, and their share of the
   gradients' squared norm held by the 4, 10 and 40 largest normals.

    python bench/line_variance.py --model M [--mc-seed 1] [--lines 2000]
"""

from __future__ import annotations

import argparse

import numpy as np

import control.tail_lines as tl
from control.config import OCPConfig
from control.ocp import NominalOCP
from control.profiles import solve_decided
from control.tightening import line_allowance
from ppann.checkpoint import load
from ppann.heads import FusedHeads


def r_squared(features: np.ndarray, y: np.ndarray) -> float:
    """Share of y's variance a least-squares fit on `features` (and a constant) explains."""
    x = np.column_stack([np.ones(len(y)), features])
    beta, *_ = np.linalg.lstsq(x, y, rcond=None)
    return float(1 - (y - x @ beta).var() / y.var())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", required=True)
    parser.add_argument("--mc-seed", type=int, default=1)
    parser.add_argument("--lines", type=int, default=2000)
    args = parser.parse_args()

    model = load(args.model)[0]
    config = OCPConfig(mc_seed=args.mc_seed)
    ocp = NominalOCP(model, config)
    heads = FusedHeads(model)
    result = solve_decided(
        model, config, profile="robust", ocp=ocp, nominal=ocp.solve(), heads=heads
    )
    solved = OCPConfig(mc_seed=args.mc_seed, k_sigma=result.k_sigma)
    spread, _ = line_allowance(heads, solved)
    population = np.asarray(result.robust_uncertainty.population)
    index = np.array(solved.constraint_samples) - 1
    solution = result.robust
    simulator = tl.Simulator(
        heads,
        np.asarray(solution.states[0], dtype=float),
        np.asarray(solution.tau, dtype=float),
        tl.layout(heads, solved.mc_mode, int(index.max())),
        np.asarray(spread),
        index,
        None,
    )
    size = simulator.layout.size
    step = tl.DIFFERENCE_STEP
    u0 = np.concatenate([np.zeros((1, size)), step * np.eye(size), -step * np.eye(size)])
    angle = simulator.angles(u0)
    gradient = ((angle[1 : size + 1] - angle[size + 1 :]) / (2 * step)).T  # (m, size)
    found = tl.direction(simulator)
    reach = heads.geometry.crank_reach(solved.height + population)
    rng = np.random.default_rng(20261202)
    u = tl.mirrored(rng, args.lines, size)
    crossings = tl.crossings(simulator, found, u, reach)
    p = crossings.probabilities()
    unit = found.direction
    along = u @ unit
    base = u - np.outer(along, unit)

    def linear(draws: np.ndarray) -> np.ndarray:
        """Each line's probability below the height with the angle linear in u."""
        offset = found.origin - found.centre + (draws - np.outer(draws @ unit, unit)) @ gradient.T
        slope = np.broadcast_to(gradient @ unit, offset.shape)
        lower, upper = (-reach - offset) / slope, (reach - offset) / slope
        # the lines' own union of the edges (control/tail_lines.py), on the linear edges
        return tl.Crossings(lower, upper, slope, slope, offset, 0, 0).probabilities()

    q = linear(u)
    expected = np.mean([linear(tl.mirrored(rng, 200_000, size)).mean() for _ in range(5)])
    pairs_p, pairs_q = p.reshape(-1, 2).mean(axis=1), q.reshape(-1, 2).mean(axis=1)
    cov = np.cov(pairs_p, pairs_q)
    beta = cov[0, 1] / cov[1, 1]
    varied = pairs_p - beta * (pairs_q - expected)
    se = pairs_p.std(ddof=1) / np.sqrt(len(pairs_p))
    plain = crossings.plain - found.centre
    print(f"model {args.model}, Monte-Carlo seed {args.mc_seed}, k {result.k_sigma:g}")
    print(f"lines: rate {100 * p.mean():.3f} %, standard error {100 * se:.4f} points")
    for j, k in enumerate(solved.constraint_samples):
        rest = plain[:, j] - (found.origin[j] - found.centre[j] + u @ gradient[j])
        print(
            f"  sample {k}: angle R^2 of the linear model {1 - rest.var() / plain[:, j].var():.3f}"
            f" (spread {plain[:, j].std():.3f} rad, linear {np.std(u @ gradient[j]):.3f})"
        )
    correlation = np.corrcoef(pairs_p, pairs_q)[0, 1]
    print(
        f"1. linear control variate: the linear model's rate {100 * expected:.3f} % "
        f"(lines {100 * p.mean():.3f} %); correlation of the pairs {correlation:.2f}, "
        f"variance / variance with it {pairs_p.var() / varied.var():.2f}"
    )
    low = base[:, [0, 1, 2, size - 1]]
    quadratic = np.column_stack(
        [low, low**2] + [low[:, [a]] * low[:, [b]] for a in range(4) for b in range(a + 1, 4)]
    )
    print(
        "2. R^2 of p on a quadratic in the machine's and the transmission's normals: "
        f"{r_squared(quadratic, p):.3f}"
    )
    orthogonal = gradient - np.outer(gradient @ unit, unit)
    parts = base @ orthogonal.T
    both = np.column_stack([parts, parts**2, parts[:, :1] * parts[:, 1:]])
    weight = np.sort((orthogonal**2).sum(axis=0))[::-1]
    shares = [weight[:n].sum() / weight.sum() for n in (4, 10, 40)]
    print(
        f"3. R^2 of p on a quadratic in the {len(index)} orthogonal gradient components: "
        f"{r_squared(both, p):.3f}; share of their squared norm in the largest 4, 10, 40 "
        f"normals: {shares[0]:.2f}, {shares[1]:.2f}, {shares[2]:.2f}"
    )


if __name__ == "__main__":
    main()
