"""Two-phase training (paper section 2.2.2), reading top to bottom.

Phase 1: the mean networks (and, if asked, J_m, B_m, K_m) minimise the N-step-ahead MSE of eq. 5
over the training windows in minibatches, with Adam (an epoch is every window, or a random
`epoch_windows` of them); the validation loss decides early stopping and the
best weights are kept. Each state's error is divided by the standard deviation of its one-step
increment in the training data, so theta (rad) and omega (rad/s) weigh alike.

Phase 2: the mean is frozen; the sigma networks minimise the propagated NLL of eq. 9 over every
training sample where the measured acceleration is valid, full batch, with Adam.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace

import numpy as np
import torch

from common.streams import rng, torch_seed
from ppann.data import (
    Windows,
    acceleration,
    check_finite_data,
    machine_split,
    split_index,
    windows,
    windows_over,
)
from ppann.inversion import CALIBRATED_MACHINES, calibrate, store_calibration
from ppann.lever import LEVER_START, lever_squared
from ppann.losses import n_step_mse, propagated_terms
from ppann.machine import (
    EpisodeTerms,
    machine_design,
    machine_sums,
    marginal_nll,
    population,
    posterior_offsets,
    white_nll,
)
from ppann.model import PPANN, n_step_prediction
from ppann.residual_mean import fit_residual_mean
from ppann.train_config import TrainConfig
from twin.dataset import Dataset, episode_machines

MACHINE_SIGMA_START = 0.05
"""Initial machine-level spread of the log-factors in phase 2."""


@dataclass
class History:
    """Loss per epoch of each phase, and where phase 1 stopped."""

    train: list[float] = field(default_factory=list)
    validation: list[float] = field(default_factory=list)
    sigma: list[float] = field(default_factory=list)
    best_epoch: int = -1
    machine_offsets: list[list[float]] = field(default_factory=list)
    """Posterior mean log-factors (J, B, K) of each training machine (an episode, or the
    episodes of one machine: twin.dataset.episode_machines), around the common offset."""
    machine_common: list[float] = field(default_factory=list)
    """Log-factor offset shared by every episode: the one-step bias of the N-step-trained mean
    model, estimated so that it is not read as machine spread (never propagated)."""
    lever_sigma: float | None = None
    """The slider force's standard deviation, N (ppann/lever.py); None: no such channel."""
    spread_data: dict[str, int] = field(default_factory=dict)
    """Phase 2's data: its `machines` and `episodes` (a machine may have played several)."""
    plan_fit: dict | None = None  # ppann/plan_fit.py's PlanFit; None: not run
    residual_mean_share: float | None = None
    """The share of phase 2's block residual power (the machines' offsets out) that the
    residual's mean took (ppann/residual_mean.py); None: not fitted (option off)."""

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Splits:
    train: Windows
    validation: Windows
    scale: torch.Tensor
    """Per-state loss scale (2,): std of one-step increments in the training split."""
    split: int
    """First sample of the validation split; phase 2 fits on the samples before it."""


def make_splits(dataset: Dataset, config: TrainConfig) -> Splits:
    """Check the data and cut it into phase 1's training windows and the windows its early
    stopping scores (`TrainConfig.early_stopping`)."""
    check_finite_data(dataset)
    split = split_index(len(dataset), config.validation_fraction)
    if config.early_stopping == "machines":
        heads, tails = machine_split(dataset, split, config.validation_fraction)
        train = windows_over(dataset, heads, horizon=config.horizon)
        validation = windows_over(dataset, tails, horizon=config.horizon)
    else:
        train = windows(dataset, start=0, stop=split, horizon=config.horizon)
        validation = windows(dataset, start=split, stop=len(dataset), horizon=config.horizon)
    increments = train.target[:, 0] - train.x0
    return Splits(train, validation, increments.std(dim=0), split)


def evaluate(model: torch.nn.Module, data: Windows, scale: torch.Tensor) -> float:
    with torch.no_grad():
        return float(n_step_mse(n_step_prediction(model, data.x0, data.tau), data.target, scale))


def train_mean(
    model: torch.nn.Module,
    splits: Splits,
    config: TrainConfig,
    *,
    history: History,
    on_epoch: Callable[[int, float, float], None] | None = None,
) -> None:
    """Phase 1, in place: N-step MSE with early stopping; the best weights are restored."""
    generator = torch.Generator().manual_seed(torch_seed(config.seed, "training") + 1)
    params = [p for p in model.parameters() if p.requires_grad]
    optimizer = torch.optim.Adam(params, lr=config.lr)
    scheduler = None
    if config.lr_decay < 1:
        scheduler = torch.optim.lr_scheduler.ReduceLROnPlateau(
            optimizer, factor=config.lr_decay, patience=config.lr_patience
        )
    best, best_state, waited = math.inf, copy.deepcopy(model.state_dict()), 0
    data = splits.train
    for epoch in range(config.max_epochs):
        order = torch.randperm(len(data), generator=generator)[: config.epoch_windows]
        total = 0.0
        for batch in order.split(config.batch_size):
            prediction = n_step_prediction(model, data.x0[batch], data.tau[batch])
            loss = n_step_mse(prediction, data.target[batch], splits.scale)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            total += float(loss.detach()) * len(batch)
        validation = evaluate(model, splits.validation, splits.scale)
        if scheduler is not None:
            scheduler.step(validation)
        history.train.append(total / len(order))
        history.validation.append(validation)
        if on_epoch is not None:
            on_epoch(epoch, history.train[-1], validation)
        if validation < best:
            best, best_state, waited = validation, copy.deepcopy(model.state_dict()), 0
            history.best_epoch = epoch
        else:
            waited += 1
            if waited >= config.patience:
                break
    model.load_state_dict(best_state)


def sigma_data(dataset: Dataset, stop: int) -> tuple[torch.Tensor, ...]:
    """(theta, omega, tau, alpha, episode, machine) of the samples before `stop` with a valid
    acceleration; episode and machine (twin.dataset.episode_machines: the episodes of one
    machine share it) are renumbered 0..E-1 and 0..M-1 over those present."""
    alpha, valid = acceleration(dataset)
    valid[stop:] = False
    idx = np.flatnonzero(valid)
    renumbered = (
        np.unique(values[idx], return_inverse=True)[1].reshape(-1)
        for values in (dataset.episode, episode_machines(dataset))
    )
    return (
        *(
            torch.from_numpy(np.ascontiguousarray(v[idx]))
            for v in (dataset.theta, dataset.omega, dataset.tau, alpha)
        ),
        *(torch.from_numpy(v.astype(np.int64)) for v in renumbered),
    )


@dataclass(frozen=True)
class SpreadSamples:
    """Phase 2's samples at the frozen mean model (`spread_samples`): per sample the state,
    torque, machine, torque residual and design D_k; their blocks (ppann/machine.py)."""

    theta: torch.Tensor
    omega: torch.Tensor
    tau: torch.Tensor
    machine: torch.Tensor
    residual: torch.Tensor
    design: torch.Tensor
    terms: EpisodeTerms
    """The blocks, the residual summed into them; its `n_machines` the machines."""
    episodes: int

    def blocks(self, residual: torch.Tensor) -> EpisodeTerms:
        """The same blocks with another per-sample residual (n,) summed into them."""
        summed = torch.zeros_like(self.terms.residual).index_add(0, self.terms.block, residual)
        return replace(self.terms, residual=summed)


def spread_samples(model: PPANN, dataset: Dataset, stop: int, config: TrainConfig) -> SpreadSamples:
    """What phase 2 fits on: the samples before `stop` with a valid acceleration (`sigma_data`)
    at the frozen mean model, in blocks of `config.sigma_block` (a machine's episodes share its
    offset)."""
    theta, omega, tau, alpha, episode, machine = sigma_data(dataset, stop)
    with torch.no_grad():
        residual, derivative = propagated_terms(model, theta, omega, tau, alpha)
        design = machine_design(model, theta, omega, derivative)
    lever = lever_squared(model.geometry, theta) if model.config.sigma_lever else None
    terms = EpisodeTerms.build(
        residual,
        derivative,
        design,
        episode,
        machine=machine,
        block_length=config.sigma_block,
        lever=lever,
    )
    episodes = int(episode.max()) + 1
    return SpreadSamples(theta, omega, tau, machine, residual, design, terms, episodes)


def train_sigma(
    model: PPANN,
    dataset: Dataset,
    splits: Splits,
    config: TrainConfig,
    *,
    history: History,
    on_epoch: Callable[[int, float], None] | None = None,
    on_bounds: Callable[[int, float], None] | None = None,
) -> None:
    """Phase 2, in place, then the line's bounds calibrated (`on_bounds`: their Adam epochs,
    ppann/inversion.py); everything but the sigma networks (and machine_sigma) is frozen.

    With `config.machine_model` the sigma networks and the machine-level spread are fitted jointly
    by the marginal likelihood of ppann/machine.py (a machine's episodes share its offset); without
    it, by eq. 9 alone and machine_sigma stays zero. A model with the slider force's channel
    (`PPANNConfig.sigma_lever`) fits its lever_sigma with them, at the machine spread's rate.
    With `config.residual_mean` a second pass follows from the same initial weights, with the
    residual's mean given the sample's state and torque (fitted with the first pass's machine
    offsets out) taken out of the residual (ppann/residual_mean.py).
    """
    data = spread_samples(model, dataset, splits.split, config)
    history.spread_data = {"machines": data.terms.n_machines, "episodes": data.episodes}
    terms, theta, omega = data.terms, data.theta, data.omega
    initial = copy.deepcopy(model.sigma_nets.state_dict())
    _fit_spread(model, terms, theta, omega, config, history=history, on_epoch=on_epoch)
    if config.residual_mean:
        model.sigma_nets.load_state_dict(initial)
        terms = _second_pass(model, data, config, history=history, on_epoch=on_epoch)
    _calibrate(model, terms, theta, omega, config, history=history, on_epoch=on_bounds)


def _second_pass(
    model: PPANN,
    data: SpreadSamples,
    config: TrainConfig,
    *,
    history: History,
    on_epoch: Callable[[int, float], None] | None,
) -> EpisodeTerms:
    """`train_sigma`'s second pass (its docstring), the sigma networks back at their start: the
    blocks it fitted."""
    terms, theta, omega = data.terms, data.theta, data.omega
    # The mean model's own one-step error is not noise: its mean is fitted on the residual with
    # the machines' offsets of the first pass taken out, and the spread fitted again around it.
    design = data.design
    shift = torch.zeros_like(design)  # each sample's machine offset (none without the model)
    if history.machine_offsets:
        shift = (
            torch.tensor(history.machine_common, dtype=design.dtype)
            + torch.tensor(history.machine_offsets, dtype=design.dtype)[data.machine]
        )
    own = data.residual + (design * shift).sum(-1)
    fitted = fit_residual_mean(own, theta=theta, omega=omega, tau=data.tau, block=terms.block)
    history.sigma.clear()
    history.residual_mean_share = fitted.share
    second = None if on_epoch is None else (lambda e, loss: on_epoch(config.sigma_epochs + e, loss))
    terms = data.blocks(data.residual - fitted.mean)
    _fit_spread(model, terms, theta, omega, config, history=history, on_epoch=second)
    return terms


def _calibrate(
    model: PPANN,
    terms: EpisodeTerms,
    theta: torch.Tensor,
    omega: torch.Tensor,
    config: TrainConfig,
    *,
    history: History,
    on_epoch: Callable[[int, float], None] | None,
) -> None:
    """The line's bounds calibrated by simulation (ppann/inversion.py) for a line of 2 to
    CALIBRATED_MACHINES machines, from the machines' information in phase 2's last blocks."""
    few = 2 <= terms.n_machines <= CALIBRATED_MACHINES
    if not config.machine_model or not config.bound_lines or not few:
        return
    with torch.no_grad():
        force = model.lever_sigma if terms.lever is not None else None
        variance = terms.white_variance(model.z_sigma(theta, omega), force)
        info, _ = machine_sums(
            terms.residual, terms.design, variance, terms.machine, terms.n_machines
        )
    found = calibrate(
        info,
        model.machine_sigma.detach(),
        torch.tensor(history.machine_common, dtype=torch.float64),
        model.machine_profile.numpy(),
        epochs=config.sigma_epochs,
        lr=config.machine_lr,
        start=MACHINE_SIGMA_START,
        rng=rng(config.seed, "spread_calibration"),
        lines=config.bound_lines,
        on_epoch=on_epoch,
    )
    store_calibration(model, found)


@dataclass
class SpreadFit:
    """Phase 2's parameters beside the sigma networks, from their start: the slider force's
    log sigma (a model with the channel), the machine spread's log sigmas and the line's
    common offset (with `TrainConfig.machine_model`), and one Adam over all of them."""

    log_force: torch.Tensor | None
    log_machine: torch.Tensor | None
    common: torch.Tensor | None
    optimizer: torch.optim.Optimizer

    @classmethod
    def start(cls, model: PPANN, terms: EpisodeTerms, config: TrainConfig) -> SpreadFit:
        groups: list[dict] = [
            {"params": list(model.sigma_nets.parameters()), "lr": config.sigma_lr}
        ]
        log_force = None
        if terms.lever is not None:
            log_force = torch.tensor([math.log(LEVER_START)], dtype=torch.float64)
            log_force.requires_grad_(True)
            groups.append({"params": [log_force], "lr": config.machine_lr})
        log_machine = common = None
        if config.machine_model:
            log_machine = torch.full((3,), math.log(MACHINE_SIGMA_START), dtype=torch.float64)
            common = torch.zeros(3, dtype=torch.float64)
            for tensor in (log_machine, common):
                tensor.requires_grad_(True)
            groups.append({"params": [log_machine, common], "lr": config.machine_lr})
        return cls(log_force, log_machine, common, torch.optim.Adam(groups))

    def step(
        self, model: PPANN, terms: EpisodeTerms, theta: torch.Tensor, omega: torch.Tensor
    ) -> float:
        """One epoch (full batch): the loss before the step."""
        sigma = model.z_sigma(theta, omega)
        force = None if self.log_force is None else self.log_force.exp()
        if self.log_machine is None:
            loss = white_nll(terms, sigma, force)
        else:
            loss = marginal_nll(terms.shifted(self.common), sigma, self.log_machine.exp(), force)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        return float(loss.detach())


def _fit_spread(
    model: PPANN,
    terms: EpisodeTerms,
    theta: torch.Tensor,
    omega: torch.Tensor,
    config: TrainConfig,
    *,
    history: History,
    on_epoch: Callable[[int, float], None] | None,
) -> None:
    """One fit of phase 2 on `terms` from the sigma networks' present weights, the machine
    spread's and the slider force's start: the model's spread, offsets and population."""
    fit = SpreadFit.start(model, terms, config)
    log_force, log_machine, common = fit.log_force, fit.log_machine, fit.common
    for epoch in range(config.sigma_epochs):
        history.sigma.append(fit.step(model, terms, theta, omega))
        if on_epoch is not None:
            on_epoch(epoch, history.sigma[-1])
    force = None
    if log_force is not None:
        with torch.no_grad():
            model.lever_sigma.copy_(log_force.exp())
        force = model.lever_sigma
        history.lever_sigma = float(force[0])
    if log_machine is not None:
        with torch.no_grad():
            model.machine_sigma.copy_(log_machine.exp())
            sigma = model.z_sigma(theta, omega)
            offsets = posterior_offsets(terms.shifted(common), sigma, model.machine_sigma, force)
        line = population(terms, sigma, model.machine_sigma, common, force)
        with torch.no_grad():
            model.common_covariance.copy_(line.common_covariance)
            model.machine_profile.copy_(line.profile)
            model.spread_machines.fill_(history.spread_data["machines"])
        history.machine_offsets = offsets.tolist()
        history.machine_common = common.detach().tolist()
