"""Online MPC on the PPANN mean: one real-time iteration per 2 ms sample (beyond the paper).

At every sample k the controller sees the measured state x_k (encoder angle and speed) and
solves, over the next H samples, the tracking problem of the profile it follows,

    min  sum_{j=1..H-1} dx_{k+j}^T Q dx_{k+j} + dx_{k+H}^T P_{k+H} dx_{k+H}
           + r sum_{j=0..H-1} du_{k+j}^2
    s.t. x_{k+j+1} = f(x_{k+j}, u_{k+j}),  |u| <= torque limit,

dx, du the deviations from the plan, f the PPANN mean's one-step map (control/dynamics.py, with
its own 2 pi wrap: the derivative of the floor is zero, so the Jacobians are those of the turn the
state is on), P_k the Riccati cost-to-go of the same weights along the plan (control/lqr.py): with
no bound active, on a linear system, this is the TV-LQR law exactly, for any H.

Solver: a real-time iteration (SQP-RTI, Gauss-Newton, Diehl et al. 2005). From the measured
state, the previous solution shifted by one sample is rolled out through f; one CasADi function
returns the predicted states and their sensitivities to the H torques (the condensed QP's
matrices, computed from the per-step Jacobians), compiled to C once per model and horizon in a
process (1-2 s; 3-4x faster than CasADi's virtual machine, which is the fallback without a C
compiler; the MPCs of one model's profiles share it: `shared_prediction`); the box QP
(control/boxqp.py) gives the new torques, of which the first is applied. One iteration per
sample, warm-started: the Newton iterations of a plain SQP are spread over the samples.

With a `SliderLimit` (`--mpc-slider-limit`) the QP also holds slider(θ + δ) >= height at the
OCP's constraint samples within the horizon, linearised about the prediction, δ the crank's
angle to the motor at its unsafe-side quantile (the model's transmission error); the QP is then
solved through its dual on those few rows (`solve_with_limits`).

Near the end of the plan the horizon shrinks: states past the plan's last sample are not
weighed and torques past its last control are not free. A step whose compute time exceeds the
deadline (one sample) is counted as a miss, and the shifted previous solution is applied instead
of the late one, as a real-time controller would have to.
"""

from __future__ import annotations

import hashlib
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass

import casadi as ca
import numpy as np

from control.boxqp import solve_box_qp, solve_with_limits
from control.compiled import Workshop
from control.lqr import LQRWeights, riccati
from control.mpc_config import MPCConfig, MPCConfigError, check_fits
from twin.geometry import Geometry


def step_sensitivities(step: ca.Function) -> ca.Function:
    """(x (2,), u) -> (x_next, A = d x_next / dx (2, 2), B = d x_next / du (2, 1)) of `step`."""
    xs, us = ca.SX.sym("x", 2), ca.SX.sym("u")
    nxt = step(xs, us)
    return ca.Function(
        "step_sensitivities", [xs, us], [nxt, ca.jacobian(nxt, xs), ca.jacobian(nxt, us)]
    )


def prediction_function(
    step: ca.Function, horizon: int, *, workshop: Workshop | None = None
) -> tuple[ca.Function, str]:
    """(x0 (2,), u (H,)) -> (x (2, H) the states after each torque, g (2H, H) d vec(x) / du)
    from the one-step map `step(x, u) -> x_next`, and the engine that evaluates it: "compiled"
    (CasADi's C code generation, built with the system's C compiler in `workshop`'s folder,
    which must live as long as the function) or "vm" (CasADi's SX virtual machine: without a
    workshop, or without a compiler). The same numbers either way (tests/test_mpc.py)."""
    jac = step_sensitivities(step)
    x0, u = ca.MX.sym("x0", 2), ca.MX.sym("u", horizon)
    x, states, blocks = x0, [], []  # blocks[i] = d x_{i+1} / du as a (2, H) row block
    for j in range(horizon):
        x, a, b = jac(x, u[j])
        unit = ca.DM.zeros(1, horizon)
        unit[j] = 1.0
        block = ca.mtimes(b, unit)
        if blocks:
            block = block + ca.mtimes(a, blocks[-1])
        states.append(x)
        blocks.append(block)
    outputs = [ca.horzcat(*states), ca.vertcat(*blocks)]
    if workshop is not None:
        try:
            with workshop.building():
                options = workshop.options(flags=("-O2",))
                fn = ca.Function("mpc_prediction", [x0, u], outputs, options)
                fn(np.zeros(2), np.zeros(horizon))  # loaded while inside the folder
            return fn, "compiled"
        except RuntimeError:  # no C compiler here: the virtual machine
            pass
    return ca.Function("mpc_prediction", [x0, u], outputs).expand(), "vm"


PREDICTIONS_KEPT = 4
"""Prediction functions `shared_prediction` keeps in a process (the oldest is dropped): a
campaign, a held-out check or a compare plays every profile of one model, one or two horizons."""

_kept: OrderedDict[tuple[str, int, bool], tuple[ca.Function, str, Workshop | None]] = OrderedDict()
_kept_lock = threading.Lock()


def shared_prediction(
    step: ca.Function, horizon: int, *, compiled: bool
) -> tuple[ca.Function, str, Workshop | None]:
    """`prediction_function` of `step`, built once in this process for every step of the same
    content (CasADi's serialisation of it: the same weights, tables, time step and geometry),
    horizon and engine asked for; with the workshop that holds its compiled code, which lives
    as long as the function is kept or used. The MPCs of one model's profiles (1-2 s each to
    build, most of it the C compile) then share one function; it is pure (its inputs give its
    outputs), so sharing it changes no number (tests/test_mpc.py)."""
    key = (hashlib.sha256(step.serialize().encode()).hexdigest(), horizon, compiled)
    with _kept_lock:
        if key not in _kept:
            workshop = Workshop() if compiled else None
            function, engine = prediction_function(step, horizon, workshop=workshop)
            _kept[key] = (function, engine, workshop if engine == "compiled" else None)
            while len(_kept) > PREDICTIONS_KEPT:
                _kept.popitem(last=False)
        _kept.move_to_end(key)
        return _kept[key]


@dataclass(frozen=True)
class SliderLimit:
    """slider(θ + δ) >= height at the plan's constraint samples, held in the MPC's QP
    (linearised about the prediction) while those samples are within the horizon. δ is the
    crank's angle to the motor (ppann/transmission.py) at its quantile on the unsafe side:
    `delta_low` where the slider rises with θ, `delta_high` where it falls (both 0: the motor
    angle itself)."""

    geometry: Geometry
    height: float
    samples: tuple[int, ...]
    """0-based state indices (the OCP's 1-based constraint samples minus 1)."""
    delta_low: float = 0.0
    delta_high: float = 0.0


@dataclass(frozen=True)
class Step:
    """What one MPC step did."""

    torque: float
    """The torque applied from t_k to t_{k+1}, N·m."""
    seconds: float
    """Compute time of the step."""
    missed: bool
    """The step took longer than the deadline; the shifted previous solution was applied."""
    qp_iterations: int
    """Active-set steps of the box QP; with a binding slider limit, the box QPs solved."""


class TrackingMPC:
    """The MPC of one plan. `start()` gives a warm start; `step(k, x, guess)` one RTI step."""

    def __init__(
        self,
        step: ca.Function,
        *,
        states: np.ndarray,
        tau: np.ndarray,
        torque_limit: float,
        config: MPCConfig,
        slider: SliderLimit | None = None,
    ) -> None:
        """Args:
        step: the model's one-step map (x (2,), u) -> x_next.
        states: the plan's states x_0..x_{N-1} (N, 2) (0-based samples).
        tau: the plan's torques (N,); u_k acts from t_k to t_{k+1}, u_{N-1} is not used.
        slider: the slider's lower limit to hold in the QP (None: tracking only).
        """
        self.slider = slider
        n = states.shape[0]
        check_fits(config, n)
        self.config = config
        self.states = np.asarray(states, dtype=float)
        self.tau = np.asarray(tau, dtype=float)
        self.limit = float(torque_limit)
        self.n = n
        h = config.horizon
        self.predict, self.engine, self.workshop = shared_prediction(
            step, h, compiled=config.compiled
        )
        _, a, b = (
            np.asarray(m)
            for m in jacobians(step, self.states[:-1], self.tau[: n - 1])  # (N-1, ...)
        )
        weights = LQRWeights(q_theta=config.q_theta, q_omega=config.q_omega, r=config.r)
        # K_0..K_{N-2} and P_0..P_{N-1}: the TV-LQR of the same weights along the plan, which the
        # MPC is while no bound is active (exactly on a linear system; module docstring)
        self.gains, self.costs = riccati(a, b, weights)
        self.q = np.array([config.q_theta, config.q_omega])

    def start(self) -> np.ndarray:
        """The first warm start: the plan's torques over the horizon."""
        return self._plan_torques(0)

    def _plan_torques(self, k: int) -> np.ndarray:
        idx = np.minimum(np.arange(k, k + self.config.horizon), self.n - 2)
        return self.tau[idx].copy()

    def step(self, k: int, x: np.ndarray, guess: np.ndarray) -> tuple[Step, np.ndarray]:
        """One RTI step at 0-based sample k from the measured state x (2,) and the warm start
        `guess` (H,); returns the step and the next sample's warm start."""
        started = time.perf_counter()
        h = self.config.horizon
        free = min(h, self.n - 1 - k)  # torques u_k..u_{k+free-1} reach a state of the plan
        if free <= 0:
            return Step(float(self.tau[min(k, self.n - 1)]), 0.0, False, 0), guess
        xs, g = self.predict(x, guess)
        xs = np.asarray(xs).T[:free].reshape(-1)  # x_{k+1}..x_{k+free}, (2 free,)
        g = np.asarray(g)[: 2 * free, :free]
        ref = self.states[k + 1 : k + 1 + free].reshape(-1)
        w = np.tile(self.q, free)
        wg = w[:, None] * g
        wg[-2:] = self.costs[k + free] @ g[-2:]
        err = xs - ref
        werr = w * err
        werr[-2:] = self.costs[k + free] @ err[-2:]
        u = guess[:free]
        du_plan = u - self.tau[k : k + free]
        hess = g.T @ wg + self.config.r * np.eye(free)
        grad = g.T @ werr + self.config.r * du_plan
        lo, hi = -self.limit - u, self.limit - u
        rows, rhs = self._slider_rows(k, free, xs, g)
        if rows is None:
            delta, iterations = solve_box_qp(hess, grad, lo, hi)
        else:
            delta, iterations = solve_with_limits(hess, grad, lo, hi, rows, rhs)
        solution = guess.copy()
        solution[:free] = u + delta
        seconds = time.perf_counter() - started
        missed = seconds > self.config.deadline
        applied = solution if not missed else guess
        nxt = np.empty_like(guess)
        nxt[:-1] = applied[1:]
        nxt[-1] = self.tau[min(k + h, self.n - 2)]
        return Step(float(applied[0]), seconds, missed, iterations), nxt

    def _slider_rows(
        self, k: int, free: int, xs: np.ndarray, g: np.ndarray
    ) -> tuple[np.ndarray | None, np.ndarray]:
        """The slider limits within the horizon as rows @ delta >= rhs, linearised about the
        prediction xs (2 free,) with sensitivities g (2 free, free); (None, _) if none."""
        if self.slider is None:
            return None, np.empty(0)
        limit = self.slider
        inside = [c - k - 1 for c in limit.samples if k < c <= k + free]
        if not inside:
            return None, np.empty(0)
        theta = xs[0::2][inside]
        eps = 1e-6
        position = limit.geometry.slider_position
        rising = position(theta + eps) >= position(theta - eps)
        theta = theta + np.where(rising, limit.delta_low, limit.delta_high)
        slope = (position(theta + eps) - position(theta - eps)) / (2 * eps)
        rows = slope[:, None] * g[[2 * j for j in inside]]
        rhs = limit.height - limit.geometry.slider_position(theta)
        reach = np.abs(rows).sum(axis=1) > 1e-12  # θ one sample ahead no torque can move
        if not reach.any():
            return None, np.empty(0)
        return rows[reach], rhs[reach]


def jacobians(
    step: ca.Function, states: np.ndarray, tau: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """f(x_k, u_k) (T, 2), A_k (T, 2, 2) and B_k (T, 2) of `step` at T states (T, 2)."""
    t = states.shape[0]
    f, a, b = step_sensitivities(step).map(t)(states.T, np.asarray(tau, dtype=float)[None, :])
    a = np.asarray(a).reshape(2, t, 2).transpose(1, 0, 2)
    return np.asarray(f).T, a, np.asarray(b).T


__all__ = [
    "MPCConfig",
    "MPCConfigError",
    "SliderLimit",
    "Step",
    "TrackingMPC",
    "jacobians",
    "shared_prediction",
]
