"""Do the line's bounds miss as often as they say through phase 2's own estimator, with the
machines seen through the white noise of their runs? (ppann/confidence.py: exact for M machines
observed directly; tests/test_small_sample.py checks that case. This measures the real one.)

    python bench/bound_coverage.py --model logs/<run>/model.pt [--machines 8] [--lines 4000]

From a trained model and the data it was trained on, phase 2's per-machine information
M_e = sum_k D_k D_k^T / V_k (ppann/machine.py: the design and white variance of each block of the
machine's runs) is rebuilt exactly as training built it. Then LINES lines are simulated under
phase 2's own model with a known truth (the model's fitted machine sigma and common offset):
each machine's log-factors eta_e = c + sigma * N(0, I), its residual statistic
b_e = -M_e eta_e + N(0, M_e) (the white noise of its runs seen through the design). Each line is
fitted twice -- with phase 2's own Adam (its epochs, rate and start) and to the maximum of the
likelihood (L-BFGS after it) -- and its bounds taken as the robust OCP takes them: the line
mean's at `mean_quantile` standard errors of `population`'s covariance, each machine sigma's at
the profile rise `spread_level` (`sigma_upper` on PROFILE_GRID). The line mean's bound is read
about the pooled average of the machines (each weighted by its information: what phase 1's
mean model, fitted on every sample alike, stands for) and about the likelihood's own estimate,
at standard errors of the pooled average's covariance (the bound since session 80) and of the
inverse Hessian (before). Prints, per component J, B, K, how often each bound missed the truth
against the 1/60 it stands for at confidence 0.95 (one of three Bonferroni bounds), with the
binomial standard error, and the same at the normal z (the bounds before session 79).
`--machines K` keeps K of the machines (drawn once): a smaller line of the same runs.

The fast path (per-machine sufficient statistics, every line at once) is checked against
ppann/machine.py's own `marginal_nll` and `population` on an equivalent dataset of three blocks
per machine for the first lines (printed; the script stops if they differ by more than 1e-8).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ppann import checkpoint, inversion
from ppann.confidence import DEFAULT_CONFIDENCE, confidence_quantile, mean_quantile, spread_level
from ppann.inversion import line_nll
from ppann.machine import (
    EpisodeTerms,
    machine_sums,
    marginal_nll,
    pooled_from_information,
    population,
    sigma_upper,
)
from ppann.model import PROFILE_GRID, Z_NAMES
from ppann.train import MACHINE_SIGMA_START, make_splits, spread_samples
from ppann.train_config import TrainConfig
from twin.mcap_dataset import read_dataset


@dataclass(frozen=True)
class Setup:
    info: torch.Tensor
    """(E, 3, 3) each machine's M_e."""
    sigma: torch.Tensor
    """(3,) the model's machine sigma: the simulated lines' truth."""
    common: torch.Tensor
    """(3,) the model's common offset: the simulated lines' mean."""
    config: TrainConfig


def setup(model_path: Path) -> Setup:
    """M_e of every training machine as phase 2 saw them, and the model's fitted line."""
    model, payload = checkpoint.load(model_path)
    config = TrainConfig(**payload["train_config"])
    dataset = read_dataset(model_path.parent / payload["data_path"])
    data = spread_samples(model, dataset, make_splits(dataset, config).split, config)
    terms = data.terms  # phase 2's own blocks (ppann/train.py)
    with torch.no_grad():
        force = model.lever_sigma if model.config.sigma_lever else None
        variance = terms.white_variance(model.z_sigma(data.theta, data.omega), force)
        info, _ = machine_sums(
            terms.residual, terms.design, variance, terms.machine, terms.n_machines
        )
    common = torch.tensor(payload["history"]["machine_common"], dtype=torch.float64)
    return Setup(info, model.machine_sigma.detach().clone(), common, config)


PICK_SEED = 20261205
"""The simulation's default seed; its first draw picks `--machines` (`kept_machines`)."""


def kept_machines(full: Setup, machines: int, rng: np.random.Generator) -> Setup:
    """`machines` of the setup's machines, drawn once from `rng` (0: all of them); the other
    bench scripts pass np.random.default_rng(PICK_SEED) to keep this script's default draw."""
    if not machines:
        return full
    pick = np.sort(rng.choice(full.info.shape[0], machines, replace=False))
    return Setup(full.info[pick], full.sigma, full.common, full.config)


def simulate(setup: Setup, lines: int, rng: np.random.Generator) -> torch.Tensor:
    """b (L, E, 3) of `lines` lines drawn under phase 2's model with the setup's truth."""
    truth = setup.sigma[None].expand(lines, 3)
    return inversion.simulate(setup.info, truth, setup.common[None].expand(lines, 3), rng)


def adam_fit(setup: Setup, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Phase 2's own fit of the machine parameters (ppann/inversion.py adam_fit), every line
    at once."""
    config = setup.config
    return inversion.adam_fit(
        setup.info, b, epochs=config.sigma_epochs, lr=config.machine_lr, start=MACHINE_SIGMA_START
    )


def ml_fit(
    setup: Setup, b: torch.Tensor, start: tuple[torch.Tensor, torch.Tensor]
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The likelihood's maximum, by Newton steps on each line's six parameters from `start`
    (halved until the NLL falls); each line's largest gradient left is returned with it."""
    log_s, c = (x.clone() for x in start)
    floor = math.log(PROFILE_GRID[0]) - 4  # a spread below the grid reads as the grid's start

    def per_line(p: torch.Tensor, bl: torch.Tensor) -> torch.Tensor:
        return line_nll(setup.info, bl[None], p[None, :3], p[None, 3:])[0]

    params = torch.cat([log_s, c], -1)
    grad_fn = torch.func.vmap(torch.func.grad(per_line))
    hess_fn = torch.func.vmap(torch.func.hessian(per_line))
    for _ in range(60):
        grad, hess = grad_fn(params, b), hess_fn(params, b)
        # a direction that descends: Newton where the Hessian is positive, else steepest
        eig = torch.linalg.eigvalsh(hess)
        ok = eig[:, 0] > 1e-10
        step = torch.where(
            ok[:, None],
            -torch.linalg.solve(hess + (~ok)[:, None, None] * torch.eye(6), grad[..., None])[
                ..., 0
            ],
            -grad / grad.norm(dim=-1, keepdim=True).clamp_min(1e-300) * 0.1,
        )
        before = line_nll(setup.info, b, params[:, :3], params[:, 3:])
        scale = torch.ones(len(params), dtype=torch.float64)
        for _ in range(30):
            trial = params + scale[:, None] * step
            trial[:, :3] = trial[:, :3].clamp_min(floor)
            worse = line_nll(setup.info, b, trial[:, :3], trial[:, 3:]) > before + 1e-12
            if not worse.any():
                break
            scale = torch.where(worse, scale / 2, scale)
        params = torch.where(worse[:, None], params, trial)
        if float(grad.abs().max()) < 1e-9:
            break
    grad = grad_fn(params, b)
    free = params[:, :3] > floor + 1e-6  # a spread at the floor is at its boundary
    left = torch.cat([grad[:, :3] * free, grad[:, 3:]], -1).abs().amax(-1)
    return params[:, :3], params[:, 3:], left


def bounds(
    setup: Setup, b: torch.Tensor, log_s: torch.Tensor, c: torch.Tensor, machines: int
) -> dict[str, np.ndarray]:
    """The robust OCP's bounds at each line's fit: the mean's standard errors (L, 3), the pooled
    average's (ppann/machine.py population, since session 80) and the likelihood's (the inverse
    Hessian in the offset: before), each spread's upper bound (L, 3) at the exact and at the
    asymptotic level."""
    s = log_s.exp()
    info = setup.info
    g = s[:, None, :, None] * info * s[:, None, None, :]
    inner = torch.linalg.solve(torch.eye(3, dtype=info.dtype) + g, s[:, None, :, None] * info)
    hessian = (info - info @ (s[:, None, :, None] * inner)).sum(1)
    sandwich = pooled_from_information(info, s)
    se = {
        name: torch.sqrt(torch.diagonal(cov, dim1=-2, dim2=-1)).numpy()
        for name, cov in (("likelihood", torch.linalg.inv(hessian)), ("pooled", sandwich))
    }
    profile = inversion.profile_rises(info, b, log_s, c).numpy()
    levels = {
        "exact": spread_level(DEFAULT_CONFIDENCE, machines),
        "normal": 0.5 * confidence_quantile(DEFAULT_CONFIDENCE) ** 2,
    }
    upper = {
        k: np.stack([sigma_upper(s[j].numpy(), profile[j], lv) for j in range(len(b))])
        for k, lv in levels.items()
    }
    counts = effective_counts(setup, s)
    upper["effective"] = np.stack(
        [
            [
                sigma_upper(s[j, i : i + 1].numpy(), profile[j, i : i + 1], lv)[0]
                for i, lv in enumerate(_spread_levels(counts["spread"][j]))
            ]
            for j in range(len(b))
        ]
    )
    return {"se": se, "profile": profile, "counts": counts, **upper}


def effective_counts(setup: Setup, s: torch.Tensor) -> dict[str, np.ndarray]:
    """Satterthwaite's effective machine counts at each line's fitted spread s (L, 3), per
    component, equal to M for M directly observed machines of equal runs (an experiment, not
    the product's): "mean", the degrees of freedom of the pooled average's estimated variance
    V = sum_j A_ij s_j^2 + B_i, V^2 / sum_j A_ij^2 Var(s_j^2) / 2 with Var(s_j^2) =
    2 / sum_e u_ej^2, u_ej = 1 / (s_j^2 + tau_ej^2), tau_ej^2 = (M_e^-1)_jj; "spread", the
    machines' worth of information on s_j^2, s_j^4 sum_e u_ej^2."""
    info = setup.info
    tau2 = torch.diagonal(torch.linalg.inv(info), dim1=-2, dim2=-1)  # (E, 3)
    rows = torch.linalg.inv(info.sum(0)) @ info  # (E, 3, 3): machine e's weight matrix
    a = (rows**2).sum(0)  # (3, 3)
    noise = torch.diagonal((rows @ torch.linalg.inv(info) @ rows.transpose(1, 2)).sum(0))
    u2 = (1.0 / (s[:, None, :] ** 2 + tau2[None]) ** 2).sum(1)  # (L, 3)
    v = (a[None] * s[:, None, :] ** 2).sum(-1) + noise  # (L, 3)
    mean = v**2 / (a[None] ** 2 / u2[:, None, :]).sum(-1)
    return {"mean": mean.numpy(), "spread": (s**4 * u2).numpy()}


def _spread_levels(counts: np.ndarray) -> list[float]:
    """spread_level at each effective count (above 1; a count at or below 1 bounds nothing:
    infinite)."""
    from scipy.stats import chi2

    miss = (1 - DEFAULT_CONFIDENCE) / 3
    levels = []
    for m in counts:
        u = chi2.ppf(miss, m - 1) / m if m > 1 else 0.0
        levels.append(0.5 * m * (u - 1 - math.log(u)) if u > 0 else math.inf)
    return levels


def _mean_quantiles(counts: np.ndarray) -> np.ndarray:
    """mean_quantile at effective counts (above 1; infinite at or below)."""
    from scipy.stats import t

    level = 1 - (1 - DEFAULT_CONFIDENCE) / 3
    m = np.where(counts > 1, counts, 2.0)
    q = t.ppf(level, m - 1) * np.sqrt(m / (m - 1))
    return np.where(counts > 1, q, np.inf)


def reference_check(setup: Setup, b: torch.Tensor, log_s: torch.Tensor, c: torch.Tensor) -> float:
    """The largest relative difference between the fast path and ppann/machine.py's own
    `population` (covariance and profile) on three lines, each written as a dataset of three
    blocks per machine with the same M_e and b_e."""
    worst = 0.0
    e = setup.info.shape[0]
    chol = torch.linalg.cholesky(setup.info)
    fast = bounds(setup, b[:3], log_s[:3], c[:3], machines=0)
    for j in range(3):
        variance = 1.0 + 1e-12  # white_variance of a block: its one sample's 1, and the floor
        design = (chol.transpose(1, 2) * math.sqrt(variance)).reshape(3 * e, 3)
        residual = math.sqrt(variance) * torch.linalg.solve_triangular(
            chol, b[j][..., None], upper=False
        )[..., 0].reshape(3 * e)
        derivative = torch.zeros((3 * e, 3), dtype=torch.float64)
        derivative[:, 0] = 1.0
        terms = EpisodeTerms(
            residual=residual,
            design=design,
            derivative=derivative,
            block=torch.arange(3 * e),
            machine=torch.arange(e).repeat_interleave(3),
            n_machines=e,
        )
        sigma = torch.ones((3 * e, 3), dtype=torch.float64)
        line = population(terms, sigma, log_s[j].exp(), c[j])
        se = torch.sqrt(torch.diagonal(line.common_covariance)).numpy()
        worst = max(worst, float(np.max(np.abs(se / fast["se"]["pooled"][j] - 1))))
        scale = np.abs(line.profile.numpy()).max()
        worst = max(worst, float(np.max(np.abs(line.profile.numpy() - fast["profile"][j]))) / scale)
        moved = log_s[j].exp() * 1.3
        real = (
            3
            * e
            * (
                marginal_nll(terms.shifted(c[j] + 0.01), sigma, moved)
                - marginal_nll(terms.shifted(c[j]), sigma, log_s[j].exp())
            )
        )
        quick = line_nll(setup.info, b[j : j + 1], moved.log()[None], c[j : j + 1] + 0.01) - (
            line_nll(setup.info, b[j : j + 1], log_s[j : j + 1], c[j : j + 1])
        )
        worst = max(worst, abs(float(real) / float(quick[0]) - 1))
    return worst


UNCONVERGED = 1e-3
"""An ML fit is counted unconverged with a gradient above this (NLL per unit log-factor)."""
MISS = (1 - DEFAULT_CONFIDENCE) / 3
"""One bound's miss probability at the default confidence (three bounds, Bonferroni)."""


def misses(
    setup: Setup,
    b: torch.Tensor,
    log_s: torch.Tensor,
    c: torch.Tensor,
    m: int,
    estimates: dict[str, torch.Tensor],
) -> dict:
    """Per component, how many lines each bound missed at the fit (log_s, c): the spread's at
    the exact and the normal level; the line mean's (each side one bound) about each of
    `estimates` (L, 3), at mean_quantile standard errors of the pooled average's covariance (the
    bound since session 80) and of the likelihood's (before), and at z of the likelihood's
    (before session 79)."""
    found = bounds(setup, b, log_s, c, m)
    truth_s, truth_c = setup.sigma.numpy(), setup.common.numpy()
    counts = {}
    for name in ("exact", "normal", "effective"):
        counts[f"spread {name}"] = (found[name] < truth_s).sum(0)
    error = (estimates["pooled"].numpy() - truth_c) / found["se"]["pooled"]
    for name, q in (
        ("own", _mean_quantiles(found["counts"]["mean"])),
        ("least", _mean_quantiles(found["counts"]["mean"].min(-1, keepdims=True))),
    ):
        key = f"mean effective ({name}), pooled se, about pooled"
        counts[key] = (error > q).sum(0) + (error < -q).sum(0)
    counts["effective mean count"] = found["counts"]["mean"].sum(0)
    counts["effective spread count"] = found["counts"]["spread"].sum(0)
    exact = mean_quantile(DEFAULT_CONFIDENCE, m)
    for about, estimate in estimates.items():
        for se, name, q in (
            ("pooled", "exact", exact),
            ("likelihood", "exact", exact),
            ("likelihood", "normal", confidence_quantile(DEFAULT_CONFIDENCE)),
        ):
            error = (estimate.numpy() - truth_c) / found["se"][se]  # in standard errors
            key = f"mean {name}, {se} se, about {about}"
            counts[key] = (error > q).sum(0) + (error < -q).sum(0)  # two one-sided bounds
    counts["spread estimate / truth"] = (log_s.exp().numpy() / truth_s).sum(0)
    return counts


def pooled(setup: Setup, b: torch.Tensor) -> torch.Tensor:
    """The line's mean as phase 1's mean model reads it (ppann/inversion.py pooled_mean)."""
    return inversion.pooled_mean(setup.info, b)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=Path, required=True)
    parser.add_argument("--machines", type=int, default=0, help="keep this many (0: all)")
    parser.add_argument("--lines", type=int, default=4000)
    parser.add_argument("--chunk", type=int, default=50)
    parser.add_argument("--seed", type=int, default=PICK_SEED, help="the simulation's seed")
    parser.add_argument("--out", type=Path, default=None, help="JSON of the counts")
    args = parser.parse_args()
    torch.set_num_threads(1)
    rng = np.random.default_rng(args.seed)
    full = setup(args.model)
    kept = full
    kept = kept_machines(full, args.machines, rng)
    m = kept.info.shape[0]
    sd = torch.sqrt(torch.diagonal(torch.linalg.inv(kept.info), dim1=-2, dim2=-1))
    seen = (sd / kept.sigma).median(0).values.numpy()
    print(
        f"{args.model}: {m} of {full.info.shape[0]} machines; truth sigma "
        + ", ".join(f"{n} {v:.4f}" for n, v in zip(Z_NAMES, kept.sigma.numpy(), strict=True))
        + "; a machine's own offset seen to "
        + ", ".join(f"{v:.2f}" for v in seen)
        + " sigma (median; 0 = directly)"
    )
    info, var = kept.info, torch.diag(kept.sigma**2)
    spread_pooled = pooled_from_information(info, kept.sigma)
    spread_gls = torch.linalg.inv(torch.linalg.inv(torch.linalg.inv(info) + var).sum(0))
    wider = torch.sqrt(torch.diagonal(spread_pooled) / torch.diagonal(spread_gls)).numpy()
    print(
        "the pooled mean's standard error against the likelihood's: "
        + ", ".join(f"{v:.3f}" for v in wider)
    )
    print(
        f"mean quantile {mean_quantile(DEFAULT_CONFIDENCE, m):.3f} (z "
        f"{confidence_quantile(DEFAULT_CONFIDENCE):.3f}), spread level "
        f"{spread_level(DEFAULT_CONFIDENCE, m):.3f} (z^2/2 "
        f"{0.5 * confidence_quantile(DEFAULT_CONFIDENCE) ** 2:.3f})",
        flush=True,
    )
    totals: dict[str, dict[str, np.ndarray]] = {"phase 2": {}, "ML": {}}
    started, done, unconverged = time.perf_counter(), 0, 0
    while done < args.lines:
        n = min(args.chunk, args.lines - done)
        b = simulate(kept, n, rng)
        adam = adam_fit(kept, b)
        log_s, c, grad = ml_fit(kept, b, adam)
        unconverged += int((grad > UNCONVERGED).sum())
        if done == 0:
            worst = reference_check(kept, b, log_s, c)
            print(f"fast path against ppann/machine.py population: {worst:.1e}", flush=True)
            if worst > 1e-8:
                raise SystemExit("the fast path is not phase 2's likelihood")
        estimates = {"pooled": pooled(kept, b), "ML": c}
        for fit, (ls, cc) in (("phase 2", adam), ("ML", (log_s, c))):
            shown = estimates if fit == "phase 2" else {"pooled": estimates["pooled"]}
            for key, value in misses(kept, b, ls, cc, m, shown).items():
                totals[fit][key] = totals[fit].get(key, 0) + value
        done += n
        rate = (time.perf_counter() - started) / done
        print(f"{done}/{args.lines} lines, {rate * (args.lines - done):.0f} s left", flush=True)
    se = math.sqrt(MISS * (1 - MISS) / args.lines)
    print(
        f"\nmisses per bound (it stands for {100 * MISS:.2f} %, binomial se {100 * se:.2f} %;"
        f" the mean's two sides averaged); ML fits left with a gradient above"
        f" {UNCONVERGED:g}: {unconverged} of {args.lines}"
    )
    print(f"{'fit':8} {'bound':52}" + "".join(f"{n:>10}" for n in Z_NAMES))
    table = {}
    for fit, counts in totals.items():
        for key, value in counts.items():
            per = 2 * args.lines if key.startswith("mean") else args.lines
            rate = np.asarray(value, dtype=float) / per
            table[f"{fit}.{key}"] = rate.tolist()
            ratio = key.endswith("truth") or key.endswith("count")
            cells = (f"{v:9.3f} " if ratio else f"{100 * v:8.2f} %" for v in rate)
            print(f"{fit:8} {key:52}" + "".join(cells))
    if args.out:
        args.out.write_text(
            json.dumps(
                {
                    "model": str(args.model),
                    "machines": m,
                    "lines": args.lines,
                    "seed": args.seed,
                    "truth_sigma": kept.sigma.tolist(),
                    "seen": seen.tolist(),
                    "mean_quantile": mean_quantile(DEFAULT_CONFIDENCE, m),
                    "spread_level": spread_level(DEFAULT_CONFIDENCE, m),
                    "ml_unconverged": unconverged,
                    "rates": table,
                },
                indent=1,
            )
        )


if __name__ == "__main__":
    main()
