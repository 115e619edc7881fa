"""The nominal OCP of paper eqs. 10 and 15 on the PPANN mean, by multiple shooting and IPOPT.

Index convention (the paper's, 1-based): sample k = 1..N is the state x_k = (theta_k, omega_k) at
t_k = (k - 1) Ts. Torque u_k acts from t_k to t_{k+1}, so x_{k+1} = step(x_k, u_k) for
k = 1..N-1 (eq. 10b). The cost of section 3.4.1,

    J = sum_{k=1}^{N} u_k^2 + 1e-4 sum_{k=1}^{N-1} ((u_{k+1} - u_k) / Ts)^2,

also holds u_N, the torque after the last sample: it enters no constraint, only the cost, so it
settles at 25/26 u_{N-1} (with Ts = 2 ms). In code, sample k is array index k - 1.

Constraints (eq. 15): theta_1, omega_1, theta_N, omega_N fixed; slider position >= height at the
configured samples (50 and 100); |u_k| <= torque limit.

theta mod 2 pi: the PPANN's stiffness term K (1 + z_K) theta_mod jumps where theta crosses a
multiple of 2 pi. Each shooting interval uses `step_on_turn` with its turn_k = floor(theta_k / 2 pi)
given as a parameter, which makes the NLP smooth. A first pass takes the turns from the starting
point and leaves theta free; if its solution lies on other turns, the OCP is solved again with the
turns of that solution and each theta_k bounded to its turn, [2 pi turn_k, 2 pi (turn_k + 1)), so
the solution satisfies the torch model's own dynamics (with its `remainder`) exactly, not an
approximation of them. While the optimum presses theta_k against a turn edge, the crossing moves
one sample that way and the OCP is solved again, warm-started; if that leads back to an assignment
already tried (the optimum sits on the edge, where the stiffness torque jumps), or after
MAX_TURN_PASSES, the consistent solution of lowest cost is kept.

Draft solves (`solve(..., draft=True)`, used by the robust loop between its final solves): one
IPOPT pass on the warm start's turns at tolerance DRAFT_TOLERANCE (control/solvers.py), without the
turn passes. The torque of a draft meets every constraint of the NLP (to 1e-8) but where its
crossing moved, its states follow the stiffness term extrapolated across 2 pi rather than the
wrapped one; the robust loop uses such a draft only for the Monte-Carlo of its torque; it returns a
draft only where its crossing stayed and its states are its torque's own (control/aware.py
`exact`). A draft whose heights jump by more than DRAFT_JUMP starts from the warm start's primal
point alone; so does one asked to (`multipliers=False`), not pushed off the bounds it sits on
(PRIMAL_BOUND_PUSH). The draft solvers share the derivative functions of the full one (CasADi's
`cache` option), so they cost no second build (0.03 s against 3.5 s for the first).
control/solvers.py builds the four and may keep them for the next OCP that poses the same NLP.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any

import casadi as ca
import numpy as np

from common.errors import CrankError
from control.config import OCPConfig
from control.dynamics import CasadiPPANN
from control.solvers import solvers
from ppann.model import PPANN
from twin.geometry import Geometry


class OCPError(CrankError, RuntimeError):
    """IPOPT did not return a solution that meets every constraint.

    Attributes:
      status: IPOPT's return status (or the reason the check after the solve failed).
      constraint: the most violated constraint, in words.
      violation: how far it is from its bound, in its own unit.
    """

    def __init__(self, status: str, constraint: str, violation: float, iterations: int) -> None:
        self.status, self.constraint, self.violation = status, constraint, violation
        self.iterations = iterations
        super().__init__(
            f"OCP failed: IPOPT status {status} after {iterations} iterations; most violated "
            f"constraint: {constraint} (off by {violation:.3g})"
        )


SOLVED = "Solve_Succeeded"
FEASIBILITY_TOLERANCE = 1e-8
"""Largest constraint violation accepted in a returned solution (m, rad, rad/s)."""
MAX_TURN_PASSES = 6
"""Most re-solves with the 2 pi crossing moved to another sample."""
TURN_EDGE = 1e-9
"""theta_k stays this far inside [2 pi turn_k, 2 pi (turn_k + 1)), rad."""
TURN_ACTIVE = 1e-7
"""theta_k this close to a turn edge means the optimum wants to cross it there, rad."""
DRAFT_JUMP = 3e-3
"""A draft whose heights move further than this from its warm start's (m) starts from the warm
start's primal point only: after a jump that large, IPOPT's multiplier warm start costs more
iterations than it saves (17 against 10 on the seed-0 model's first robust step)."""


@dataclass(frozen=True)
class Solution:
    """One solved OCP. Arrays are indexed by sample - 1 (see the module docstring)."""

    tau: np.ndarray
    """u_1..u_N, N·m, (N,)."""
    states: np.ndarray
    """x_1..x_N as (theta, omega), (N, 2)."""
    heights: np.ndarray
    """Lower bounds the slider had at the constraint samples in this solve, m (a robust solve
    of control/aware.py: the height plus the margin its slider keeps)."""
    cost: float
    status: str
    iterations: int
    """IPOPT iterations, summed over the turn passes."""
    wall_time: float
    """Seconds, all passes."""
    turn_passes: int
    geometry: Geometry
    """The mechanism whose slider the constraints hold (the model's, twin/geometry.py)."""
    lam_g: np.ndarray = field(repr=False)
    lam_x: np.ndarray = field(repr=False)

    @property
    def slider(self) -> np.ndarray:
        """Slider position of the mean-model states, (N,), m."""
        return self.geometry.slider_position(self.states[:, 0])


class NominalOCP:
    """Eqs. 10 and 15 for one trained PPANN, built once and re-solvable with other slider heights
    (the robust loop) and warm starts."""

    def __init__(self, model: PPANN, config: OCPConfig | None = None) -> None:
        self.config = c = config or OCPConfig()
        self.geometry = model.geometry
        self.dynamics = CasadiPPANN(model)
        self.dt = self.dynamics.dt
        n = c.horizon
        x = ca.MX.sym("x", 2, n)
        u = ca.MX.sym("u", n)
        turns = ca.MX.sym("turns", n - 1)
        step = self.dynamics.step_on_turn.map(n - 1)
        defects = step(x[:, :-1], u[: n - 1].T, turns.T) - x[:, 1:]
        du = (u[1:] - u[:-1]) / self.dt
        cost = ca.sumsqr(u) + c.smoothness_weight * ca.sumsqr(du)
        index = [k - 1 for k in c.constraint_samples]
        slider, extra = self._slider_rows(x, index)
        self._extra = np.zeros(extra.numel())
        boundary = ca.vertcat(x[0, 0], x[1, 0], x[0, n - 1], x[1, n - 1])
        g = ca.vertcat(ca.vec(defects), boundary, slider)
        w = ca.vertcat(ca.vec(x), u)
        self._labels = (
            [f"dynamics (eq. 10b) {s} from sample {k}" for k in range(1, n) for s in "θω"]
            + [
                f"θ_1 = {c.theta_start:.6g}",
                f"ω_1 = {c.omega_start:.6g}",
                f"θ_{n} = {c.theta_end:.6g}",
                f"ω_{n} = {c.omega_end:.6g}",
            ]
            + [
                f"slider position ≥ {{h{i}}} m at sample {k}"
                for i, k in enumerate(c.constraint_samples)
            ]
        )
        self._boundary = np.array([c.theta_start, c.omega_start, c.theta_end, c.omega_end])
        self._n_defects = 2 * (n - 1)
        options: dict[str, Any] = {
            "expand": True,
            "print_time": False,
            # the parameters' multipliers (turns, aware terms) serve nothing here, and CasADi
            # computes them after each solve: 2-4 ms of a 5-iteration draft's ~63 (interleaved)
            "calc_lam_p": False,
            # nor CasADi's gradient of the Lagrangian (`nlp_grad`), which only those multipliers
            # and the solver's own parametric derivatives (none taken here) use: not built, the
            # same numbers to the last bit, 1.4 of the 5.2 s an NLP took to build (session 66)
            "no_nlp_grad": True,
            "ipopt": {
                "print_level": 0,
                "sb": "yes",
                "tol": 1e-10,
                "constr_viol_tol": 1e-10,
                "max_iter": c.max_ipopt_iterations,
                "warm_start_init_point": "yes",
                "warm_start_bound_push": 1e-9,
                "warm_start_mult_bound_push": 1e-9,
                "mu_init": 1e-3,
            },
        }
        nlp = {"x": w, "p": ca.vertcat(turns, extra), "f": cost, "g": g}
        built = solvers(nlp, options, compiled=c.compiled)
        self.engine = built.engine
        self._workshop = built.workshop
        self._solver, self._draft_solver = built.full, built.draft
        self._jump_solver, self._primal_solver = built.jump, built.primal
        self._lbx = np.concatenate([np.full(2 * n, -np.inf), np.full(n, -c.torque_limit)])
        self._ubx = np.concatenate([np.full(2 * n, np.inf), np.full(n, c.torque_limit)])

    def _slider_rows(self, x: ca.MX, index: list[int]) -> tuple[ca.MX, ca.MX]:
        """The constrained quantity at each constraint sample (0-based `index`) of the states x
        (2, N), and the NLP parameters it needs beside the turns: here the mean-model slider
        position and none. A subclass may constrain another function of the states (e.g. the
        slider less a tightening that depends on theta_k, control/aware.py); it sets the
        parameters' values in `self._extra` before each solve."""
        rows = ca.vertcat(*(self.geometry.slider_position(x[0, i], lib=ca) for i in index))
        return rows, ca.MX(0, 1)

    def initial_guess(self) -> np.ndarray:
        """States on a cosine ramp from the start to the end angle, zero torque."""
        c = self.config
        s = np.linspace(0.0, 1.0, c.horizon)
        span = c.theta_end - c.theta_start
        theta = c.theta_start + span * (1 - np.cos(np.pi * s)) / 2
        omega = span * np.pi / (2 * (c.horizon - 1) * self.dt) * np.sin(np.pi * s)
        return np.concatenate([np.stack([theta, omega], axis=1).ravel(), np.zeros(c.horizon)])

    def bounds(self, heights: np.ndarray) -> dict[str, np.ndarray]:
        """IPOPT's lbx, ubx, lbg and ubg with slider lower bounds `heights` at the constraint
        samples (the turn passes narrow lbx and ubx further)."""
        zeros = np.zeros(self._n_defects)
        return {
            "lbx": self._lbx,
            "ubx": self._ubx,
            "lbg": np.concatenate([zeros, self._boundary, heights]),
            "ubg": np.concatenate([zeros, self._boundary, np.full(len(heights), np.inf)]),
        }

    def solve(
        self,
        heights: np.ndarray | None = None,
        *,
        warm: Solution | None = None,
        draft: bool = False,
        multipliers: bool = True,
        bounded: bool = False,
    ) -> Solution:
        """Solve with slider lower bounds `heights` at the constraint samples (default: the
        configured height everywhere), warm-started from `warm` if given. `draft=True`: one
        loose pass on the warm start's turns (module docstring); needs `warm`.
        `multipliers=False`: start from the warm start's primal point alone, as after a jump
        (its multipliers belong to another constraint function, control/aware.py).
        `bounded=True` (a draft): its one pass with each theta_k bounded to the warm start's
        turn, as a full solve's second pass, so that its states are its torque's own.

        Raises:
          OCPError: IPOPT failed, or its answer breaks a constraint by more than 1e-8.
        """
        c, n = self.config, self.config.horizon
        if heights is None:
            heights = np.full(len(c.constraint_samples), c.height)
        heights = np.asarray(heights, dtype=float)
        args: dict[str, Any] = self.bounds(heights)
        lbg, ubg = args["lbg"], args["ubg"]
        if warm is None:
            w0 = self.initial_guess()
        else:
            w0 = np.concatenate([warm.states.ravel(), warm.tau])
            if multipliers:
                args.update(lam_g0=warm.lam_g, lam_x0=warm.lam_x)
        iterations, wall = 0, 0.0
        thetas = slice(0, 2 * (n - 1), 2)  # theta_1..theta_{N-1} in the decision vector
        turns = np.floor(w0[thetas] / (2 * math.pi))
        tried: set[bytes] = set()
        solver = self._solver
        if draft:
            if warm is None:
                raise ValueError("a draft solve needs a warm start")
            if not multipliers:  # its point alone (no multipliers were passed above)
                solver = self._primal_solver
            elif np.max(np.abs(heights - warm.heights)) > DRAFT_JUMP:
                solver = self._jump_solver
                args.pop("lam_g0")
                args.pop("lam_x0")
            else:
                solver = self._draft_solver
        best: Solution | None = None
        for passes in range(1, 2 if draft else MAX_TURN_PASSES + 1):
            tried.add(turns.tobytes())
            lower, upper = 2 * math.pi * turns + TURN_EDGE, 2 * math.pi * (turns + 1) - TURN_EDGE
            args["lbx"], args["ubx"] = self._lbx.copy(), self._ubx.copy()
            if passes > 1 or bounded:  # a first pass is free: it moves the crossing
                args["lbx"][thetas] = lower
                args["ubx"][thetas] = upper
                w0 = w0.copy()
                w0[thetas] = np.clip(w0[thetas], lower, upper)
            started = time.perf_counter()
            result = solver(x0=w0, p=np.concatenate([turns, self._extra]), **args)
            wall += time.perf_counter() - started
            stats = solver.stats()
            iterations += int(stats["iter_count"])
            w = result["x"].full().ravel()
            g = result["g"].full().ravel()
            status = str(stats["return_status"])
            label, violation = self._most_violated(g, lbg, ubg, w, heights)
            if status != SOLVED or violation > FEASIBILITY_TOLERANCE:
                raise OCPError(status, label, violation, iterations)
            args["lam_g0"] = result["lam_g"].full().ravel()
            args["lam_x0"] = result["lam_x"].full().ravel()
            theta = w[thetas]
            # a bounded pass is consistent by its bounds (up to IPOPT's 1e-8 bound relaxation)
            consistent = passes > 1 or np.array_equal(np.floor(theta / (2 * math.pi)), turns)
            if draft or (consistent and (best is None or float(result["f"]) < best.cost)):
                best = Solution(
                    tau=w[2 * n :].copy(),
                    states=w[: 2 * n].reshape(n, 2).copy(),
                    heights=heights.copy(),
                    cost=float(result["f"]),
                    status=status,
                    iterations=0,
                    wall_time=0.0,
                    turn_passes=passes,
                    geometry=self.geometry,
                    lam_g=args["lam_g0"],
                    lam_x=args["lam_x0"],
                )
            if passes == 1:
                following = np.floor(theta / (2 * math.pi))
                if consistent:
                    break
            else:
                pressed_up = theta >= upper - TURN_ACTIVE
                following = turns + pressed_up - (theta <= lower + TURN_ACTIVE)
                shift = following != turns
                if not shift.any():
                    break
            if following.tobytes() in tried or passes == MAX_TURN_PASSES:
                break
            turns, w0 = following, w
        assert best is not None  # pass 1 is consistent, or a bounded pass follows
        return replace(best, iterations=iterations, wall_time=wall, turn_passes=passes)

    def _most_violated(
        self, g: np.ndarray, lbg: np.ndarray, ubg: np.ndarray, w: np.ndarray, heights: np.ndarray
    ) -> tuple[str, float]:
        """The constraint (or torque bound) furthest outside its bounds, and by how much."""
        excess = np.maximum(lbg - g, g - ubg)
        n = self.config.horizon
        tau = w[2 * n :]
        torque_excess = np.abs(tau) - self.config.torque_limit
        i = int(np.argmax(excess))
        j = int(np.argmax(torque_excess))
        if torque_excess[j] > excess[i]:
            return f"|torque| ≤ {self.config.torque_limit:g} N·m at sample {j + 1}", float(
                torque_excess[j]
            )
        label = self._labels[i]
        if "{h" in label:
            slot = i - self._n_defects - 4
            label = label.replace(f"{{h{slot}}}", f"{heights[slot]:.4g}")
        return label, float(max(excess[i], 0.0))
