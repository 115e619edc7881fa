"""The trained PPANN written out as CasADi SX expressions (no torch callback in an OCP).

`CasadiPPANN(model)` reads the weights once and builds:
  z_mean(theta, omega) -> (3,)   the mean networks, J, B, K
  z_sigma(theta, omega) -> (3,)  the sigma networks (softplus + floor)
  step(x, tau) -> x_next          forward Euler of eq. 14 with the mean z (eq. 10b), the angle
                                  by PPANNConfig.angle_update
  step_on_turn(x, tau, turn) -> x_next
                                  the same with theta_mod = theta - 2 pi turn, a given turn
as `casadi.Function`s, equal to the torch model to 1e-9 (tests/test_control_dynamics.py).

theta_mod is theta - 2 pi floor(theta / 2 pi), as in torch (`torch.remainder`); it is
discontinuous at multiples of 2 pi. `step_on_turn` is smooth in x: an OCP fixes each sample's turn
floor(theta / 2 pi) and checks it after the solve (control/ocp.py), where it equals `step`.

The networks of the angle alone (the mean z_J and z_K, and the sigma z_J and z_K unless the
sigma networks see the speed) are, by default, cubic B-splines of the torch model's own outputs
on ANGLE_KNOTS points per turn (`angle_splines`), evaluated at theta mod 2 pi: equal to the
networks to ~1e-13 and the step's Jacobian to ~1e-11 (tests/test_control_dynamics.py), and a lookup
instead of a tanh layer in every function IPOPT calls. The nominal solve of the seed-0 model took
176 ms with the networks and 136 ms with the splines in CasADi's virtual machine, 82 and 45 ms
compiled (build 3.5 and 1.5 s, compiled 6.9 and 2.4 s), same iterations and torques to 6e-12
(idle, median of 5; docs/benchmarks.md).
`splines=False` keeps the networks: the reference the splines are tested against.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
from torch import nn

from ppann.friction import coulomb_friction
from ppann.model import OUTPUTS, PPANN, Z_NAMES, sees_angle_alone, tabulate

ANGLE_KNOTS = 4096
"""Spline points per turn of the angle-only networks (64 miss the step's Jacobian by ~1e-6)."""
ANGLE_PAD = 8
"""Points beyond each end of the turn, so that the spline's end conditions fall outside it."""


def mlp(net: nn.Sequential, features: ca.SX) -> ca.SX:
    """A Linear-tanh-Linear network as an SX expression of its input column."""
    first, last = net[0], net[2]
    w1, b1 = (ca.DM(t.detach().numpy()) for t in (first.weight, first.bias))
    w2, b2 = (ca.DM(t.detach().numpy()) for t in (last.weight, last.bias))
    return ca.mtimes(w2, ca.tanh(ca.mtimes(w1, features) + b1)) + b2


def softplus(x: ca.SX) -> ca.SX:
    """log(1 + exp(x)), written to stay finite for large x."""
    return ca.fmax(x, 0) + ca.log1p(ca.exp(-ca.fabs(x)))


def angle_splines(model: PPANN) -> dict[str, ca.Function]:
    """Cubic B-splines of the networks that see only the angle, keyed "mean J", "sigma K", ...,
    each a function of theta in [0, 2 pi) tabulated from the torch model itself."""
    grid = np.arange(-ANGLE_PAD, ANGLE_KNOTS + ANGLE_PAD + 1) * (2 * math.pi / ANGLE_KNOTS)
    values = tabulate(model, grid)  # unwrapped: the pads continue each function
    return {
        f"{kind} {name}": ca.interpolant(
            f"{kind}_{name}", "bspline", [grid], values[:, OUTPUTS.index((kind, name))]
        )
        for kind, name in sees_angle_alone(model.config)
        if kind == "sigma" or model.config.use_networks  # without networks the mean is 0
    }


class CasadiPPANN:
    """SX functions of a trained PPANN's mean, sigma and one-step dynamics; `splines` replaces
    the networks of the angle alone by their B-splines (module docstring)."""

    def __init__(self, model: PPANN, *, splines: bool = True) -> None:
        c = model.config
        self.dt = c.dt
        j, b, k = (float(v) for v in model.physical.detach())
        theta, omega, tau = ca.SX.sym("theta"), ca.SX.sym("omega"), ca.SX.sym("tau")
        s, co = ca.sin(theta), ca.cos(theta)
        features = {
            "J": ca.vertcat(s, co),
            "B": ca.vertcat(s, co, omega / c.omega_scale),
            "K": ca.vertcat(s, co),
        }
        wrapped = theta - 2 * math.pi * ca.floor(theta / (2 * math.pi))
        turn = ca.SX.sym("turn")
        tables = angle_splines(model) if splines else {}

        def mean_at(angle: ca.SX, *, on_turn: bool = False) -> ca.SX:
            """The mean networks, the angle tables at the wrapped theta; with `mean_wrap` z_K
            sees `angle` / 2 pi (theta_mod, or theta on a given turn). On a turn z_K is its
            network, not its table: the OCP's iterates may leave the turn, where a B-spline
            is 0 beyond its pads and the network goes on smoothly."""
            if not c.use_networks:
                return ca.SX.zeros(3)
            own = dict(features)
            if c.mean_wrap:
                own["K"] = ca.vertcat(s, co, angle / (2 * math.pi))
            return ca.vertcat(
                *(
                    tables[f"mean {n}"](wrapped)
                    if f"mean {n}" in tables and not (on_turn and n == "K")
                    else mlp(model.mean_nets[n], own[n])
                    for n in Z_NAMES
                )
            )

        mean = mean_at(wrapped)
        # on a given turn z_K sees theta there: with `mean_wrap` it jumps where theta_mod does,
        # and a step on a fixed turn must not see the one without the other
        mean_turn = mean_at(theta - 2 * math.pi * turn, on_turn=True) if c.mean_wrap else mean
        sigma_features = {n: features["B"] for n in Z_NAMES} if c.sigma_speed else dict(features)
        if c.sigma_wrap:
            sigma_features["K"] = ca.vertcat(s, co, wrapped / (2 * math.pi))
        sigma = ca.vertcat(
            *(
                tables[f"sigma {n}"](wrapped)
                if f"sigma {n}" in tables
                else softplus(mlp(model.sigma_nets[n], sigma_features[n])) + c.sigma_floor
                for n in Z_NAMES
            )
        )
        drive = tau
        if c.coulomb:  # the prior's Coulomb friction (ppann/friction.py)
            motor, load = (float(v) for v in model.coulomb.detach())
            drive = tau - coulomb_friction(
                theta,
                omega,
                motor=motor,
                load=load,
                speed=c.coulomb_speed,
                geometry=model.geometry,
                lib=ca,
            )

        def alpha_at(angle: ca.SX, z: ca.SX) -> ca.SX:
            return (drive - b * (1 + z[1]) * omega - k * (1 + z[2]) * angle) / (j * (1 + z[0]))

        alpha = alpha_at(wrapped, mean)
        alpha_turn = alpha_at(theta - 2 * math.pi * turn, mean_turn)
        half = c.half_step  # the trapezoid angle update's dt^2 / 2 (PPANNConfig.angle_update)

        def ahead(acceleration: ca.SX) -> ca.SX:
            moved = theta + self.dt * omega
            return moved + half * acceleration if half else moved

        x = ca.vertcat(theta, omega)
        self._rollouts: dict[int, ca.Function] = {}
        self.z_mean = ca.Function("z_mean", [theta, omega], [mean], ["theta", "omega"], ["z"])
        self.z_sigma = ca.Function("z_sigma", [theta, omega], [sigma], ["theta", "omega"], ["s"])
        self.acceleration = ca.Function("alpha", [x, tau], [alpha], ["x", "tau"], ["alpha"])
        self.step = ca.Function(
            "step",
            [x, tau],
            [ca.vertcat(ahead(alpha), omega + self.dt * alpha)],
            ["x", "tau"],
            ["x_next"],
        )
        self.step_on_turn = ca.Function(
            "step_on_turn",
            [x, tau, turn],
            [ca.vertcat(ahead(alpha_turn), omega + self.dt * alpha_turn)],
            ["x", "tau", "turn"],
            ["x_next"],
        )

    def rollout(self, x0: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Mean trajectory (T + 1, 2) by `step` T times (theta wrapped at every step), in one
        call of its `mapaccum` (built once per T: 2 ms for T = 199 against 13 ms step by step,
        the same numbers to the bit)."""
        steps = len(tau)
        if steps not in self._rollouts:
            self._rollouts[steps] = self.step.mapaccum("rollout", steps)
        x0 = np.asarray(x0, dtype=float)
        if steps == 0:
            return x0[None, :].copy()
        states = self._rollouts[steps](x0, np.asarray(tau, dtype=float)[None, :]).full()
        return np.vstack([x0, states.T])
