"""The IPOPT solvers of one OCP's NLP (control/ocp.py): the full one and the three drafts that
share its derivative functions, built once and, on request, kept for the next OCP of this
process whose NLP is the same.

Building is most of a short solve: `nlpsol` expands the 149 mapped PPANN steps and forms the exact
Hessian, ~3 s for the nominal and again for the aware NLP of the default task (~4.5 s while it
also built the gradient of the Lagrangian, control/ocp.py; bench/bench_build.py), against ~2 s of
IPOPT's own work in a one-profile solve (session 64, bench/suite_time.md). A process that poses
the same NLP again (a test that runs a chain a second time to compare it with a sweep's leaf, a
resumed chain, a notebook solving one model twice) may keep what it built: `keep_solvers(n)` keeps
the last n built. Nothing is kept by default, since no command of `crank` builds one NLP twice and
each costs ~250 MB.

The key is the NLP itself: CasADi's serialisation of its function from decision variables and
parameters to cost and constraints (the weights of the PPANN's mean, the geometry, the horizon, the
constraint samples, the aware NLP's surrogate size; 6 ms), and the solvers' options. NLPs that
serialise alike are one function, so a kept solver is never another problem's: one ulp of a mean
network's weight is another key, while the sigma networks, which the NLP does not see (the aware
NLP takes the spread as parameters), are not in it (tests/test_solvers.py). A solver is pure
between calls (IPOPT starts from what each call passes: x0, multipliers, bounds, parameters), so a
kept one gives the numbers a fresh build gives, to the last bit (tests/test_solvers.py). One OCP's
solves read their IPOPT statistics from the solver after each call (`Function.stats`): a kept
solver is for solves one after another, not on several threads at once.
"""

from __future__ import annotations

import hashlib
import json
import threading
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import casadi as ca

from control.compiled import Workshop

DRAFT_TOLERANCE = 1e-6
"""IPOPT's optimality tolerance in draft solves (full solves: 1e-10)."""
PRIMAL_BOUND_PUSH = 1e-9
"""How far a draft from a primal point alone (control/ocp.py `solve(..., multipliers=False)`) is
moved inside the torque bounds and the inequality slacks (IPOPT's bound_push and bound_frac;
default 1e-2, kept after a DRAFT_JUMP). The point is a solution: on control/aware.py's first draft
the default took 8-13 IPOPT iterations on the five session-27 models, this 5, to the same robust
torques (1e-13 N·m); on the bracketed loop's drafts after a jump it took more in sum (350 against
325 on the same models), so they keep the default."""


@dataclass(frozen=True)
class Solvers:
    """One NLP's IPOPT solvers (control/ocp.py's module docstring, "Draft solves")."""

    full: ca.Function
    """At tolerance 1e-10, warm-started from a solution's point and multipliers."""
    draft: ca.Function
    """At DRAFT_TOLERANCE, warm-started likewise."""
    jump: ca.Function
    """A draft from a point alone (after a jump of the heights)."""
    primal: ca.Function
    """A draft from a solution's point alone, pushed PRIMAL_BOUND_PUSH off its bounds."""
    engine: str
    """'compiled' (the NLP's functions in C) or 'vm' (CasADi's virtual machine)."""
    workshop: Workshop | None
    """The folder that holds the compiled functions (kept as long as the solvers are)."""


_kept: OrderedDict[str, Solvers] = OrderedDict()
_kept_lock = threading.Lock()
_capacity = 0


def keep_solvers(count: int) -> None:
    """Keep the last `count` NLPs' solvers built in this process for OCPs that pose the same
    NLP again (0, the default: keep none; fewer than kept now drops the oldest)."""
    global _capacity
    if count < 0:
        raise ValueError(f"keep_solvers: count {count} is negative")
    with _kept_lock:
        _capacity = count
        while len(_kept) > _capacity:
            _kept.popitem(last=False)


def nlp_key(nlp: dict[str, ca.MX], options: dict[str, Any]) -> str:
    """The sha256 of the NLP's function (its serialisation) and of `options` (JSON)."""
    function = ca.Function("nlp", [nlp["x"], nlp["p"]], [nlp["f"], nlp["g"]])
    digest = hashlib.sha256(function.serialize().encode())
    digest.update(json.dumps(options, sort_keys=True).encode())
    return digest.hexdigest()


def solvers(nlp: dict[str, ca.MX], options: dict[str, Any], *, compiled: bool) -> Solvers:
    """The solvers of `nlp` with IPOPT `options` (the full solve's), compiled to C if asked and
    a C compiler is here: kept ones if this process built them and keeps them
    (`keep_solvers`), built otherwise."""
    if _capacity == 0:
        return build(nlp, options, compiled=compiled)
    key = nlp_key(nlp, {**options, "compiled": compiled})
    with _kept_lock:
        found = _kept.get(key)
        if found is not None:
            _kept.move_to_end(key)
            return found
    built = build(nlp, options, compiled=compiled)
    with _kept_lock:
        _kept[key] = built
        while len(_kept) > _capacity:
            _kept.popitem(last=False)
    return built


def build(nlp: dict[str, ca.MX], options: dict[str, Any], *, compiled: bool) -> Solvers:
    """Build the four solvers of `nlp`: the full one, then the drafts on its derivative
    functions (CasADi's `cache` option: 0.03 s each against ~4 s for the first)."""
    engine, workshop = "vm", None
    options = dict(options)
    if compiled:  # the NLP's functions in C: IPOPT's callbacks are most of a solve
        workshop = Workshop()
        try:
            jit = {**options, "expand": False, **workshop.options()}
            with workshop.building():
                full = ca.nlpsol("nominal_ocp", "ipopt", nlp, jit)
            engine = "compiled"
        except RuntimeError:  # no C compiler here: CasADi's virtual machine
            workshop = None
    if engine == "vm":
        full = ca.nlpsol("nominal_ocp", "ipopt", nlp, options)
    derivatives = {f: full.get_function(f) for f in full.get_function()}
    # the drafts share those functions (compiled or not) through the cache
    options["expand"] = engine == "vm"
    draft_ipopt = {**options["ipopt"], "tol": DRAFT_TOLERANCE, "mu_init": 1e-6}
    draft = ca.nlpsol(
        "draft_ocp", "ipopt", nlp, {**options, "ipopt": draft_ipopt, "cache": derivatives}
    )
    jump_ipopt = {**draft_ipopt, "warm_start_init_point": "no"}
    jump = ca.nlpsol(
        "jump_ocp", "ipopt", nlp, {**options, "ipopt": jump_ipopt, "cache": derivatives}
    )
    push = {"bound_push": PRIMAL_BOUND_PUSH, "bound_frac": PRIMAL_BOUND_PUSH}
    primal_ipopt = {**jump_ipopt, **push}
    primal = ca.nlpsol(
        "primal_ocp", "ipopt", nlp, {**options, "ipopt": primal_ipopt, "cache": derivatives}
    )
    return Solvers(full, draft, jump, primal, engine, workshop)
