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
Forward Euler at dt (eq. 4) with theta' = omega exactly (eq. 12).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from ppann.friction import coulomb_friction
from ppann.lever import lever_arm
from ppann.model_config import ModelConfigError, PPANNConfig
from ppann.transmission import LEVELS as TRANSMISSION_LEVELS
from twin.geometry import PAPER, Geometry

Z_NAMES = ("J", "B", "K")
"""The three augmented terms, in the order of the last axis of every z tensor (and of the
machine-level log-factors, ppann/machine.py)."""
PROFILE_GRID = np.geomspace(1e-4, 1.0, 97)
"""machine_sigma values (log-factor standard deviations) at which the likelihood profile of
ppann/machine.py is kept in the model (`machine_profile`): 1e-4 to 1 in steps of a factor 1.1."""
ANGLE_TABLE = 16384
"""Cells of FusedHeads' table of the angle-only networks over one turn."""
INERTIA_FACTOR_FLOOR = 0.1
"""Smallest 1 + z_J a Monte-Carlo draw may give (see FusedHeads.acceleration)."""


def _mlp(inputs: int, hidden: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(inputs, hidden), nn.Tanh(), nn.Linear(hidden, 1))


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
        """One forward-Euler step (eq. 4) of x (..., 2) under tau (...); z defaults to the mean."""
        theta, omega = x[..., 0], x[..., 1]
        if z is None:
            z = self.z_mean(theta, omega)
        alpha = self.acceleration(theta, omega, tau, z)
        dt = self.config.dt
        return torch.stack([theta + dt * omega, omega + dt * alpha], dim=-1)


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


class FusedHeads:
    """All six networks in NumPy, for fast simulation.

    The networks of the angle alone (the mean networks of z_J and z_K, and their sigma networks
    unless `sigma_speed`; with `sigma_wrap` z_K's sigma network, of theta mod 2 pi too) are a
    table over theta mod 2 pi, ANGLE_TABLE cells evaluated in float64 once, its last row the
    limit from below, interpolated linearly: within ~1e-7 of the networks on trained models
    (h² max|f''| / 8, h = 2 pi / 16384), and a few array operations per step instead of 220 of
    the 330 hidden tanh per sample (tanh is what the Monte-Carlo spends its time on: ~3 ns an
    element with NumPy's float32 tanh on an AVX2 machine, which vectorises it only with
    AVX-512; the rest is computed from exp). The networks of the speed (z_B's, and with
    `sigma_speed` the other sigma networks) are one layer pair: the features [sin, cos,
    omega / omega_scale, 1] (n, 4) times one (4, H) matrix holding their first layers and, in
    its last row, the biases, in float32 (~1e-7 absolute; tests/test_ppann.py bounds both
    paths); each network's last layer on its own columns. Each sample is one row, computed by
    the same kernel: equal states give bit-equal z. The arrays live in a workspace reused across
    calls of the same n (a fresh array per step cost more in page faults than the arithmetic). A
    snapshot of the current weights: rebuild after training; not to be shared between threads.
    `lever_table`: the slider force's lever_sigma x'(theta) on the same grid (ppann/lever.py).
    """

    def __init__(self, model: PPANN) -> None:
        c = model.config
        self.omega_scale, self.sigma_floor = c.omega_scale, c.sigma_floor
        self.use_networks = c.use_networks
        self.machine_prior = c.machine_terms == "prior"
        self.j, self.b, self.k = (float(v) for v in model.physical.detach())
        self.coulomb = [float(v) for v in model.coulomb.detach()] if c.coulomb else None
        self.coulomb_speed = c.coulomb_speed
        self.dt = c.dt
        self.machine_sigma = model.machine_sigma.detach().numpy().copy()
        self.common_covariance = model.common_covariance.detach().numpy().copy()
        self.machine_profile = model.machine_profile.detach().numpy().copy()
        self.transmission = model.transmission.detach().numpy().copy()
        self.geometry = model.geometry
        self.lever_sigma = float(getattr(model, "lever_sigma", torch.zeros(1))[0])
        nets = [model.mean_nets[n] for n in Z_NAMES] + [model.sigma_nets[n] for n in Z_NAMES]
        # outputs 0-2 the means, 3-5 the sigmas; of the angle alone (a table) or of the state
        angle_alone = sees_angle_alone(c)
        self.angle_outputs = [i for i, out in enumerate(OUTPUTS) if out in angle_alone]
        self.speed_outputs = [i for i, out in enumerate(OUTPUTS) if out not in angle_alone]
        grid = np.arange(ANGLE_TABLE + 1) * (2 * math.pi / ANGLE_TABLE)
        # row ANGLE_TABLE is 2 pi: row 0 again, or with `sigma_wrap` / `mean_wrap` the limit
        # from below
        self.table = tabulate(model, grid)[:, self.angle_outputs].copy()
        self.cell = ANGLE_TABLE / (2 * math.pi)
        self.lever_table = self.lever_sigma * lever_arm(self.geometry, grid)  # N·m per unit eps
        hidden = sum(nets[i][0].out_features for i in self.speed_outputs)
        self.w_in = np.zeros((4, hidden), dtype=np.float32)  # row 3: the biases
        self.w_out: list[np.ndarray] = []
        self.rows: list[slice] = []
        self.b_out = np.zeros((len(self.speed_outputs), 1))
        row = 0
        for j, i in enumerate(self.speed_outputs):
            first, last = nets[i][0], nets[i][2]
            width = first.out_features
            self.w_in[:3, row : row + width] = first.weight.detach().numpy().T
            self.w_in[3, row : row + width] = first.bias.detach().numpy()
            self.w_out.append(last.weight.detach().numpy()[0].astype(np.float32))
            self.rows.append(slice(row, row + width))
            self.b_out[j] = float(last.bias.detach()[0])
            row += width
        self._workspace: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    @property
    def has_lever(self) -> bool:
        """Whether the model has the slider force's channel (ppann/lever.py): the Monte-Carlo
        draws its normals and the rollout applies `lever_table`."""
        return self.lever_sigma > 0

    def __call__(self, theta: np.ndarray, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(z_mean, z_sigma), each (n, 3), for theta and omega of shape (n,); NaN rows where
        theta is not finite."""
        n = theta.shape[0]
        if n not in self._workspace:
            self._workspace[n] = (
                np.ones((n, 4), dtype=np.float32),  # column 3 stays 1: the biases' feature
                np.empty((n, self.w_in.shape[1]), dtype=np.float32),
                np.empty((len(self.speed_outputs), n), dtype=np.float32),
            )
        g, hidden, raw = self._workspace[n]
        g[:, 0], g[:, 1], g[:, 2] = np.sin(theta), np.cos(theta), omega / self.omega_scale
        np.matmul(g, self.w_in, out=hidden)
        # tanh(x) = 1 - 2 / (exp(2 x) + 1): NumPy's float32 exp is vectorised with AVX2, its
        # tanh only with AVX-512 (1.5x faster here, 2e-7 from float64 tanh; inf at large x
        # gives exactly 1, 0 at very negative x exactly -1)
        np.multiply(hidden, 2, out=hidden)
        with np.errstate(over="ignore"):
            np.exp(hidden, out=hidden)
        np.add(hidden, 1, out=hidden)
        np.divide(2, hidden, out=hidden)
        np.subtract(1, hidden, out=hidden)
        for j, (w, rows) in enumerate(zip(self.w_out, self.rows, strict=True)):
            np.matmul(hidden[:, rows], w, out=raw[j])
        out = np.empty((6, n))
        out[self.speed_outputs] = raw + self.b_out
        for i in self.speed_outputs:
            if i >= 3:  # a sigma network: softplus, floor
                out[i] = np.logaddexp(0.0, out[i]) + self.sigma_floor
        at = np.remainder(theta, 2 * math.pi) * self.cell
        finite = np.isfinite(at)
        if not finite.all():
            at = np.where(finite, at, 0.0)
        cell = np.minimum(at.astype(np.intp), ANGLE_TABLE - 1)
        frac = (at - cell)[:, None]
        angle = self.table[cell] * (1 - frac) + self.table[cell + 1] * frac  # (n, columns)
        if not finite.all():
            angle[~finite] = np.nan
        out[self.angle_outputs] = angle.T
        mean = out[:3].T if self.use_networks else np.zeros((n, 3))
        return mean, out[3:].T

    def acceleration(
        self,
        theta: np.ndarray,
        omega: np.ndarray,
        tau: float | np.ndarray,
        z: np.ndarray,
        *,
        factors: np.ndarray | None = None,
    ) -> np.ndarray:
        """Eq. 14 in NumPy, as `PPANN.acceleration`, except that a sampled inertia factor
        1 + z_J is kept >= INERTIA_FACTOR_FLOOR: a drawn machine cannot have zero or negative
        inertia (a 3-sigma draw of z_J can reach -1, and the simulation then diverges).

        factors: per-sample machine factors (n, 3) multiplying the inertia, damping and stiffness
        terms (ppann/montecarlo.py, modes "machine" and "mixed"), or with `machine_terms`
        "prior" the prior's part of them (f - 1 added to 1 + z); the damping factor multiplies
        the prior's Coulomb friction in either case; None means 1.
        """
        angle = np.remainder(theta, 2 * math.pi)
        if self.coulomb is not None:  # a machine's damping factor scales its whole friction
            friction = coulomb_friction(
                theta,
                omega,
                motor=self.coulomb[0],
                load=self.coulomb[1],
                speed=self.coulomb_speed,
                geometry=self.geometry,
                lib=np,
            )
            tau = tau - (friction if factors is None else friction * factors[:, 1])
        scale = 1 + z
        if factors is not None and self.machine_prior:
            scale = scale + factors - 1
        inertia = self.j * np.maximum(scale[:, 0], INERTIA_FACTOR_FLOOR)
        damping = self.b * scale[:, 1] * omega
        stiffness = self.k * scale[:, 2] * angle
        if factors is not None and not self.machine_prior:
            inertia = inertia * factors[:, 0]
            damping = damping * factors[:, 1]
            stiffness = stiffness * factors[:, 2]
        return (tau - damping - stiffness) / inertia
