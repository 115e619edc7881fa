"""The tightening of the robust constraint (eq. 16 and beyond) at each constraint sample, from
the Monte-Carlo of one torque (`slider_uncertainty`): k sigma below the Monte-Carlo's mean
(centred, the default), below the plan (gaussian, eq. 16) or the empirical one-sided quantile,
each with its standard error, the allowance for the Monte-Carlo's own error, and the
allowance for the line as known from a few machines (`confidence`, control/robust.py's
docstring): the machine spread the Monte-Carlo draws with, and how far the line's mean slider can
sit below the model's."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from common.streams import PrefixDraws, rng, stream
from control.config import OCPConfig, lower_tail
from control.ocp import Solution
from ppann.confidence import confidence_quantile, one_machine
from ppann.heads import FusedHeads
from ppann.inversion import line_bounds
from ppann.modes import MONTE_CARLO_MODES
from ppann.montecarlo import Feedback, monte_carlo, rollout
from ppann.transmission import draw

_DELTA = PrefixDraws()
"""The transmission angles drawn for the Monte-Carlo's slider positions (a prefix per draft)."""


def line_allowance(heads: FusedHeads, config: OCPConfig) -> tuple[np.ndarray | None, float]:
    """The machine spread the Monte-Carlo draws with (None: the model's own) and z, for the
    configured confidence (module docstring): the spread's bound (`_bounds`)."""
    z = confidence_quantile(config.confidence)
    if z == 0 or not MONTE_CARLO_MODES[config.mc_mode].machine:
        return None, z
    return _bounds(heads, config)[0], z


def mean_allowance_quantile(heads: FusedHeads, config: OCPConfig) -> np.ndarray:
    """The line mean's radius along each component (`population_margin`'s z) for the configured
    confidence (`_bounds`)."""
    return _bounds(heads, config)[1]


def _bounds(heads: FusedHeads, config: OCPConfig) -> tuple[np.ndarray, np.ndarray, bool]:
    """ppann/inversion.py line_bounds at the configured confidence (RobustError: one machine)."""
    if heads.spread_machines == 1 and config.confidence > 0:
        from control.records import RobustError  # control.records imports this module

        raise RobustError(one_machine(config.confidence))
    return line_bounds(
        machine_sigma=heads.machine_sigma,
        profile=heads.machine_profile,
        machines=heads.spread_machines,
        confidence=config.confidence,
        calibration=heads.calibration,
    )


def population_margin(
    heads: FusedHeads,
    solution: Solution,
    config: OCPConfig,
    z: float | np.ndarray,
    *,
    feedback: Feedback | None = None,
) -> np.ndarray:
    """How far the line's mean slider can sit below the model's at each constraint sample, at
    z standard errors of the line's mean (`mean_allowance_quantile`: the one-sided bound from
    the model's machines, module docstring; per component (3,): the ellipsoid's axes scaled
    so that each component reaches its own), m: the largest drop of the mean model's slider
    over line shifts delta on the ellipsoid delta^T C^-1 delta = z^2, evaluated by simulation, not
    linearised (near top dead centre the slider is concave in theta: the linear bound was 30 %
    short in tests/test_tightening.py). The shifts tried: the ellipsoid's six vertices (+-z along
    each principal axis), the linear worst case of each sample, and ELLIPSOID_DIRECTIONS spread
    evenly over the ellipsoid. With `feedback`, every shifted line runs under that tracking law.

    The linear worst case comes from secants across the ellipsoid (vertex against opposite
    vertex), not from a derivative at delta = 0: the model's stiffness term jumps where theta
    crosses 2 pi, so the mean slider moves in small steps as the crossing changes sample, and
    central differences 1e-3 wide landed on a step on every other torque of one robust solve (a
    linear bound of 1.98 mm beside 1.33 mm a torque later); the worst case they pointed to was
    then no worst case, and the simulated allowance fell from 1.45 to 1.33 mm."""
    count = len(config.constraint_samples)
    radius = np.broadcast_to(np.asarray(z, dtype=float), (3,))  # per component: scaled axes
    if not radius.any() or not np.any(heads.common_covariance):
        return np.zeros(count)
    index = np.array(config.constraint_samples) - 1
    x0, tau = solution.states[0], solution.tau[: int(index.max())]
    z = float(radius.max())
    c = heads.common_covariance * np.outer(radius / z, radius / z)
    values, vectors = np.linalg.eigh(0.5 * (c + c.T))
    root = vectors * np.sqrt(np.clip(values, 0.0, None))  # root @ root.T == c
    vertices = z * np.concatenate([root.T, -root.T])
    first = _slider_at(
        heads, x0, tau, np.concatenate([np.zeros((1, 3)), vertices]), index, feedback
    )
    # slope of the slider in whitened coordinates u (delta = root u), per sample: (count, 3)
    slope = ((first[1:4] - first[4:7]) / (2 * z)).T
    norm = np.linalg.norm(slope, axis=1, keepdims=True)
    worst = -z * np.where(norm > 0, slope / np.where(norm > 0, norm, 1.0), 0.0) @ root.T
    shifts = np.concatenate([z * _sphere(ELLIPSOID_DIRECTIONS) @ root.T, worst])
    slider = np.concatenate([first, _slider_at(heads, x0, tau, shifts, index, feedback)])
    drop = slider[0] - slider[1:]
    return np.clip(np.where(np.isfinite(drop), drop, np.inf).max(axis=0), 0.0, None)


def _slider_at(
    heads: FusedHeads,
    x0: np.ndarray,
    tau: np.ndarray,
    delta: np.ndarray,
    index: np.ndarray,
    feedback: Feedback | None,
) -> np.ndarray:
    """Mean-model slider position at samples `index` of lines shifted by delta (n, 3): (n, k)."""
    paths = rollout(heads, x0, tau, n_samples=len(delta), factors=np.exp(delta), feedback=feedback)
    with np.errstate(invalid="ignore"):
        return heads.geometry.slider_position(paths[:, index, 0])


ELLIPSOID_DIRECTIONS = 64
"""Shifts of the line tried evenly over the confidence ellipsoid (beside the linear worst case)."""


def _sphere(n: int) -> np.ndarray:
    """n unit vectors spread evenly over the sphere (Fibonacci lattice), (n, 3)."""
    i = np.arange(n) + 0.5
    polar = np.arccos(1 - 2 * i / n)
    azimuth = np.pi * (1 + 5**0.5) * i
    return np.stack(
        [np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=-1
    )


def tightening(
    samples: np.ndarray, plan: float, *, k_sigma: float, method: str
) -> tuple[float, float]:
    """The margin one constraint sample asks for, and its standard error, from Monte-Carlo slider
    positions `samples` (n,) under a plan whose mean-model slider position is `plan`.

    gaussian  k·σ (paper eq. 16); standard error k·σ·sqrt((κ − 1) / (4 n)), κ the samples'
              kurtosis (the delta method on Var(s²) = (μ₄ − σ⁴) / n): k·σ / sqrt(2 n) for
              normal samples, and larger for the heavy, skewed tails near top dead centre, where
              the normal formula understated the estimate's spread (2× for an exponential law).
    centred   plan − mean + k·σ: k·σ below the samples' mean rather than below the plan. Near
              top dead centre x(theta) is concave, so the mean slider of the machines sits below
              the slider of the mean plan (by about |x''| var(theta) / 2); eq. 16 counts k·σ from
              the plan and so reads that offset as margin. Measured on a horizon-200 task
              (docs/history.md, *Warm machines and the centred tightening*): the Monte-Carlo's mean
              sat 1.5 mm below the plan at sample 130, the twin's on machines of the training
              population 1.7 mm below it.
              Standard error by the delta method on mean − k·s: sqrt((σ² + k² (μ₄ − σ⁴) / (4 σ²)
              − k μ₃ / σ) / n) (the mean and s of a skewed law are correlated: μ₃ / (2 σ n)).
    quantile  plan − Q_p, Q_p the empirical lower quantile at p = Φ(−k), so that the slider is
              above the height with the probability k·σ stands for even when the spread is skewed
              or its mean is not the plan; standard error half the distance between the order
              statistics n p ∓ sqrt(n p (1 − p)) (distribution-free).
    """
    n = samples.shape[0]
    if method == "gaussian":
        sigma = float(np.std(samples, ddof=1))
        return k_sigma * sigma, k_sigma * sigma * sigma_relative_se(samples)
    if method == "centred":
        sigma = float(np.std(samples, ddof=1))
        offset = plan - float(np.mean(samples))
        return offset + k_sigma * sigma, _centred_se(samples, k_sigma)
    p = lower_tail(k_sigma)
    ordered = np.sort(samples)
    spread = math.sqrt(n * p * (1 - p))
    lo = ordered[max(0, math.floor(n * p - spread))]
    hi = ordered[min(n - 1, math.ceil(n * p + spread))]
    return plan - float(np.quantile(samples, p)), float(hi - lo) / 2


def sampling_allowance(
    samples: np.ndarray, plan: float, *, k_sigma: float, method: str, z: float
) -> float:
    """How much to add to `tightening(samples, ...)` so that the sum is a one-sided upper
    confidence bound, at normal quantile z, of the tightening an infinite Monte-Carlo would ask
    for (control/robust.py's docstring); 0 at z = 0.

    gaussian  k (s_up − s), s_up the chi-square bound s sqrt(d / chi2_d(Φ(−z))) with
              d = 2 n / (κ − 1) degrees of freedom, the chi-square whose variance of s² is the
              one the samples' kurtosis κ gives (Satterthwaite; ≈ n, the classical bound, for
              normal samples). It keeps the skew of the estimate's distribution, which a
              symmetric z·SE does not: z·SE covered 97.9 % of normal Monte-Carlos at a nominal
              98.3 %, this bound 98.3 % (tests/test_tightening.py).
    centred   the gaussian allowance scaled by the ratio of the two standard errors (that of
              mean − k·s to that of k·s): the chi-square bound's skew, widened for the mean.
    quantile  Q_p − the order statistic n p − z sqrt(n p (1 − p)) (distribution-free).
    """
    if z == 0:
        return 0.0
    n = samples.shape[0]
    if method in ("gaussian", "centred"):
        from scipy.special import chdtri  # SciPy where it is used: the CLI does not load it

        sigma = float(np.std(samples, ddof=1))
        kurtosis = _kurtosis(samples)
        dof = 2 * n / max(kurtosis - 1, 1e-12)
        lower = float(chdtri(dof, 1 - 0.5 * math.erfc(z / math.sqrt(2))))
        allowance = k_sigma * sigma * (math.sqrt(dof / lower) - 1)
        if method == "gaussian":
            return allowance
        plain = k_sigma * sigma * sigma_relative_se(samples)  # `tightening`'s gaussian se
        return allowance * _centred_se(samples, k_sigma) / plain if plain > 0 else 0.0
    p = lower_tail(k_sigma)
    ordered = np.sort(samples)
    low = ordered[max(0, math.floor(n * p - z * math.sqrt(n * p * (1 - p))))]
    return float(np.quantile(samples, p)) - float(low)


def _moments(samples: np.ndarray) -> tuple[float, float, float]:
    """The samples' central moments m2, m3, m4 (by products: NumPy's power took 185 us for 1000
    samples, called four times per constraint sample of each Monte-Carlo)."""
    centred = samples - samples.mean()
    square = centred * centred
    return float(square.mean()), float((square * centred).mean()), float((square * square).mean())


def _centred_se(samples: np.ndarray, k_sigma: float) -> float:
    """Standard error of mean − k·s of `samples` (the delta method, `tightening`'s docstring)."""
    m2, m3, m4 = _moments(samples)
    if m2 == 0:
        return 0.0
    sigma = math.sqrt(m2)
    variance = m2 + k_sigma**2 * (m4 - m2**2) / (4 * m2) - k_sigma * m3 / sigma
    return math.sqrt(max(variance, 0.0) / samples.shape[0])


def sigma_relative_se(samples: np.ndarray) -> float:
    """The standard error of the samples' standard deviation relative to it, sqrt((κ − 1) / (4 n))
    with κ their kurtosis (the delta method on Var(s²) = (μ₄ − σ⁴) / n; 1 / sqrt(2 n) for a
    normal law): the gaussian tightening's, and the held-out check's for each predicted σ
    (replay/heldout.py). 0 for constant samples, inf where one is not finite (a diverged draw)."""
    if not np.all(np.isfinite(samples)):
        return math.inf
    m2, _, m4 = _moments(samples)
    return math.sqrt(max(m4 / m2**2 - 1, 0.0) / (4 * samples.shape[0])) if m2 > 0 else 0.0


def _kurtosis(samples: np.ndarray) -> float:
    """The samples' kurtosis m4 / m2² (3 for a normal law; 3 for constant samples)."""
    m2, _, m4 = _moments(samples)
    return m4 / m2**2 if m2 > 0 else 3.0


@dataclass(frozen=True)
class Uncertainty:
    """Monte-Carlo slider position under one torque: mean and std per sample, (N,) each, m (a
    draft's, `constraints_only`: to the last constraint sample, NaN between the constraint
    samples); and the tightening it asks for at the constraint samples, with its standard
    error, m."""

    mean: np.ndarray
    std: np.ndarray
    wall_time: float
    tightening: np.ndarray
    """Per constraint sample: plan − mean + k·σ (centred), k·σ (gaussian) or plan − quantile
    (quantile), plus `population`
    and `sampling`, m."""
    tightening_se: np.ndarray
    """Standard error of plan − mean + k·σ, k·σ or plan − quantile from the finite Monte-Carlo,
    m."""
    population: np.ndarray
    """The part of `tightening` that allows for the line's uncertain mean, m (module docstring);
    zeros at confidence 0."""
    sampling: np.ndarray
    """The part of `tightening` that allows for the Monte-Carlo's finite sample, about z times
    `tightening_se`, m (module docstring); zeros at confidence 0."""
    samples: int
    """Trajectories the Monte-Carlo drew (control/profiles.py may have drawn more than the
    configured count)."""
    angles: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 0)))
    """The drawn crank angles (with the transmission's) at the constraint samples, (samples,
    constraint samples), rad: what the slider positions of the tightening were computed from."""


def slider_uncertainty(
    heads: FusedHeads,
    solution: Solution,
    config: OCPConfig,
    *,
    constraints_only: bool = False,
    gains: np.ndarray | None = None,
) -> Uncertainty:
    """Monte-Carlo (eq. 11, or the configured mode) of the slider position under the solution's
    torque u_1..u_{N-1}, and the tightening of `config.tightening` at the constraint samples.
    The draws are the same for every call (common random numbers). With `gains` (N-1, 2) each
    machine runs under the LQR law along the solution (profile robust-fb: a tube), and so do
    the shifted lines of the line allowance.

    constraints_only: simulate only up to the last constraint sample, and take the slider only
    at the constraint samples (mean and std stop at the last one and are NaN between them); the
    tightening is the same to the last bit, since every draw is a prefix of the full run's. The
    drafts of the robust loop need nothing more (the slider at every sample was 2.5 ms of a
    draft's ~22).
    """
    started = time.perf_counter()
    steps = max(config.constraint_samples) - 1 if constraints_only else len(solution.tau) - 1
    spread, z = line_allowance(heads, config)
    feedback = None
    if gains is not None:
        feedback = Feedback(solution.states, gains, config.torque_limit)
    bands = monte_carlo(
        heads,
        solution.states[0],
        solution.tau[:steps],
        n_samples=config.mc_samples,
        mode=config.mc_mode,
        seed=stream(config.mc_seed, "monte_carlo"),
        machine_sigma=spread,
        feedback=feedback,
    )
    # The crank's angle to the motor (ppann/transmission.py): zero if the model has none. Drawn
    # time-major so that a shorter run's draws are a prefix of a longer one's (the drafts).
    n, length = bands.samples.shape[:2]
    delta = _DELTA.get(
        (config.mc_seed, n, heads.transmission.tobytes()),
        length,
        lambda rows: draw(heads.transmission, (rows, n), rng(config.mc_seed, "transmission")),
    ).T
    index = np.array(config.constraint_samples) - 1
    if constraints_only:
        angle = bands.samples[:, index, 0] + delta[:, index]
        with np.errstate(over="ignore", invalid="ignore"):
            constrained = heads.geometry.slider_position(angle)
        mean, std = np.full(length, np.nan), np.full(length, np.nan)
        mean[index], std[index] = constrained.mean(axis=0), constrained.std(axis=0, ddof=1)
    else:
        every = bands.samples[:, :, 0] + delta
        angle = every[:, index]
        with np.errstate(over="ignore", invalid="ignore"):
            slider = heads.geometry.slider_position(every)
        constrained = slider[:, index]
        mean, std = slider.mean(axis=0), slider.std(axis=0, ddof=1)
    z_mean = mean_allowance_quantile(heads, config)
    population = population_margin(heads, solution, config, z_mean, feedback=feedback)
    tightened, standard_error, sampling = _tightened(solution, constrained, population, config, z)
    return Uncertainty(
        mean,
        std,
        time.perf_counter() - started,
        tightening=tightened,
        tightening_se=standard_error,
        population=population,
        sampling=sampling,
        samples=n,
        angles=angle,
    )


def at_k(heads: FusedHeads, solution: Solution, unc: Uncertainty, config: OCPConfig) -> Uncertainty:
    """`unc`, `slider_uncertainty`'s of `solution` under a configuration that differs from
    `config` in k alone, at config.k_sigma: the same draws give the same sliders and the line's
    mean allowance (`population`) does not depend on k, so only the tightening, its standard
    error and the sampling allowance are computed again, from `unc.angles` (the aware loop's
    raise at a draft, control/aware.py: one Monte-Carlo fewer). Equal to
    `slider_uncertainty` at that k to the last bit (tests/test_tightening.py)."""
    if unc.samples != config.mc_samples:
        raise ValueError(
            f"a Monte-Carlo of {unc.samples} draws moved to k {config.k_sigma:g}, where the "
            f"configuration draws {config.mc_samples}"
        )
    started = time.perf_counter()
    with np.errstate(over="ignore", invalid="ignore"):
        constrained = heads.geometry.slider_position(unc.angles)
    z = confidence_quantile(config.confidence)  # line_allowance's z, without its machine spread
    tightened, standard_error, sampling = _tightened(
        solution, constrained, unc.population, config, z
    )
    return replace(
        unc,
        wall_time=unc.wall_time + time.perf_counter() - started,
        tightening=tightened,
        tightening_se=standard_error,
        sampling=sampling,
    )


def _tightened(
    solution: Solution,
    constrained: np.ndarray,
    population: np.ndarray,
    config: OCPConfig,
    z: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tightening at config.k_sigma (population and sampling allowance included), its
    standard error and the sampling allowance, from the sliders at the constraint samples
    (`constrained`, (draws, constraint samples)), m."""
    index = np.array(config.constraint_samples) - 1
    plan = solution.slider
    columns = [(constrained[:, j], plan[k]) for j, k in enumerate(index)]
    options = {"k_sigma": config.k_sigma, "method": config.tightening}
    margins = [tightening(x, at, **options) for x, at in columns]
    sampling = np.array([sampling_allowance(x, at, **options, z=z) for x, at in columns])
    tightened = np.array([m for m, _ in margins]) + population + sampling
    return tightened, np.array([se for _, se in margins]), sampling
