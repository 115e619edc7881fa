"""Feedback from the model: time-varying LQR gains along a plan, from the PPANN's linearisation.

The closed loop the twin plays (and the closed-loop Monte-Carlo of the feedback-aware robust OCP)
applies, before sample k, u_k = clip(u_plan_k - K_k (x_k - x_plan_k), +-torque_limit), x = (theta,
omega) measured at t_k. K_k comes from the linearisation of the mean model's one-step map along
the plan, x_{k+1} ~ A_k x_k + B_k u_k (CasADi Jacobians of `step_on_turn` on the plan's turns, so
smooth), and the finite-horizon Riccati recursion of

    sum_k (dx_k^T Q dx_k + r du_k^2) + dx_N^T Q dx_N,   Q = diag(q_theta, q_omega):

    P_N = Q,  K_k = (r + B_k^T P_{k+1} B_k)^-1 B_k^T P_{k+1} A_k,
    P_k = Q + A_k^T P_{k+1} (A_k - B_k K_k).

Weights by Bryson's rule: q = 1 / (largest acceptable deviation)^2 (`OCPConfig.feedback_theta`,
`feedback_omega`, `feedback_torque`). The defaults accept 20 mrad of crank angle (~1 mm of slider
at mid-stroke, the scale of the robust margins' precision), 1 rad/s and 1 N·m. Along the seed-0
robust plan that gives Kp 25-40 N·m/rad and Kd 0.6-0.9 N·m·s/rad, the order of the fixed PD the
replay used before (20 and 0.5); 5 mrad gave 105-139, which the 10 N·m actuator would saturate
on deviations of 0.1 rad. They are options, not tuned to any figure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from control.config import OCPConfig


@dataclass(frozen=True)
class LQRWeights:
    """Weights of the tracking LQR (module docstring), from the acceptable deviations."""

    q_theta: float
    q_omega: float
    r: float

    @classmethod
    def from_config(cls, config: OCPConfig) -> LQRWeights:
        return cls(
            q_theta=config.feedback_theta**-2,
            q_omega=config.feedback_omega**-2,
            r=config.feedback_torque**-2,
        )


def linearise(
    step_on_turn: ca.Function, states: np.ndarray, tau: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """A_k (N-1, 2, 2) and B_k (N-1, 2) of the one-step map at the plan's states x_1..x_{N-1}
    (N, 2) and torques u_1..u_{N-1}, each on its own turn floor(theta_k / 2 pi)."""
    x, u, turn = ca.SX.sym("x", 2), ca.SX.sym("u"), ca.SX.sym("turn")
    nxt = step_on_turn(x, u, turn)
    jac = ca.Function("step_jacobians", [x, u, turn], [ca.jacobian(nxt, x), ca.jacobian(nxt, u)])
    steps = states.shape[0] - 1
    batch = jac.map(steps)
    turns = np.floor(states[:-1, 0] / (2 * math.pi))
    a, b = batch(states[:-1].T, tau[:steps][None, :], turns[None, :])
    a = np.asarray(a.full()).reshape(2, steps, 2).transpose(1, 0, 2)  # (steps, 2, 2)
    return a, np.asarray(b.full()).T  # (steps, 2)


def riccati(a: np.ndarray, b: np.ndarray, weights: LQRWeights) -> tuple[np.ndarray, np.ndarray]:
    """K_k (T, 2) and the cost-to-go P_k (T + 1, 2, 2), P_T = Q, of the finite-horizon recursion
    (module docstring) for A (T, 2, 2), B (T, 2). The MPC (control/mpc.py) ends its horizon on
    P, so that without active bounds it is this LQR on a linear system."""
    q = np.diag([weights.q_theta, weights.q_omega])
    costs = np.empty((a.shape[0] + 1, 2, 2))
    costs[-1] = p = q.copy()
    gains = np.empty((a.shape[0], 2))
    for k in range(a.shape[0] - 1, -1, -1):
        ak, bk = a[k], b[k]
        pb = p @ bk
        gains[k] = (pb @ ak) / (weights.r + bk @ pb)
        p = q + ak.T @ p @ (ak - np.outer(bk, gains[k]))
        costs[k] = p = 0.5 * (p + p.T)
    return gains, costs


def riccati_gains(a: np.ndarray, b: np.ndarray, weights: LQRWeights) -> np.ndarray:
    """K_k (T, 2) of the finite-horizon recursion (module docstring) for A (T, 2, 2), B (T, 2)."""
    return riccati(a, b, weights)[0]


def tracking_gains(
    step_on_turn: ca.Function, states: np.ndarray, tau: np.ndarray, weights: LQRWeights
) -> np.ndarray:
    """K_k (N-1, 2) along a plan: the gain applied before sample k = 1..N-1."""
    a, b = linearise(step_on_turn, states, tau)
    return riccati_gains(a, b, weights)
