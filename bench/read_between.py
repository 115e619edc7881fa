"""Is the straight line between candidates what makes the calibrated spread bounds miss? The
lines of a bench/calibrated_coverage.py file whose spread bound missed, calibrated again, their
bound read four ways between the last candidate not rejected and the rejected one after it:
the product's straight line of the excess (`calibrated_upper`), the rejected candidate itself
(`interpolate=False`), and the observed rise read on the profile's own grid between the two
against the simulated quantile's straight line in log spread (`read_on_profile`: if the profile
is convex there, the excess's chord crosses zero early), and one step of a law simulated at the
straight line's bound itself (`simulated_between`: the simulated quantile's own straight line
replaced there).

    python bench/read_between.py --model logs/<run>/model.pt --machines 5 \\
        --rows bench/calibrated_coverage_m5.jsonl --seed 20261211

Each line is drawn and calibrated again as in the rows (`one_line`'s stream, 500 lines a
candidate; the straight line's bound is checked to come back to the bit). Session 83: ~12 s a
line on one core. Only the lines that missed are read: a rule that lowers a bound could add a
miss elsewhere, which this does not look for.
"""

from __future__ import annotations

import math
import sys

import numpy as np
import torch
from bound_coverage import PICK_SEED, kept_machines, setup
from calibrated_coverage import calibrated_line, read_rows, rows_parser

from ppann.confidence import DEFAULT_CONFIDENCE, bound_level
from ppann.inversion import (
    _at_tail,
    calibrated_upper,
    last_accepted,
    one_sided_rises,
    simulate,
)
from ppann.inversion import adam_fit as adam_line
from ppann.machine import sigma_upper
from ppann.model import PROFILE_GRID, RISE_GRID, TAIL_GRID, Z_NAMES
from ppann.train import MACHINE_SIGMA_START

BETWEEN = 2_000_000
"""The between-laws' streams: the seed's child at (this key, the line), beyond any line's index."""


def read_on_profile(
    profile: np.ndarray, candidates: np.ndarray, rise_tail: np.ndarray, tail: float
) -> np.ndarray:
    """`calibrated_upper`'s bound (3,), but between the last candidate not rejected and the
    rejected one after it the observed rise is read at PROFILE_GRID's points, against the
    simulated quantile interpolated linearly in log spread between the two candidates."""
    critical = _at_tail(rise_tail, tail)
    upper = np.empty(3)
    for i in range(3):
        excess, j = last_accepted(profile[i], candidates[i], critical[i])
        if j == len(excess) - 1:
            upper[i] = PROFILE_GRID[-1]
            continue
        x0, x1 = candidates[i, j], candidates[i, j + 1]
        grid = PROFILE_GRID
        x = np.concatenate([[x0], grid[(grid > x0) & (grid < x1)], [x1]])
        at = (np.log(x) - math.log(x0)) / (math.log(x1) - math.log(x0))
        level = (1 - at) * critical[i, j] + at * critical[i, j + 1]
        fine = np.interp(np.log(x), np.log(PROFILE_GRID), profile[i]) - level
        fine[0], fine[-1] = min(fine[0], 0.0), max(fine[-1], np.nextafter(0.0, 1.0))
        k = int(np.flatnonzero(fine[:-1] <= 0)[-1])
        upper[i] = x[k] + (x[k + 1] - x[k]) * (-fine[k]) / (fine[k + 1] - fine[k])
    return upper


def simulated_between(
    kept,
    fit: tuple[torch.Tensor, torch.Tensor],
    profile: np.ndarray,
    found,
    tail: float,
    *,
    rng: np.random.Generator,
    lines: int,
) -> np.ndarray:
    """The straight line's bound (3,), then, where it fell between two candidates, the law at
    that bound itself simulated (`lines` lines, that component there, the others at the line's
    estimate, as `calibrate`'s spread sets) and the bound read again on the straight line of the
    half, estimate side or far side, that the test there leaves: one step of the sharper rule
    (bench/calibrated_coverage.md, session 83)."""
    log_s, c = fit
    estimate = log_s[0].exp().numpy()
    upper = calibrated_upper(profile, found.candidates, found.rise_tail, tail)
    critical = _at_tail(found.rise_tail, tail)
    config = kept.config
    for i in range(3):
        x = found.candidates[i]
        observed, j = last_accepted(profile[i], x, critical[i])
        if j == len(x) - 1:
            continue
        truth = torch.from_numpy(
            np.tile(np.where(np.arange(3) == i, upper[i], estimate), (lines, 1))
        )
        b = simulate(kept.info, truth, c[0].expand(lines, 3), rng)
        fitted = adam_line(
            kept.info,
            b,
            epochs=config.sigma_epochs,
            lr=config.machine_lr,
            start=MACHINE_SIGMA_START,
        )
        rise = one_sided_rises(kept.info, b, *fitted, truth).clamp_min(0.0).numpy()[:, i]
        level = _at_tail(np.quantile(rise, 1 - TAIL_GRID)[None], tail)[0]
        middle = float(np.interp(np.log(upper[i]), np.log(PROFILE_GRID), profile[i])) - level
        if middle <= 0:  # not rejected: the far half
            x0, x1, y0, y1 = upper[i], x[j + 1], middle, observed[j + 1]
        else:
            x0, x1, y0, y1 = x[j], upper[i], observed[j], middle
        upper[i] = x0 + (x1 - x0) * (-y0) / (y1 - y0)
    return upper


def check_reading() -> None:
    """On a convex rise (30 (log(s / e))^2) with candidates four grid steps apart and one level at
    every candidate, `read_on_profile` is sigma_upper at the level (the test its tail would be)
    and the straight line falls short: else exit."""
    e = PROFILE_GRID[30]
    profile = np.tile(np.where(e < PROFILE_GRID, 30 * np.log(PROFILE_GRID / e) ** 2, 0.0), (3, 1))
    candidates = np.tile(PROFILE_GRID[30 : 30 + 4 * len(RISE_GRID) : 4], (3, 1))
    tail = 1 - bound_level(DEFAULT_CONFIDENCE)
    for level in (0.7, 2.3, 3.51):
        rise_tail = np.full((3, len(RISE_GRID), len(TAIL_GRID)), level)
        read = read_on_profile(profile, candidates, rise_tail, tail)
        line = calibrated_upper(profile, candidates, rise_tail, tail)
        exact = sigma_upper(np.full(3, e), profile, level)
        if not (np.allclose(read, exact, rtol=1e-12, atol=0) and np.all(line < exact)):
            sys.exit(f"read_on_profile at level {level}: {read} against {exact} (line {line})")


def main() -> None:
    args = rows_parser(__doc__).parse_args()
    check_reading()
    torch.set_num_threads(1)
    kept = kept_machines(setup(args.model), args.machines, np.random.default_rng(PICK_SEED))
    rows = read_rows(args.rows)
    missed = sorted(i for i, r in rows.items() if any(r["spread_miss"]))
    print(f"{len(missed)} of {len(rows)} lines with a spread bound missed", flush=True)
    tail = 1 - bound_level(DEFAULT_CONFIDENCE)
    counts = np.zeros((4, 3), dtype=int)  # rule x component
    for index in missed:
        _, (log_s, c), profile, found = calibrated_line(kept, index, args.inner, args.seed)
        line = calibrated_upper(profile, found.candidates, found.rise_tail, tail)
        step = calibrated_upper(profile, found.candidates, found.rise_tail, tail, interpolate=False)
        read = read_on_profile(profile, found.candidates, found.rise_tail, tail)
        between = simulated_between(
            kept,
            (log_s, c),
            profile,
            found,
            tail,
            rng=np.random.default_rng(
                np.random.SeedSequence(args.seed, spawn_key=(BETWEEN, index))
            ),
            lines=args.inner,
        )
        if line.tolist() != rows[index]["upper"]:
            sys.exit(f"line {index} does not come back to the bit: not the rows' model or code")
        truth = np.array(rows[index].get("truth", kept.sigma.numpy()))  # session 81: none
        counts += np.stack([line < truth, step < truth, read < truth, between < truth])
        change = np.abs(read / line - 1).max()
        print(
            f"line {index}: missed {(line < truth).astype(int)}, read on the profile "
            f"{(read < truth).astype(int)}, step {(step < truth).astype(int)}, "
            f"simulated between {(between < truth).astype(int)}; "
            f"largest change of the bound {100 * change:.2f} %",
            flush=True,
        )
    print(f"misses among these lines{'':8}" + "".join(f"{z:>8}" for z in Z_NAMES))
    names = ("straight line", "first rejected", "read on the profile", "simulated between")
    for name, row in zip(names, counts, strict=True):
        print(f"{name:32}" + "".join(f"{v:8d}" for v in row))


if __name__ == "__main__":
    main()
