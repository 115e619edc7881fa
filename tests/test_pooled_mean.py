"""The line mean's covariance is the pooled average's (ppann/machine.py `pooled_covariance`): the
mean model averages the machines by the information their runs carry, not as the likelihood
would, so where machines carry unequal information its error is wider than the inverse Hessian
said (session 80: 1.6x in the damping after the default chain's plan round)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ppann.machine import (
    EpisodeTerms,
    machine_sums,
    marginal_nll,
    pooled_covariance,
    population,
)

SPREAD = torch.tensor([0.3, 0.2, 0.1], dtype=torch.float64)


def _line(counts: list[int], seed: int) -> EpisodeTerms:
    """Machines with `counts` samples each, a random design of unit white variance per sample
    (one sample a block); the residual is left zero (the test draws its own)."""
    rng = np.random.default_rng(seed)
    n = sum(counts)
    design = torch.from_numpy(rng.standard_normal((n, 3)) * np.array([1.0, 0.7, 1.3]))
    derivative = torch.zeros((n, 3), dtype=torch.float64)
    derivative[:, 0] = 1.0  # with sigma (1, ., .): each sample's white variance 1
    machine = torch.repeat_interleave(torch.arange(len(counts)), torch.tensor(counts))
    return EpisodeTerms(
        residual=torch.zeros(n, dtype=torch.float64),
        design=design,
        derivative=derivative,
        block=torch.arange(n),
        machine=machine,
        n_machines=len(counts),
    )


def _ones(terms: EpisodeTerms) -> torch.Tensor:
    return torch.ones((terms.residual.shape[0], 3), dtype=torch.float64)


def _likelihood_covariance(terms: EpisodeTerms) -> torch.Tensor:
    """The inverse Hessian of the summed phase-2 NLL in the common offset (autograd): the
    covariance of the likelihood's own estimate of the line's mean."""
    n = terms.residual.shape[0]

    def total(offset: torch.Tensor) -> torch.Tensor:
        return n * marginal_nll(terms.shifted(offset), _ones(terms), SPREAD)

    hessian = torch.autograd.functional.hessian(total, torch.zeros(3, dtype=torch.float64))
    return torch.linalg.inv(0.5 * (hessian + hessian.T))


def _repeated(samples: int, machines: int, *, scale: float = 1.0) -> EpisodeTerms:
    """`machines` machines that ran the same `samples` samples, the design times `scale`."""
    one = _line([samples], seed=samples)
    return EpisodeTerms(
        residual=one.residual.repeat(machines),
        design=scale * one.design.repeat(machines, 1),
        derivative=one.derivative.repeat(machines, 1),
        block=torch.arange(samples * machines),
        machine=torch.arange(machines).repeat_interleave(samples),
        n_machines=machines,
    )


def test_machines_of_equal_information_give_the_likelihoods_covariance() -> None:
    """Every machine the same runs: the pooled average is the likelihood's estimate, and the
    two covariances agree to rounding."""
    terms = _repeated(60, 9)
    pooled = pooled_covariance(terms, _ones(terms), SPREAD)
    assert torch.allclose(pooled, _likelihood_covariance(terms), rtol=1e-9, atol=1e-15)


def test_the_pooled_average_varies_as_its_covariance_says_and_more_than_the_likelihoods() -> None:
    """Six machines of 200 samples and six of 20 (a dataset's long runs beside a plan round's
    short ones): over 8000 drawn lines (machine offsets ~ N(0, SPREAD^2), unit white noise per
    sample) the information-weighted average of the machines varies as `pooled_covariance` says
    (within 4 standard errors of the sample variance), and the likelihood's inverse Hessian is
    short of it by more than that in every component."""
    counts = [200] * 6 + [20] * 6
    terms = _line(counts, seed=2)
    ones = _ones(terms)
    variance = terms.white_variance(ones)
    info, _ = machine_sums(terms.residual, terms.design, variance, terms.machine, 12)
    inverse = torch.linalg.inv(info.sum(0))
    generator = torch.Generator().manual_seed(3)
    lines, estimates = 8000, []
    for _ in range(lines // 1000):
        eta = SPREAD * torch.randn((1000, 12, 3), generator=generator, dtype=torch.float64)
        noise = torch.randn((1000, len(terms.residual)), generator=generator, dtype=torch.float64)
        residual = -(terms.design * eta[:, terms.machine]).sum(-1) + noise
        # the pooled fit's offset: argmin of sum_k (r_k + D_k c)^2 / V_k over all samples
        b = (terms.design * (residual / variance)[..., None]).sum(1)
        estimates.append(-(inverse @ b[..., None])[..., 0])
    observed = torch.cat(estimates).var(0, correction=0)
    pooled = torch.diagonal(pooled_covariance(terms, ones, SPREAD))
    likelihood = torch.diagonal(_likelihood_covariance(terms))
    se = math.sqrt(2 / lines)  # relative standard error of a normal sample variance
    print(
        f"observed {observed.tolist()}, pooled {pooled.tolist()}, likelihood {likelihood.tolist()}"
    )
    assert torch.all(torch.abs(observed / pooled - 1) < 4 * se)
    assert torch.all(likelihood < (1 - 4 * se) * observed)


def test_the_pooled_covariance_is_never_below_the_likelihoods() -> None:
    """Gauss-Markov: the likelihood's estimate is the best linear one, so the pooled average's
    covariance minus the inverse Hessian is positive semi-definite, for any mix of machines."""
    for seed, counts in enumerate(([5, 300, 40], [100] * 4 + [3] * 7, [30, 31, 29, 500])):
        terms = _line(counts, seed=10 + seed)
        gap = pooled_covariance(terms, _ones(terms), SPREAD) - _likelihood_covariance(terms)
        assert torch.linalg.eigvalsh(0.5 * (gap + gap.T)).min() > -1e-12
        assert torch.trace(gap) > 0


@pytest.mark.parametrize("machines", [8, 40])
def test_directly_observed_machines_give_the_textbook_standard_error(machines: int) -> None:
    """Equal runs that see each machine's offset to ~1e-3 of the spread: s / sqrt(M), as the
    likelihood's did (test_machine.py)."""
    terms = _repeated(400, machines, scale=1e2)
    se = torch.sqrt(torch.diagonal(pooled_covariance(terms, _ones(terms), SPREAD)))
    assert torch.allclose(se, SPREAD / math.sqrt(machines), rtol=1e-3)


def test_phase_twos_population_carries_the_pooled_covariance() -> None:
    """What phase 2 stores in the checkpoint (`population`'s common_covariance) is the pooled
    average's, not the likelihood's inverse Hessian, on machines of unequal runs."""
    terms = _line([200] * 3 + [20] * 3, seed=4)
    ones = _ones(terms)
    line = population(terms, ones, SPREAD, torch.zeros(3, dtype=torch.float64))
    pooled = pooled_covariance(terms, ones, SPREAD)
    assert torch.allclose(line.common_covariance, pooled, rtol=1e-12, atol=0.0)
    assert not torch.allclose(pooled, _likelihood_covariance(terms), rtol=0.05)
