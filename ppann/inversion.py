"""The line's bounds calibrated by simulation: the spread's by inverting its likelihood-ratio test,
the mean's radius by the studentised pivot's own law (beyond session 79's exact levels).

ppann/confidence.py's levels are exact for M machines observed directly and, measured through
phase 2's own fit (bench/bound_coverage.md), hold where the machines ran alike. Where a few
machines were seen unequally (a long run beside short ones) they do not: eight such machines
missed the damping's spread 3.3 % and its mean 3.6 % of the time, not the 1.67 % each bound
stands for, while components barely seen at all were bounded far wider than needed. The law of
the statistic depends on how well each machine was seen, which the training data tell exactly
(each machine's information M_e, phase 2's blocks), so it is simulated:

- the spread (test inversion): for each component i and candidate value g above the estimate,
  lines are drawn under phase 2's model with the truth at the estimate but sigma_i = g, each fitted
  by phase 2's own Adam (its epochs, rate and start), and the one-sided rise of the profile at
  the truth recorded (the rise at g of the NLL with the other parameters at the line's fit, 0
  where the line's estimate is above g; at the estimate itself too). The bound is the largest
  candidate whose observed rise does not exceed that rise's quantile at the asked level: the
  largest g the data cannot reject (the accepted set need not be an interval). Candidates sit
  where the observed profile has risen by RISE_GRID, so the observed rise at each is known
  without interpolating the quantiles across values;
- the mean: with every component's spread at its k-th candidate (k = 0: the estimate), the
  pooled average of each line's machines (what the mean model stands for) less the truth, in
  standard errors of the pooled covariance at the line's fitted spread; each component's radius
  is its one-sided quantile's largest over the candidates up to the first that covers the
  spread's bound (the pivot's tail is not monotone in the spread).

Measured (bench/calibrated_coverage.md, 825 lines of 8 unequally seen machines): the spread's
bound misses 1.70 / 2.18 / 0.24 % (the stiffness' 1.94 % of session 81 was the rule before the
estimate's own critical rise) and the mean's 0.55 / 0.97 / 0.00 % against the 1.67 % each
stands for, where the exact levels missed the damping 2.91 / 3.52 %. The default since then.
Two machines miss at most 1.97 %; three miss the damping's spread 2.60 % (809 lines, the bar
2.57 %; the exact levels miss its mean 3.40 %), of which 0.25 % is a bound below a truth a
fresh test did not reject (bench/calibration_size.py); on a fresh draw of 800 lines three
machines miss at most 1.38 %. Five machines (800 lines) miss at most 2.50 % (the damping's
spread; the exact levels its mean 5.00 %); pooled over every mix (4149 lines) the damping's
spread bound misses 2.12 % at the bench's 500 lines a candidate, about 1.9 % at
CALIBRATION_LINES (bench/inner_lines.py); neither the straight line between candidates nor the
profile's chord is the cause (bench/read_between.py).

Each statistic's quantiles are kept at TAIL_GRID's upper-tail probabilities (the OCP's
confidence is chosen later, `ppann/confidence.py`: each bound's tail is (1 - c) / 3); a tail
outside the grid, or a model without a calibration, takes the exact levels. The cost grows
with the machines (a line is fitted for each of them at every Adam step), and for many machines
the exact levels hold (Wilks: bench/bound_coverage.md, 70 and 310 machines): lines are
calibrated up to CALIBRATED_MACHINES machines.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from ppann.confidence import bound_level, mean_quantile, spread_level
from ppann.machine import pooled_from_information, sigma_upper
from ppann.model import PROFILE_GRID, RISE_GRID, TAIL_GRID

CALIBRATION_LINES = 2000
"""Lines simulated at each candidate (TAIL_GRID's last, 0.005, leaves ten in the tail)."""
CALIBRATION_CHUNK = 8192
"""Lines fitted at once."""
SETS = len(RISE_GRID) + 3 * (len(RISE_GRID) - 1)
"""The laws `calibrate` simulates: the mean's (every component at each candidate) and each
component's spread (at each candidate above the estimate, the others at the estimate)."""
CALIBRATED_MACHINES = 32
"""Lines of more machines than this keep the exact levels (module docstring)."""


def line_nll(
    info: torch.Tensor, b: torch.Tensor, log_s: torch.Tensor, c: torch.Tensor
) -> torch.Tensor:
    """Each line's summed phase-2 NLL (ppann/machine.py's `marginal_nll`, less what does not
    depend on the parameters), (L,), for machines' information M_e `info` (E, 3, 3), their
    statistics b_e = sum_k D_k R_k / V_k `b` (L, E, 3), log machine sigma and common offset
    (L, 3) each (broadcast to (L, ..., 3) for a grid). Written entry by entry: x^T (I + G)^-1 x
    and det(I + G) of each machine's 3 x 3 system by the adjugate, elementwise, so that many
    small systems cost what a few large arrays do (torch's batched Cholesky of 3 x 3 blocks
    took 5x as long)."""
    s = log_s.exp()
    white = 2 * (b.sum(-2) * c).sum(-1) + torch.einsum("...i,ij,...j->...", c, info.sum(0), c)
    x = s[..., None, :] * (b + torch.einsum("eij,...j->...ei", info, c))  # S (b_e + M_e c)
    m = {(i, j): info[:, i, j] for i in range(3) for j in range(i, 3)}
    s0, s1, s2 = s[..., 0, None], s[..., 1, None], s[..., 2, None]
    # I + G = [[a, b, c], [b, d, e], [c, e, f]] and its cofactors
    a, b_, c_ = 1 + s0 * s0 * m[0, 0], s0 * s1 * m[0, 1], s0 * s2 * m[0, 2]
    d, e, f = 1 + s1 * s1 * m[1, 1], s1 * s2 * m[1, 2], 1 + s2 * s2 * m[2, 2]
    k00, k01, k02 = d * f - e * e, c_ * e - b_ * f, b_ * e - c_ * d
    k11, k12, k22 = a * f - c_ * c_, b_ * c_ - a * e, a * d - b_ * b_
    det = a * k00 + b_ * k01 + c_ * k02
    x0, x1, x2 = x[..., 0], x[..., 1], x[..., 2]
    adj = (
        k00 * x0 * x0
        + k11 * x1 * x1
        + k22 * x2 * x2
        + 2 * (k01 * x0 * x1 + k02 * x0 * x2 + k12 * x1 * x2)
    )
    return 0.5 * (white - (adj / det).sum(-1) + torch.log(det).sum(-1))


def simulate(
    info: torch.Tensor, sigma: torch.Tensor, common: torch.Tensor, rng: np.random.Generator
) -> torch.Tensor:
    """b (L, E, 3) of lines drawn under phase 2's model, machine spread `sigma` and mean
    `common` (L, 3) each: eta_e = c + sigma N(0, I), b_e = -M_e eta_e + N(0, M_e)."""
    m = info.numpy()
    lines, machines = sigma.shape[0], m.shape[0]
    eta = common.numpy()[:, None] + sigma.numpy()[:, None] * rng.standard_normal(
        (lines, machines, 3)
    )
    chol = np.linalg.cholesky(m + 1e-300 * np.eye(3))
    noise = np.einsum("eij,lej->lei", chol, rng.standard_normal((lines, machines, 3)))
    return torch.from_numpy(-np.einsum("eij,lej->lei", m, eta) + noise)


def adam_fit(
    info: torch.Tensor,
    b: torch.Tensor,
    *,
    epochs: int,
    lr: float,
    start: float,
    on_epoch: Callable[[int, float], None] | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Phase 2's own fit of each line's machine parameters (ppann/train.py SpreadFit: Adam at
    `lr` for `epochs` from sigma `start` and offset 0), every line at once (Adam is per
    parameter: the lines' fits are independent). Log sigma and offset, (L, 3) each; `on_epoch`
    is told each epoch and its loss (the lines' mean NLL per machine)."""
    lines = b.shape[0]
    log_s = torch.full((lines, 3), math.log(start), dtype=torch.float64, requires_grad=True)
    c = torch.zeros((lines, 3), dtype=torch.float64, requires_grad=True)
    optimizer = torch.optim.Adam([log_s, c], lr=lr)
    blocks = 1.0 / b.shape[1]  # phase 2 averages over blocks; Adam is blind to the scale
    for epoch in range(epochs):
        loss = line_nll(info, b, log_s, c).sum() * blocks
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        if on_epoch is not None:
            on_epoch(epoch, float(loss.detach()) / lines)
    return log_s.detach(), c.detach()


def one_sided_rises(
    info: torch.Tensor, b: torch.Tensor, log_s: torch.Tensor, c: torch.Tensor, at: torch.Tensor
) -> torch.Tensor:
    """Each line's profile rise (L, 3) with one spread component moved to `at` (L, 3), the rest
    and the offset at the line's fit (`log_s`, `c`); 0 where `at` is not above the fit (the
    bound is upper: an estimate above the truth rejects nothing)."""
    with torch.no_grad():
        base = line_nll(info, b, log_s, c)
        out = torch.empty_like(log_s)
        for i in range(3):
            moved = log_s.clone()
            moved[:, i] = at[:, i].log()
            out[:, i] = line_nll(info, b, moved, c) - base
        return torch.where(log_s < at.log(), out, torch.zeros_like(out))


def profile_rises(
    info: torch.Tensor, b: torch.Tensor, log_s: torch.Tensor, c: torch.Tensor
) -> torch.Tensor:
    """Each line's profile rise on PROFILE_GRID (L, 3, len(PROFILE_GRID)), as ppann/machine.py's
    `population` takes it: one spread component moved, the rest and the offset at the fit."""
    grid = torch.as_tensor(PROFILE_GRID)
    with torch.no_grad():
        base = line_nll(info, b, log_s, c)
        profile = torch.empty((len(b), 3, len(grid)), dtype=torch.float64)
        for i in range(3):
            moved = log_s[:, None, :].repeat(1, len(grid), 1)
            moved[:, :, i] = grid.log()
            offset = c[:, None, :].expand(-1, len(grid), -1)
            profile[:, i] = line_nll(info, b[:, None], moved, offset) - base[:, None]
    return profile


def pooled_mean(info: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """The line's mean as a pooled least-squares fit reads it (the machines weighted by their
    information alone, as phase 1's mean model averages its data): -(sum M_e)^-1 sum b_e, (L, 3)."""
    return -torch.linalg.solve(info.sum(0), b.sum(1)[..., None])[..., 0]


def _upper_quantiles(values: np.ndarray) -> np.ndarray:
    """Quantiles of `values` (..., L) at TAIL_GRID's upper tails, (..., len(TAIL_GRID))."""
    return np.moveaxis(np.quantile(values, 1 - TAIL_GRID, axis=-1), 0, -1)


@dataclass(frozen=True)
class Calibration:
    """The simulated laws (module docstring) at TAIL_GRID."""

    candidates: np.ndarray
    """(3, len(RISE_GRID)) each component's candidate spreads (the first: the estimate)."""
    rise_tail: np.ndarray
    """(3, len(RISE_GRID), len(TAIL_GRID)) the one-sided rise's quantiles at each candidate
    (the first: at the estimate, every component's truth there)."""
    mean_tail: np.ndarray
    """(len(RISE_GRID), 3, len(TAIL_GRID)) each component's radius of the mean in standard
    errors (the one-sided pivot's quantile, both sides pooled) with every component's spread at
    its candidate."""


def calibrate(
    info: torch.Tensor,
    machine_sigma: torch.Tensor,
    common: torch.Tensor,
    profile: np.ndarray,
    *,
    epochs: int,
    lr: float,
    start: float,
    rng: np.random.Generator,
    lines: int = CALIBRATION_LINES,
    chunk: int = CALIBRATION_CHUNK,
    on_epoch: Callable[[int, float], None] | None = None,
) -> Calibration:
    """`Calibration` of a line fitted to `machine_sigma` (3,) and `common` (3,) with profile
    `profile` (3, len(PROFILE_GRID)), from its machines' information `info` (E, 3, 3), by phase
    2's Adam (`epochs`, `lr`, `start`); `lines` at each candidate, fitted `chunk` at a time
    (`on_epoch`: each Adam epoch of every chunk, numbered on, and its loss;
    `calibration_epochs` in all)."""
    estimate = machine_sigma.detach().numpy()
    k = len(RISE_GRID)
    candidates = np.stack(
        [
            [sigma_upper(estimate[i : i + 1], profile[i : i + 1], r)[0] for r in RISE_GRID]
            for i in range(3)
        ]
    )
    # the SETS truths: the mean's (every component at its k-th candidate), then the spread's
    # (one component at its k-th candidate, the others at the estimate), k from 1
    truths = [candidates[:, j] for j in range(k)] + [
        np.where(np.arange(3) == i, g, estimate) for i in range(3) for g in candidates[i, 1:]
    ]
    assert len(truths) == SETS  # calibration_epochs counts them
    truth = torch.from_numpy(np.repeat(np.array(truths), lines, axis=0))
    mean = common.detach()[None].expand(len(truth), 3)
    rise = np.zeros((len(truth), 3))
    pivot = np.zeros((len(truth), 3))
    for first in range(0, len(truth), chunk):
        part = slice(first, min(first + chunk, len(truth)))
        b = simulate(info, truth[part], mean[part], rng)
        done = first // chunk * epochs
        told = None if on_epoch is None else (lambda e, loss, d=done: on_epoch(d + e, loss))
        log_s, c = adam_fit(info, b, epochs=epochs, lr=lr, start=start, on_epoch=told)
        # each component's one-sided rise at its truth
        rise[part] = one_sided_rises(info, b, log_s, c, truth[part]).clamp_min(0.0).numpy()
        with torch.no_grad():
            cov = pooled_from_information(info, log_s.exp())
            se = torch.sqrt(torch.diagonal(cov, dim1=-2, dim2=-1))
            pivot[part] = ((pooled_mean(info, b) - mean[part]) / se).numpy()
    # each component's rise at the estimate (the first set: every truth there) and at its own
    # candidates (its sets, the others at the estimate)
    own = rise[k * lines :].reshape(3, k - 1, lines, 3)[np.arange(3), :, :, np.arange(3)]
    at_estimate = rise[:lines].T[:, None]  # (3, 1, lines)
    rise_tail = _upper_quantiles(np.concatenate([at_estimate, own], axis=1))
    sides = pivot[: k * lines].reshape(k, lines, 3)
    both = np.concatenate([sides, -sides], axis=1).transpose(0, 2, 1)  # (k, 3, 2 lines)
    return Calibration(candidates, rise_tail, _upper_quantiles(both))


def calibration_epochs(epochs: int, *, lines: int = CALIBRATION_LINES) -> int:
    """The Adam epochs of `calibrate` at `epochs` per chunk: its progress bar's length."""
    return epochs * math.ceil(SETS * lines / CALIBRATION_CHUNK)


def store_calibration(model: torch.nn.Module, found: Calibration) -> None:
    """Keep `found` in the model's buffers (ppann/model.py)."""
    with torch.no_grad():
        model.spread_candidates.copy_(torch.from_numpy(found.candidates))
        model.spread_rise_tail.copy_(torch.from_numpy(found.rise_tail))
        model.spread_mean_tail.copy_(torch.from_numpy(found.mean_tail))


def calibration_of(model: torch.nn.Module) -> Calibration | None:
    """The model's calibration, None if it has none (zeros: many machines, or trained before
    session 81)."""
    candidates = model.spread_candidates.detach().numpy().copy()
    if not candidates.any():
        return None
    rise = model.spread_rise_tail.detach().numpy().copy()
    return Calibration(candidates, rise, model.spread_mean_tail.detach().numpy().copy())


def line_bounds(
    *,
    machine_sigma: np.ndarray,
    profile: np.ndarray,
    machines: int,
    confidence: float,
    calibration: Calibration | None,
) -> tuple[np.ndarray, np.ndarray, bool]:
    """The line's bounds at `confidence` (each one-sided at tail (1 - c) / 3, ppann/confidence.py):
    the spread's upper bound (3,), the line mean's radius in standard errors along each
    component (3,), and whether they are the calibration's (else the exact levels for
    `machines`: no calibration, or the tail outside TAIL_GRID). At confidence 0 the estimate
    and 0.

    Raises:
      ValueError: one machine, at a confidence above 0."""
    if confidence == 0:
        return np.asarray(machine_sigma, dtype=float).copy(), np.zeros(3), False
    tail = 1 - bound_level(confidence)
    exact_radius = np.full(3, mean_quantile(confidence, machines))
    if calibration is not None:
        upper = calibrated_upper(profile, calibration.candidates, calibration.rise_tail, tail)
        if upper is not None:
            radius = calibrated_radius(calibration.mean_tail, calibration.candidates, upper, tail)
            return upper, exact_radius if radius is None else radius, True
    level = spread_level(confidence, machines)
    return sigma_upper(machine_sigma, profile, level), exact_radius, False


def _at_tail(table: np.ndarray, tail: float) -> np.ndarray | None:
    """`table` (..., len(TAIL_GRID)) interpolated in log tail to `tail`; None outside the grid."""
    if not TAIL_GRID[-1] <= tail <= TAIL_GRID[0]:
        return None
    x = np.log(TAIL_GRID[::-1])
    flat = table.reshape(-1, len(TAIL_GRID))[:, ::-1]
    at = np.array([np.interp(math.log(tail), x, row) for row in flat])
    return at.reshape(table.shape[:-1])


def last_accepted(
    profile: np.ndarray, candidates: np.ndarray, critical: np.ndarray
) -> tuple[np.ndarray, int]:
    """One component's excess at each candidate (the observed rise, `profile` read at the
    candidate, less its `critical` rise; at the estimate never above 0, its rise being 0) and
    the last candidate not rejected (excess at most 0)."""
    excess = np.interp(np.log(candidates), np.log(PROFILE_GRID), profile) - critical
    excess[0] = min(excess[0], 0.0)
    return excess, int(np.flatnonzero(excess <= 0)[-1])


def calibrated_upper(
    profile: np.ndarray,
    candidates: np.ndarray,
    rise_tail: np.ndarray,
    tail: float,
    *,
    interpolate: bool = True,
) -> np.ndarray | None:
    """Each spread's upper bound (3,) at upper tail `tail` by test inversion (module docstring):
    the largest spread not rejected -- the last candidate where the observed rise (`profile`
    read at the candidate) is at most the simulated rise's quantile, interpolated linearly to
    the rejected one after it (not `interpolate`: the rejected one itself, since the spreads
    between were not tested; wider by 26-56 % for 0.25 % fewer misses: not the default,
    bench/calibrated_coverage.md); PROFILE_GRID's
    end if the last is not rejected. Not the first rejection: the accepted set need not be an
    interval (a rejection just above a small estimate cut off truths that were not rejected:
    session 81). None: `tail` outside TAIL_GRID."""
    critical = _at_tail(rise_tail, tail)
    if critical is None:
        return None
    upper = np.empty(3)
    for i in range(3):
        excess, j = last_accepted(profile[i], candidates[i], critical[i])
        if j == len(excess) - 1:
            upper[i] = PROFILE_GRID[-1]
            continue
        x0, x1, y0, y1 = candidates[i, j], candidates[i, j + 1], excess[j], excess[j + 1]
        upper[i] = x0 + (x1 - x0) * (-y0) / (y1 - y0) if interpolate else x1
    return upper


def calibrated_radius(
    mean_tail: np.ndarray, candidates: np.ndarray, upper: np.ndarray, tail: float
) -> np.ndarray | None:
    """Each component's radius of the line mean (3,), in standard errors, at upper tail `tail`:
    the largest of its quantiles over the joint candidates from the estimate up to the first that
    covers the spread's bound `upper` (3,) (the spreads the data leave open; the pivot's tail is
    not monotone in the spread: heaviest where the spread is about what the runs can see). None:
    `tail` outside TAIL_GRID, or `upper` beyond the last candidate (the caller takes the exact
    radius, the limit of a spread far above the white noise)."""
    at = _at_tail(mean_tail, tail)
    covering = np.flatnonzero((candidates >= upper[:, None]).all(0))
    if at is None or covering.size == 0:
        return None
    return at[: int(covering[0]) + 1].max(0)
