"""Monte-Carlo simulation of a PPANN (paper eq. 11 and the machine-level extension), vectorised
over samples and seeded.

Modes (`MONTE_CARLO_MODES`):
- "step": z = z_mu + z_sigma * eps with a fresh eps at every step (the paper's eq. 11): white in
  time, what the sigma networks were fitted on (one-step residuals).
- "trajectory": one eps per trajectory, held for its whole length. A 3σ draw of z_B can make the
  damping negative, and such a draw diverges; kept for comparison with the paper's text.
- "machine": one machine per trajectory and no white noise: the inertia, damping and stiffness
  terms of eq. 14 are multiplied by exp(eta), eta ~ N(0, diag(machine_sigma^2)) drawn once per
  trajectory (the per-episode spread fitted in phase 2, ppann/machine.py); with
  `PPANNConfig.machine_terms` "prior", exp(eta) - 1 is added to 1 + z instead, so that only the
  prior's physical part of each term varies.
- "mixed": "machine" and "step" together: each trajectory is a machine, and white noise acts on it
  at every step. With machine_sigma = 0 it equals "step" exactly (exp(0) = 1).

The machine factors are log-normal, so a drawn machine's inertia, damping and stiffness keep the
sign of the mean model's at any number of σ: no machine draw diverges. With "prior" the drawn
prior part exp(eta) stays positive and the inertia keeps its floor (FusedHeads.acceleration); a
term whose network correction z is below -1 is negative on the mean model already.

Random numbers: the seed's SeedSequence spawns two children, white (eps) and machine (eta), so
"mixed" uses exactly the white draws of "step" and the machine draws of "machine" (common random
numbers across modes and across the iterations of the robust loop). A model with the slider
force's channel (ppann/lever.py) draws its force from the white child's first child, drawn per
step or per trajectory as eps is; a model without it draws nothing more, so its numbers are
those of before the channel existed.

The loop runs in NumPy on the fused weights (`FusedHeads`): a few dozen array operations per step
on (n_samples,) arrays, where torch's per-operation overhead would dominate.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.streams import PrefixDraws, sequence_key
from ppann import kernel
from ppann.counter import counter_normals, key_of
from ppann.heads import FusedHeads
from ppann.lever import lever_torque_sigma
from ppann.model import PPANN
from ppann.modes import MONTE_CARLO_MODES, check_mode

NORMAL_SOURCES = ("stream", "counter")
"""Where `monte_carlo`'s white normals come from (its docstring)."""
_WHITE = PrefixDraws()
"""The white draws (eps) of the seeds used last, per number of samples."""
_LEVER = PrefixDraws()
"""The same for the slider force's normals (a model with the channel, ppann/lever.py)."""


@dataclass(frozen=True)
class Bands:
    """Trajectories (n_samples, T + 1, 2) and their mean and standard deviation (T + 1, 2), the
    two computed when first read (the robust loop's tightening reads the samples alone: 0.6 ms
    of a draft's ~22 at 1000 trajectories)."""

    samples: np.ndarray

    @functools.cached_property
    def mean(self) -> np.ndarray:
        with np.errstate(over="ignore", invalid="ignore"):
            return self.samples.mean(axis=0)

    @functools.cached_property
    def std(self) -> np.ndarray:
        with np.errstate(over="ignore", invalid="ignore"):
            return self.samples.std(axis=0, ddof=1)


def machine_factors(
    machine_sigma: npt.ArrayLike, n_samples: int, rng: np.random.Generator
) -> np.ndarray:
    """Log-normal factors exp(eta), eta ~ N(0, diag(machine_sigma^2)), (n_samples, 3)."""
    sigma = np.asarray(machine_sigma, dtype=float)
    return np.exp(sigma * rng.standard_normal((n_samples, 3)))


def monte_carlo(
    model: PPANN | FusedHeads,
    x0: npt.ArrayLike,
    tau: npt.ArrayLike,
    *,
    n_samples: int = 100,
    mode: str = "step",
    seed: int | np.random.SeedSequence = 0,
    machine_sigma: npt.ArrayLike | None = None,
    feedback: Feedback | None = None,
    compiled: bool = True,
    normals: str = "stream",
    at: npt.ArrayLike | None = None,
    first: int = 0,
) -> Bands:
    """Simulate n_samples trajectories of the PPANN from x0 (2,) under tau (T,).

    machine_sigma: the spread of the machine draws (3,) in place of the model's (e.g. its upper
    confidence bound, control/robust.py); the same standard normals are scaled either way.
    feedback: simulate the closed loop under this tracking law (None: open loop).
    compiled: the rollout in C where it builds (`rollout`); False: NumPy's, bit for bit the
    per-step arithmetic of FusedHeads.
    normals: where the white normals come from: "stream", NumPy's generator on the white child
    (cached per seed, the common random numbers of the robust loop); "counter", ppann/counter.py's
    counter-based normals under the white child's key, generated inside the kernel (the tail
    check's 20 000 trajectories; the same numbers on the NumPy path).
    at: keep only these states (indices into the T + 1, increasing): the samples are then
    (n_samples, len(at), 2), the same numbers as the full run's at those indices (the tail
    check keeps its constraint samples: 32 MB written and faulted in less at 20 000).
    first: the trajectories first..first + n_samples - 1 of the run of first + n_samples (the
    same numbers; with counter normals only): the tail check's stages draw only their new ones.

    A draw that diverges (possible with trajectory draws of a model whose σ allows a negative
    effective damping) becomes inf/NaN in its samples, silently: callers report such numbers as
    null rather than let NumPy print overflow warnings at the user.
    """
    check_mode(mode)
    if n_samples < 2:
        raise ValueError(f"n_samples must be >= 2 for a standard deviation, got {n_samples}")
    if first < 0 or (first and normals != "counter"):
        raise ValueError(f"first must be >= 0, and 0 unless normals is 'counter', got {first}")
    heads = model if isinstance(model, FusedHeads) else FusedHeads(model)
    tau = np.asarray(tau, dtype=float)
    root = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    white_seq, machine_seq = root.spawn(2)
    steps = tau.shape[0]
    draw = MONTE_CARLO_MODES[mode]
    if normals not in NORMAL_SOURCES:
        raise ValueError(f"normals must be one of {', '.join(NORMAL_SOURCES)}, got {normals!r}")
    eps = lever_eps = key = None
    if draw.white is not None and normals == "counter":
        key = key_of(white_seq)
    elif draw.white is not None:
        per = steps if draw.white == "step" else 1
        eps = _WHITE.get(
            (sequence_key(white_seq), n_samples),
            per,
            lambda rows: np.random.default_rng(white_seq).standard_normal((rows, n_samples, 3)),
        )
        if heads.has_lever:
            force_seq = np.random.SeedSequence(
                white_seq.entropy, spawn_key=(*white_seq.spawn_key, 0)
            )
            lever_eps = _LEVER.get(
                (sequence_key(force_seq), n_samples),
                per,
                lambda rows: np.random.default_rng(force_seq).standard_normal((rows, n_samples)),
            )
    factors = None
    if draw.machine:
        spread = heads.machine_sigma if machine_sigma is None else machine_sigma
        rng = np.random.default_rng(machine_seq)
        factors = machine_factors(spread, first + n_samples, rng)[first:]
    samples = rollout(
        heads,
        x0,
        tau,
        n_samples=n_samples,
        eps=eps,
        factors=factors,
        feedback=feedback,
        compiled=compiled,
        lever_eps=lever_eps,
        key=key,
        per_trajectory=draw.white == "held",
        at=at,
        first=first,
    )
    return Bands(samples)


@dataclass(frozen=True)
class Feedback:
    """A tracking law the simulated machine runs under (control/lqr.py): before step k the torque
    is clip(tau_k - gains_k . (x_k - plan_k), +-limit), x = (theta, omega)."""

    plan: np.ndarray
    """Planned states x_1..x_T, (T, 2) or longer."""
    gains: np.ndarray
    """(T, 2) or longer."""
    limit: float
    """Torque saturation, N·m."""


def rollout(
    heads: FusedHeads,
    x0: npt.ArrayLike,
    tau: np.ndarray,
    *,
    n_samples: int,
    eps: np.ndarray | None = None,
    factors: np.ndarray | None = None,
    feedback: Feedback | None = None,
    compiled: bool = True,
    lever_eps: np.ndarray | None = None,
    key: int | None = None,
    per_trajectory: bool = False,
    at: npt.ArrayLike | None = None,
    first: int = 0,
) -> np.ndarray:
    """Trajectories (n_samples, T + 1, 2) from x0 under tau (T,): z = z_mu + z_sigma eps[k]
    (eps (T, n, 3) for a fresh draw per step, (1, n, 3) for one per trajectory, None for the
    mean model), on machines `factors` (n, 3) (None: the fitted line's mean machine), open loop
    or under `feedback`; `lever_eps` (T or 1, n): the slider force's normals (ppann/lever.py),
    with eps, for a model that has the channel. `compiled`: by the C kernel of ppann/kernel.py
    where it builds (the same numbers to float32 rounding), else by the NumPy loop below.
    `key` (eps and lever_eps None): ppann/counter.py's normals under it in their place, drawn
    per step, or per trajectory with `per_trajectory`. `at`: only these states (indices into
    the T + 1, increasing), (n_samples, len(at), 2). `first`: the key's normals of trajectories
    first.. (`monte_carlo`)."""
    steps = tau.shape[0]
    if at is not None:
        at = np.asarray(at, dtype=int)
        if at.ndim != 1 or at.size == 0 or at[0] < 0 or at[-1] > steps or np.any(np.diff(at) <= 0):
            raise ValueError(f"at: increasing state indices within 0..{steps}, got {at.tolist()}")
    if key is not None:
        per_step = not per_trajectory and steps > 1
    else:
        per_step = eps is not None and eps.shape[0] == steps and steps > 1
    if compiled:
        samples = kernel.rollout(
            heads,
            np.asarray(x0, dtype=float),
            np.asarray(tau, dtype=float),
            n_samples=n_samples,
            eps=eps,
            factors=factors,
            plan=None if feedback is None else feedback.plan,
            gains=None if feedback is None else feedback.gains,
            limit=0.0 if feedback is None else feedback.limit,
            per_step=per_step,
            lever_eps=lever_eps,
            key=key,
            at=at,
            first=first,
        )
        if samples is not None:
            return samples
    if key is not None:
        drawn = counter_normals(
            key, samples=n_samples, steps=steps if per_step else 1, offset=first
        )
        eps = drawn[..., :3]
        lever_eps = drawn[..., 3] if heads.has_lever else None
    samples = np.empty((n_samples, steps + 1, 2))
    theta = np.full(n_samples, float(np.asarray(x0)[0]))
    omega = np.full(n_samples, float(np.asarray(x0)[1]))
    samples[:, 0, 0], samples[:, 0, 1] = theta, omega
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(steps):
            mean, sigma = heads(theta, omega)
            draw = None if eps is None else sigma * eps[k if per_step else 0]
            z = mean if draw is None else mean + draw
            noise = None
            if draw is not None and heads.linear_inertia:  # z_J's draw to first order
                z[:, 0], noise = mean[:, 0], draw[:, 0]
            u: float | np.ndarray = tau[k]
            if feedback is not None:
                ref, gain = feedback.plan[k], feedback.gains[k]
                u = tau[k] - gain[0] * (theta - ref[0]) - gain[1] * (omega - ref[1])
                u = np.clip(u, -feedback.limit, feedback.limit)
            if lever_eps is not None:  # a load disturbance: after the law's saturation
                force = lever_eps[k if per_step else 0]
                u = u + lever_torque_sigma(heads.lever_table, heads.cell, theta) * force
            alpha = heads.acceleration(theta, omega, u, z, factors=factors, inertia_noise=noise)
            theta, omega = heads.advance(theta, omega, alpha)
            samples[:, k + 1, 0], samples[:, k + 1, 1] = theta, omega
    return samples if at is None else samples[:, at]
