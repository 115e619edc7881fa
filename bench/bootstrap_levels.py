"""Would a parametric bootstrap of the line's two levels make its bounds hold for a few machines
of unequal runs? (bench/bound_coverage.md: there the exact levels missed 2x.) An experiment for
the product's next step, not the product's.

    python bench/bootstrap_levels.py --model logs/<run>/model.pt [--machines 8] \
        [--lines 1000] [--inner 400]

Outer lines are drawn and fitted as in bench/bound_coverage.py (phase 2's own Adam). For each, the
bootstrap draws `--inner` lines at its own fit (its spread and offset, the same machines'
information), fits them the same way and reads two levels off them: the profile rise of each spread
component at the outer fit's value (the likelihood-ratio statistic at the bootstrap's truth;
"boot|exact": the larger of it and the exact level), and the pooled average's error in its own
standard errors (per component, and their largest: the ellipsoid's one radius); each at 1 - 1/60
(one of three Bonferroni bounds at confidence 0.95; the mean's two sides as one |error| at 1 -
2/60). The outer line then misses its spread bound where its own rise at the true spread exceeds the
level (the bound read off the profile at that level lies below the truth), its mean bound where its
pooled average's error exceeds the radius. Prints per component the misses with the bootstrap levels
beside the exact ones (ppann/confidence.py), against 1.67 %.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
import torch
from bound_coverage import (
    MISS,
    PICK_SEED,
    adam_fit,
    kept_machines,
    pooled,
    setup,
    simulate,
)

from ppann.confidence import DEFAULT_CONFIDENCE, mean_quantile, spread_level
from ppann.inversion import one_sided_rises
from ppann.machine import pooled_from_information
from ppann.model import Z_NAMES


def drawn_at(info: torch.Tensor, sigma: torch.Tensor, common: torch.Tensor, inner: int, rng):
    """b (n * inner, E, 3): `inner` lines at each of n fits (sigma, common (n, 3))."""
    n, e = sigma.shape[0], info.shape[0]
    s = np.repeat(sigma.numpy(), inner, axis=0)[:, None, :]
    c = np.repeat(common.numpy(), inner, axis=0)[:, None, :]
    eta = c + s * rng.standard_normal((n * inner, e, 3))
    chol = np.linalg.cholesky(info.numpy())
    noise = np.einsum("eij,lej->lei", chol, rng.standard_normal((n * inner, e, 3)))
    return torch.from_numpy(-np.einsum("eij,lej->lei", info.numpy(), eta) + noise)


def pooled_se(info: torch.Tensor, log_s: torch.Tensor) -> torch.Tensor:
    """The pooled average's standard errors (L, 3) at spreads exp(log_s) (ppann/machine.py)."""
    covariance = pooled_from_information(info, log_s.exp())
    return torch.sqrt(torch.diagonal(covariance, dim1=-2, dim2=-1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=Path, required=True)
    parser.add_argument("--machines", type=int, default=0)
    parser.add_argument("--lines", type=int, default=1000)
    parser.add_argument("--inner", type=int, default=400)
    parser.add_argument("--chunk", type=int, default=10)
    parser.add_argument("--seed", type=int, default=20261206)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    torch.set_num_threads(1)
    rng = np.random.default_rng(args.seed)
    full = setup(args.model)
    kept = kept_machines(full, args.machines, np.random.default_rng(PICK_SEED))
    m, info = kept.info.shape[0], kept.info
    exact_level = spread_level(DEFAULT_CONFIDENCE, m)
    exact_radius = mean_quantile(DEFAULT_CONFIDENCE, m)
    keys = (
        "spread exact",
        "spread boot",
        "spread boot|exact",
        "mean exact",
        "mean boot",
        "mean boot (max)",
    )
    miss = {k: np.zeros(3) for k in keys}
    levels, radii = [], []
    started, done = time.perf_counter(), 0
    while done < args.lines:
        n = min(args.chunk, args.lines - done)
        b = simulate(kept, n, rng)
        log_s, c = adam_fit(kept, b)
        # the bootstrap at each outer fit
        inner_b = drawn_at(info, log_s.exp(), c, args.inner, rng)
        inner_s, inner_c = adam_fit(kept, inner_b)
        truth_s = log_s.exp().repeat_interleave(args.inner, 0)
        rise = one_sided_rises(info, inner_b, inner_s, inner_c, truth_s).reshape(n, args.inner, 3)
        err = (pooled(kept, inner_b) - c.repeat_interleave(args.inner, 0)) / pooled_se(
            info, inner_s
        )
        err = err.abs().reshape(n, args.inner, 3)
        level = torch.quantile(rise, 1 - MISS, dim=1)  # (n, 3)
        radius = torch.quantile(err, 1 - 2 * MISS, dim=1)  # (n, 3)
        levels.append(level)
        radii.append(radius)
        # the outer lines judged
        outer = one_sided_rises(info, b, log_s, c, kept.sigma.expand(n, 3))
        miss["spread exact"] += (outer > exact_level).sum(0).numpy()
        miss["spread boot"] += (outer > level).sum(0).numpy()
        miss["spread boot|exact"] += (outer > level.clamp_min(exact_level)).sum(0).numpy()
        error = ((pooled(kept, b) - kept.common) / pooled_se(info, log_s)).abs()
        miss["mean exact"] += (error > exact_radius).sum(0).numpy()
        miss["mean boot"] += (error > radius).sum(0).numpy()
        miss["mean boot (max)"] += (error > radius.max(-1, keepdim=True).values).sum(0).numpy()
        done += n
        rate = (time.perf_counter() - started) / done
        print(f"{done}/{args.lines} lines, {rate * (args.lines - done):.0f} s left", flush=True)
    level, radius = torch.cat(levels), torch.cat(radii)
    se = math.sqrt(MISS * (1 - MISS) / args.lines)
    print(
        f"\n{m} machines; exact level {exact_level:.2f}, radius {exact_radius:.2f}; bootstrap "
        "level median "
        + ", ".join(f"{v:.2f}" for v in level.median(0).values.tolist())
        + "; radius median "
        + ", ".join(f"{v:.2f}" for v in radius.median(0).values.tolist())
    )
    print(
        f"misses (stand for {100 * MISS:.2f} %, binomial se {100 * se:.2f} %; the mean's sides"
        " together, per side: half)"
    )
    print(f"{'bound':18}" + "".join(f"{n:>10}" for n in Z_NAMES))
    rates = {}
    for key, count in miss.items():
        per = 2 * args.lines if key.startswith("mean") else args.lines
        rates[key] = (count / per).tolist()
        print(f"{key:18}" + "".join(f"{100 * v:8.2f} %" for v in count / per))
    if args.out:
        args.out.write_text(
            json.dumps(
                {
                    "model": str(args.model),
                    "machines": m,
                    "lines": args.lines,
                    "inner": args.inner,
                    "seed": args.seed,
                    "rates": rates,
                    "level_median": level.median(0).values.tolist(),
                    "radius_median": radius.median(0).values.tolist(),
                },
                indent=1,
            )
        )


if __name__ == "__main__":
    main()
