"""The PPANN of paper eqs. 12-14: a linear motor prior augmented by mean and sigma networks.

State x = [theta, omega], input tau. The prior (eq. 13) is

    alpha_lin = (tau - B_m omega - K_m theta_mod) / J_m,

and the augmented acceleration (eq. 14) is

    alpha = (tau - B_m (1 + z_B) omega - K_m (1 + z_K) theta_mod) / (J_m (1 + z_J)),

with z_J(sin, cos), z_B(sin, cos, omega / omega_scale), z_K(sin, cos) (with
`PPANNConfig.coulomb` the numerator also loses the Coulomb friction of ppann/friction.py).
Each z is a normal variable whose mean comes from a network of one hidden layer (100 tanh
neurons, linear output) and whose standard deviation comes from a network of 10 tanh neurons
with a softplus output plus a floor.
Forward Euler at dt (eq. 4) with theta' = omega exactly (eq. 12); with
`PPANNConfig.angle_update` "trapezoid" the angle moves by dt (omega_k + omega_{k+1}) / 2.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from ppann.activation import Tanh
from ppann.friction import coulomb_friction
from ppann.model_config import ModelConfigError, PPANNConfig
from ppann.transmission import LEVELS as TRANSMISSION_LEVELS
from twin.geometry import PAPER, Geometry

Z_NAMES = ("J", "B", "K")
"""The three augmented terms, in the order of the last axis of every z tensor (and of the
machine-level log-factors, ppann/machine.py)."""
PROFILE_GRID = np.geomspace(1e-4, 1.0, 97)
"""machine_sigma values (log-factor standard deviations) at which the likelihood profile of
ppann/machine.py is kept in the model (`machine_profile`): 1e-4 to 1 in steps of a factor 1.1."""
RISE_GRID = np.array([0.0, 0.25, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.5, 8.0])
"""Profile rises at which ppann/inversion.py's candidate spreads sit (0: the estimate); 8 is
z^2 / 2 at z = 4."""
TAIL_GRID = np.geomspace(0.25, 0.005, 24)
"""Upper-tail probabilities at which ppann/inversion.py keeps its statistics' quantiles: (1 - c) / 3
for confidences c from 0.25 to 0.985."""


def _mlp(inputs: int, hidden: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(inputs, hidden), Tanh(), nn.Linear(hidden, 1))


def theta_mod(theta: torch.Tensor) -> torch.Tensor:
    """theta modulo 2 pi, in [0, 2 pi)."""
    return torch.remainder(theta, 2 * math.pi)


class PPANN(nn.Module):
    """Physical prior, three mean networks and three sigma networks in one module."""

    def __init__(self, config: PPANNConfig | None = None) -> None:
        super().__init__()
        self.config = config or PPANNConfig()
        self.geometry: Geometry = PAPER
        """The mechanism whose slider this model's constraints and transmission are about:
        the training data's (set by ppann/fit.py, restored by ppann/checkpoint.py)."""
        c = self.config
        # J_m, B_m, K_m = prior × factor: Adam moves a parameter by about lr per step, so the
        # factor (starting at 1) makes that step relative rather than 5e-3 kg·m² on a 3e-3 J_m.
        self.register_buffer("prior", torch.tensor([c.j_m, c.b_m, c.k_m], dtype=torch.float64))
        factor = torch.ones(3, dtype=torch.float64)
        if c.trainable_physics or not c.use_networks:
            self.physical_factor = nn.Parameter(factor)
        else:
            self.register_buffer("physical_factor", factor)
        self.mean_nets = nn.ModuleDict(
            {
                "J": _mlp(2, c.mean_hidden),
                "B": _mlp(3, c.mean_hidden),
                "K": _mlp(2 + c.mean_wrap, c.mean_hidden),
            }
        )
        angle_inputs = 3 if c.sigma_speed else 2
        self.sigma_nets = nn.ModuleDict(
            {
                "J": _mlp(angle_inputs, c.sigma_hidden),
                "B": _mlp(3, c.sigma_hidden),
                "K": _mlp(angle_inputs + c.sigma_wrap, c.sigma_hidden),
            }
        )
        # Spread of the per-machine log-factors of inertia, damping and stiffness (phase 2,
        # ppann/machine.py); zero until fitted, and then "mixed" equals "step".
        self.register_buffer("machine_sigma", torch.zeros(3, dtype=torch.float64))
        # What the training machines leave open about the line (ppann/machine.py, Population):
        # zeros until fitted, and then no allowance is made.
        self.register_buffer("common_covariance", torch.zeros((3, 3), dtype=torch.float64))
        self.register_buffer(
            "machine_profile", torch.zeros((3, len(PROFILE_GRID)), dtype=torch.float64)
        )
        # The machines phase 2 learnt that line from (ppann/confidence.py: the bounds' small-sample
        # factors); 0: not recorded (a checkpoint from before session 79: the normal z).
        self.register_buffer("spread_machines", torch.zeros((), dtype=torch.float64))
        # The laws that calibrate the line's bounds for few machines (ppann/inversion.py); zeros:
        # none (many machines, or a checkpoint from before session 81: the exact levels).
        rises, tails = len(RISE_GRID), len(TAIL_GRID)
        for name, shape in (
            ("spread_candidates", (3, rises)),
            ("spread_rise_tail", (3, rises, tails)),
            ("spread_mean_tail", (rises, 3, tails)),
        ):
            self.register_buffer(name, torch.zeros(shape, dtype=torch.float64))
        # Quantiles of the crank's angle to the motor (ppann/transmission.py); zeros: none.
        self.register_buffer(
            "transmission", torch.zeros(len(TRANSMISSION_LEVELS), dtype=torch.float64)
        )
        if c.coulomb:  # logs of C / coulomb_m, F / coulomb_load, fitted in phase 1
            self.coulomb_log = nn.Parameter(torch.zeros(2, dtype=torch.float64))
        if c.sigma_lever:  # the slider force's standard deviation, N (ppann/lever.py); 0: none
            self.register_buffer("lever_sigma", torch.zeros(1, dtype=torch.float64))
        self.double()

    @property
    def physical(self) -> torch.Tensor:
        """[J_m, B_m, K_m] in use, (3,)."""
        return self.prior * self.physical_factor

    @property
    def coulomb(self) -> torch.Tensor:
        """[C, F]: the motor's Coulomb torque (N·m) and the slider's Coulomb force (N) of
        ppann/friction.py, (2,); zeros without `PPANNConfig.coulomb`."""
        if not self.config.coulomb:
            return torch.zeros(2, dtype=torch.float64)
        c = self.config
        prior = torch.tensor([c.coulomb_m, c.coulomb_load], dtype=torch.float64)
        return prior * self.coulomb_log.exp()

    def friction(self, theta: torch.Tensor, omega: torch.Tensor) -> torch.Tensor | float:
        """The Coulomb friction torque at (theta, omega) (ppann/friction.py; 0.0 without)."""
        if not self.config.coulomb:
            return 0.0
        motor, load = self.coulomb
        return coulomb_friction(
            theta,
            omega,
            motor=motor,
            load=load,
            speed=self.config.coulomb_speed,
            geometry=self.geometry,
            lib=torch,
        )

    def _features(
        self, theta: torch.Tensor, omega: torch.Tensor, *, sigma: bool = False, wrap: bool = True
    ) -> dict[str, torch.Tensor]:
        """Each network's input: (sin, cos) or (sin, cos, omega / omega_scale); with
        `sigma_wrap` the sigma network of z_K's (sin, cos, theta_mod / 2 pi), with `mean_wrap`
        its mean network's, or with `wrap` False (sin, cos, theta / 2 pi), for tables that must
        not wrap at their ends."""
        s, c = torch.sin(theta), torch.cos(theta)
        angle = torch.stack([s, c], dim=-1)
        speed = torch.stack([s, c, omega / self.config.omega_scale], dim=-1)
        if sigma and self.config.sigma_speed:
            angle = speed
        stiffness = angle
        if self.config.sigma_wrap if sigma else self.config.mean_wrap:
            turn = (theta_mod(theta) if wrap else theta) / (2 * math.pi)
            stiffness = torch.cat([angle, turn.unsqueeze(-1)], dim=-1)
        return {"J": angle, "B": speed, "K": stiffness}

    def z_mean(
        self, theta: torch.Tensor, omega: torch.Tensor, *, wrap: bool = True
    ) -> torch.Tensor:
        """Mean network outputs, shape (..., 3) in the order J, B, K (zero without networks;
        `wrap`: `_features`)."""
        if not self.config.use_networks:
            return torch.zeros((*theta.shape, 3), dtype=theta.dtype)
        g = self._features(theta, omega, wrap=wrap)
        return torch.cat([self.mean_nets[n](g[n]) for n in Z_NAMES], dim=-1)

    def z_sigma(
        self, theta: torch.Tensor, omega: torch.Tensor, *, wrap: bool = True
    ) -> torch.Tensor:
        """Sigma network outputs, shape (..., 3), each >= sigma_floor (`wrap`: `_features`)."""
        g = self._features(theta, omega, sigma=True, wrap=wrap)
        raw = torch.cat([self.sigma_nets[n](g[n]) for n in Z_NAMES], dim=-1)
        return nn.functional.softplus(raw) + self.config.sigma_floor

    def acceleration(
        self, theta: torch.Tensor, omega: torch.Tensor, tau: torch.Tensor, z: torch.Tensor
    ) -> torch.Tensor:
        """alpha of eq. 14 for given z (..., 3); with z = 0 it is the prior of eq. 13."""
        j, b, k = self.physical
        drive = tau - self.friction(theta, omega) if self.config.coulomb else tau
        return (drive - b * (1 + z[..., 1]) * omega - k * (1 + z[..., 2]) * theta_mod(theta)) / (
            j * (1 + z[..., 0])
        )

    def step(
        self, x: torch.Tensor, tau: torch.Tensor, z: torch.Tensor | None = None
    ) -> torch.Tensor:
        """One forward-Euler step (eq. 4) of x (..., 2) under tau (...), the angle's by the
        config's `angle_update`; z defaults to the mean."""
        theta, omega = x[..., 0], x[..., 1]
        if z is None:
            z = self.z_mean(theta, omega)
        alpha = self.acceleration(theta, omega, tau, z)
        dt, half = self.config.dt, self.config.half_step
        ahead = theta + dt * omega
        if half:
            ahead = ahead + half * alpha
        return torch.stack([ahead, omega + dt * alpha], dim=-1)


def constant_ppann(
    *,
    z_mean: tuple[float, float, float] = (0.0, 0.0, 0.0),
    z_sigma: tuple[float, float, float],
    config: PPANNConfig | None = None,
) -> PPANN:
    """A PPANN whose networks output constants: z_mu = z_mean and z_sigma exactly (through the
    softplus), for tests and benches that need known dynamics and uncertainty."""
    model = PPANN(config)
    floor = model.config.sigma_floor
    if min(z_sigma) <= floor:
        raise ModelConfigError(f"z_sigma must exceed the floor {floor}, got {z_sigma}")
    with torch.no_grad():
        for i, name in enumerate(Z_NAMES):
            for net, value in (
                (model.mean_nets[name], z_mean[i]),
                (model.sigma_nets[name], math.log(math.expm1(z_sigma[i] - floor))),
            ):
                net[2].weight.zero_()
                net[2].bias.fill_(value)
    return model.eval()


OUTPUTS: tuple[tuple[str, str], ...] = tuple((k, n) for k in ("mean", "sigma") for n in Z_NAMES)
"""The six network outputs in order, (kind, z): the means of J, B, K, then their sigmas."""


def sees_angle_alone(config: PPANNConfig) -> tuple[tuple[str, str], ...]:
    """The outputs (of OUTPUTS) whose networks see the angle alone, the ones a table over one turn
    can stand for (FusedHeads, control/dynamics.py): z_J's and z_K's, except the sigmas with
    `sigma_speed`."""
    speed = {("mean", "B"), ("sigma", "B")}
    if config.sigma_speed:
        speed |= {("sigma", name) for name in Z_NAMES}
    return tuple(out for out in OUTPUTS if out not in speed)


def tabulate(model: PPANN, theta: np.ndarray) -> np.ndarray:
    """The six outputs (OUTPUTS order) at angles `theta` (n,) and omega 0, (n, 6); theta is not
    wrapped (`sigma_wrap`'s and `mean_wrap`'s feature theta / 2 pi), so a table running past
    either end of a turn continues each function there."""
    angle = torch.from_numpy(np.asarray(theta, dtype=np.float64))
    zero = torch.zeros_like(angle)
    with torch.no_grad():
        mean = model.z_mean(angle, zero, wrap=False)
        both = torch.cat([mean, model.z_sigma(angle, zero, wrap=False)], 1)
    return both.numpy()


def n_step_prediction(model: nn.Module, x0: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
    """States after 1..N mean-model steps of any model with `step(x, tau)`, from x0 (..., 2) under
    tau (..., N), all windows at once: (..., N, 2)."""
    states, x = [], x0
    for k in range(tau.shape[-1]):
        x = model.step(x, tau[..., k])
        states.append(x)
    return torch.stack(states, dim=-2)


def rollout(model: nn.Module, x0: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
    """Mean-model trajectory including x0: states (..., T + 1, 2)."""
    return torch.cat([x0.unsqueeze(-2), n_step_prediction(model, x0, tau)], dim=-2)
