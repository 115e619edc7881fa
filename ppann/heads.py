"""FusedHeads: the PPANN's six networks (ppann/model.py) in NumPy, for fast simulation (the
Monte-Carlo's NumPy path, and the tables and weights ppann/kernel.py's compiled rollout reads).
Apart from the torch model so that each stays one concept of readable length."""

from __future__ import annotations

import copy
import math

import numpy as np
import torch

from ppann.friction import coulomb_friction
from ppann.inversion import calibration_of
from ppann.lever import lever_arm
from ppann.model import OUTPUTS, PPANN, Z_NAMES, sees_angle_alone, tabulate

ANGLE_TABLE = 16384
"""Cells of FusedHeads' table of the angle-only networks over one turn."""
INERTIA_FACTOR_FLOOR = 0.1
"""Smallest 1 + z_J a Monte-Carlo draw may give (see FusedHeads.acceleration)."""


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
    snapshot of the current weights: rebuild after training; not to be shared between threads
    (`clone` one for another).
    `lever_table`: the slider force's lever_sigma x'(theta) on the same grid (ppann/lever.py).
    """

    def __init__(self, model: PPANN) -> None:
        c = model.config
        self.omega_scale, self.sigma_floor = c.omega_scale, c.sigma_floor
        self.use_networks = c.use_networks
        self.machine_prior = c.machine_terms == "prior"
        self.linear_inertia = c.white_inertia == "linear"
        self.j, self.b, self.k = (float(v) for v in model.physical.detach())
        self.coulomb = [float(v) for v in model.coulomb.detach()] if c.coulomb else None
        self.coulomb_speed = c.coulomb_speed
        self.dt = c.dt
        self.half_step = c.half_step  # the trapezoid angle update's dt^2 / 2, or 0
        self.machine_sigma = model.machine_sigma.detach().numpy().copy()
        self.common_covariance = model.common_covariance.detach().numpy().copy()
        self.machine_profile = model.machine_profile.detach().numpy().copy()
        self.spread_machines = int(model.spread_machines)  # 0: not recorded (ppann/confidence.py)
        self.calibration = calibration_of(model)  # None: the exact levels (ppann/inversion.py)
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

    def clone(self) -> FusedHeads:
        """The same networks (their arrays shared, read only) with a workspace of its own: for
        another thread (control/aware.py runs a check beside the loop's solves)."""
        twin = copy.copy(self)
        twin._workspace = {}
        return twin

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

    def advance(
        self, theta: np.ndarray, omega: np.ndarray, alpha: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """One step of the state under the acceleration alpha, as `PPANN.step`: eq. 4's forward
        Euler, the angle's by `PPANNConfig.angle_update` (dt^2 / 2 alpha more with the trapezoid,
        added only then, so Euler's numbers stay to the bit)."""
        ahead = theta + self.dt * omega
        if self.half_step:
            ahead = ahead + self.half_step * alpha
        return ahead, omega + self.dt * alpha

    def acceleration(
        self,
        theta: np.ndarray,
        omega: np.ndarray,
        tau: float | np.ndarray,
        z: np.ndarray,
        *,
        factors: np.ndarray | None = None,
        inertia_noise: np.ndarray | None = None,
    ) -> np.ndarray:
        """Eq. 14 in NumPy, as `PPANN.acceleration`, except that a sampled inertia factor
        1 + z_J is kept >= INERTIA_FACTOR_FLOOR: a drawn machine cannot have zero or negative
        inertia (a 3-sigma draw of z_J can reach -1, and the simulation then diverges).

        factors: per-sample machine factors (n, 3) multiplying the inertia, damping and stiffness
        terms (ppann/montecarlo.py, modes "machine" and "mixed"), or with `machine_terms`
        "prior" the prior's part of them (f - 1 added to 1 + z); the damping factor multiplies
        the prior's Coulomb friction in either case; None means 1.
        inertia_noise: z_J's white draw sigma_J eps, taken to first order about z's (its mean:
        `PPANNConfig.white_inertia` "linear"); None: z holds it (eq. 14's quotient).
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
        floored = np.maximum(scale[:, 0], INERTIA_FACTOR_FLOOR)
        inertia = self.j * floored
        damping = self.b * scale[:, 1] * omega
        stiffness = self.k * scale[:, 2] * angle
        if factors is not None and not self.machine_prior:
            inertia = inertia * factors[:, 0]
            damping = damping * factors[:, 1]
            stiffness = stiffness * factors[:, 2]
        alpha = (tau - damping - stiffness) / inertia
        return alpha if inertia_noise is None else alpha * (1 - inertia_noise / floored)
