"""The project's nominal OCP (control/ocp.py) written in do-mpc, for bench_mpc.py's comparison:
the same PPANN one-step map on the same turns, the same cost, bounds and constraints, IPOPT with
the same tolerances, started from the same initial guess.

Differences of formulation, both do-mpc's: its cost holds the torques u_1..u_{N-1} (the project's
also holds u_N, which enters no constraint) and its rate penalty also weighs u_1 against the
previous input (0 here). The optimal Σu² differs by about 1 %.

do-mpc 5.0.1 (the latest on PyPI) still imports names that CasADi 3.8 moved: `casadi.tools` no
longer re-exports CasADi's namespace, and `structure3` is now `structure`. `load_do_mpc()` puts
them back before importing it; nothing of the project depends on do-mpc (`pip install -e
".[bench]"`).
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import casadi as ca
import numpy as np

from control.dynamics import CasadiPPANN
from control.ocp import NominalOCP


def load_do_mpc() -> Any:
    """do-mpc, importable with this CasADi."""
    import casadi.tools as tools
    import casadi.tools.structure as structure

    for name in dir(ca):
        if not name.startswith("_") and not hasattr(tools, name):
            setattr(tools, name, getattr(ca, name))
    tools.structure3 = structure
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # its optional ONNX and OPC UA features
        import do_mpc
    return do_mpc


class DoMPCOCP:
    """The nominal OCP in do-mpc, on the turns of the project's initial guess (its first pass);
    `dynamics` is the PPANN's CasADi form it is given (default the OCP's own, with the angle
    splines of control/dynamics.py; `CasadiPPANN(model, splines=False)` gives it the networks)."""

    def __init__(self, ocp: NominalOCP, *, dynamics: CasadiPPANN | None = None) -> None:
        do_mpc = load_do_mpc()
        c, n = ocp.config, ocp.config.horizon
        self.n, self.config = n, c
        self.guess = ocp.initial_guess()
        turns = np.floor(self.guess[0 : 2 * (n - 1) : 2] / (2 * math.pi))
        model = do_mpc.model.Model("discrete")
        theta = model.set_variable("_x", "theta")
        omega = model.set_variable("_x", "omega")
        tau = model.set_variable("_u", "tau")
        turn = model.set_variable("_tvp", "turn")
        height = model.set_variable("_tvp", "height")
        nxt = (dynamics or ocp.dynamics).step_on_turn(ca.vertcat(theta, omega), tau, turn)
        model.set_rhs("theta", nxt[0])
        model.set_rhs("omega", nxt[1])
        model.set_expression("slider", ocp.geometry.slider_position(theta, lib=ca))
        model.setup()
        mpc = do_mpc.controller.MPC(model)
        mpc.settings.n_horizon = n - 1
        mpc.settings.t_step = ocp.dt
        mpc.settings.use_terminal_bounds = True
        mpc.settings.store_full_solution = False
        mpc.settings.nlpsol_opts = {
            "print_time": 0,
            "ipopt.print_level": 0,
            "ipopt.sb": "yes",
            "ipopt.tol": 1e-10,
            "ipopt.constr_viol_tol": 1e-10,
            "ipopt.mu_init": 1e-3,
            "ipopt.max_iter": c.max_ipopt_iterations,
        }
        mpc.set_objective(lterm=tau**2, mterm=ca.DM(0))
        mpc.set_rterm(tau=c.smoothness_weight / ocp.dt**2)
        mpc.bounds["lower", "_u", "tau"] = -c.torque_limit
        mpc.bounds["upper", "_u", "tau"] = c.torque_limit
        for name, value in (("theta", c.theta_end), ("omega", c.omega_end)):
            mpc.terminal_bounds["lower", name] = value
            mpc.terminal_bounds["upper", name] = value
        mpc.set_nl_cons("slider", height - model.aux["slider"], ub=0.0)
        template = mpc.get_tvp_template()
        for k in range(n):
            template["_tvp", k, "turn"] = turns[min(k, n - 2)]
            template["_tvp", k, "height"] = c.height if k + 1 in c.constraint_samples else -1.0
        mpc.set_tvp_fun(lambda _: template)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # do-mpc's own NumPy calls on CasADi values
            mpc.setup()
        self.mpc = mpc

    def solve(self) -> tuple[float, int, str, np.ndarray]:
        """One solve from the initial guess: (seconds, IPOPT iterations, status, torques)."""
        import time

        mpc, n = self.mpc, self.n
        states = self.guess[: 2 * n].reshape(n, 2)
        for k in range(n):
            mpc.opt_x_num["_x", k, 0, -1] = states[k]
        for k in range(n - 1):
            mpc.opt_x_num["_u", k, 0] = 0.0
        x0 = np.array([self.config.theta_start, self.config.omega_start])
        mpc.x0 = x0
        mpc.u0 = np.zeros(1)  # the rate penalty's u_0: make_step keeps the last call's u_1
        mpc.flags["set_initial_guess"] = True  # ours, set above (its own would overwrite it)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # do-mpc's NumPy deprecation notices
            started = time.perf_counter()
            mpc.make_step(x0)
            seconds = time.perf_counter() - started
        stats = mpc.solver_stats
        tau = np.array([float(mpc.opt_x_num["_u", k, 0]) for k in range(n - 1)])
        return seconds, int(stats["iter_count"]), str(stats["return_status"]), tau
