"""Writing ocp.json (its keys: control/ocp_file.py) and what a failed robust solve leaves."""

from __future__ import annotations

import platform
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np
import torch

from common.atomic import writes
from common.jsonio import write_json
from control.config import OCPConfig, loop_of
from control.ocp import Solution
from control.ocp_file import FAILED_FORMAT, FORMAT, INDEX_CONVENTION, VERSION
from control.profiles import Solved
from control.records import BeyondStrokeError
from control.robust import Partial, RobustResult
from control.tightening import Uncertainty
from twin import __version__
from twin.geometry import Geometry


def profile_dict(
    solution: Solution,
    uncertainty: Uncertainty,
    *,
    gains: np.ndarray,
    loops: dict[str, np.ndarray],
    k_sigma: float,
    dt: float,
    loop: str,
) -> dict[str, Any]:
    """A profile as JSON-ready lists and scalars."""
    n = len(solution.tau)
    band = k_sigma * uncertainty.std
    series = {
        "time": np.arange(n) * dt,
        "tau": solution.tau,
        "theta": solution.states[:, 0],
        "omega": solution.states[:, 1],
        "slider": solution.slider,
        "slider_mc_mean": uncertainty.mean,
        "slider_sigma": uncertainty.std,
        "slider_lower": solution.slider - band,
        "slider_upper": solution.slider + band,
        "slider_sigma_open": loops["open"],
        "slider_sigma_closed": loops["closed"],
    }
    return {
        **{k: [float(v) for v in values] for k, values in series.items()},
        "heights": [float(h) for h in solution.heights],
        "tightening": [float(v) for v in uncertainty.tightening],
        "tightening_se": [float(v) for v in uncertainty.tightening_se],
        "population": [float(v) for v in uncertainty.population],
        "sampling": [float(v) for v in uncertainty.sampling],
        "mc_samples": uncertainty.samples,
        "gain_theta": [float(v) for v in gains[:, 0]],
        "gain_omega": [float(v) for v in gains[:, 1]],
        "cost": solution.cost,
        "status": solution.status,
        "ipopt_iterations": solution.iterations,
        "wall_time_s": solution.wall_time,
        "loop": loop,
    }


def _header(
    config: OCPConfig,
    *,
    dt: float,
    model: dict[str, Any],
    geometry: Geometry,
    variability: dict[str, Any] | None,
) -> dict[str, Any]:
    return {
        "format": FORMAT,
        "version": VERSION,
        "index_convention": INDEX_CONVENTION,
        "dt": dt,
        "horizon": config.horizon,
        "constraint_samples": list(config.constraint_samples),
        "config": config.as_dict(),
        "model": model,
        "geometry": geometry.as_dict(),
        "variability": variability,
    }


def _part(
    result: RobustResult | Partial, part: str, *, config: OCPConfig, dt: float, loop: str
) -> dict[str, Any]:
    """The plan `part` ("nominal" or "robust") of a result (or of a failed solve's partial one)
    as JSON-ready data, its bands in `loop`."""
    return profile_dict(
        getattr(result, part),
        getattr(result, f"{part}_uncertainty"),
        gains=getattr(result, f"{part}_gains"),
        loops=getattr(result, f"{part}_loops"),
        k_sigma=config.k_sigma,
        dt=dt,
        loop=loop,
    )


def _history(results: dict[str, RobustResult] | dict[str, Partial]) -> dict[str, Any]:
    """Every robust iteration of every profile and every margin IPOPT could not meet."""
    return {
        "robust_iterations": [
            {
                "profile": it.profile,
                "margin": it.margin.tolist(),
                "tightening": it.tightening.tolist(),
                "tightening_se": it.tightening_se.tolist(),
                "cost": it.cost,
                "ipopt_iterations": it.ipopt_iterations,
                "solve_time_s": it.solve_time,
                "monte_carlo_time_s": it.monte_carlo_time,
                "damping": it.damping,
                "draft": it.draft,
                "scheme": it.scheme,
                "k_sigma": it.k_sigma,
            }
            for result in results.values()
            for it in result.iterations
        ],
        "failed_margins": {
            name: [m.tolist() for m in result.failed_proposals] for name, result in results.items()
        },
    }


def _versions() -> dict[str, str]:
    return {
        "project": __version__,
        "casadi": ca.__version__,
        "torch": torch.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
    }


def write_ocp(
    path: str | Path,
    solved: Solved,
    *,
    config: OCPConfig,
    dt: float,
    model: dict[str, Any],
    geometry: Geometry,
    build_s: float,
    variability: dict[str, Any] | None = None,
    engine: str = "vm",
) -> dict[str, Any]:
    """Write ocp.json atomically and return what was written: the nominal profile (its bands in
    the loop of the first robust profile solved), each robust profile solved (those solved as
    the fallback named) and why the others were refused. `variability` is the training
    dataset's scenario (from the checkpoint), which replays draw their machines from; `engine`
    what evaluated the NLP (compiled or vm)."""
    first_name, first = next(iter(solved.results.items()))
    robust = {
        name: {
            **_part(result, "robust", config=config, dt=dt, loop=loop_of(name)),
            "tightening_method": result.tightening,
            "k_sigma": result.k_sigma,
            "tail_checks": [check.as_dict() for check in result.tail_checks],
        }
        for name, result in solved.results.items()
    }
    payload = {
        **_header(config, dt=dt, model=model, geometry=geometry, variability=variability),
        "profiles": ["nominal", *robust],
        "refused": {name: str(exc) for name, exc in solved.refused.items()},
        "refused_spread": {  # what a refusal beyond the stroke measured (a study's figure)
            name: {"sample": int(exc.sample)}
            | {k: float(getattr(exc, k)) for k in ("tightening", "se", "available", "line")}
            for name, exc in solved.refused.items()
            if isinstance(exc, BeyondStrokeError)
        },
        "fallback": [name for name in solved.results if name not in config.profiles],
        # the nominal plan's bands in the loop of the first robust profile solved
        "nominal": _part(first, "nominal", config=config, dt=dt, loop=loop_of(first_name)),
        **robust,
        **_history(solved.results),
        "timing": {
            "build_s": build_s,
            "engine": engine,
            "nominal_solve_s": first.nominal.wall_time,
            "robust_loop_s": {name: r.wall_time for name, r in solved.results.items()},
        },
        "versions": _versions(),
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    write_json(path, payload)
    return payload


@writes("path", suffix=".json")
def write_failed(
    path: str | Path,
    partials: dict[str, Partial],
    *,
    error: str,
    config: OCPConfig,
    dt: float,
    model: dict[str, Any],
    geometry: Geometry,
    variability: dict[str, Any] | None = None,
) -> None:
    """Write what a failed robust solve leaves (`<stem>.failed.json`): the nominal profile in
    ocp.json's form, each profile's margin history and the error, marked `"status": "failed"`.
    It is not an ocp.json (no robust profile), and read_ocp refuses it by its format name."""
    first_name, first = next(iter(partials.items()))
    payload = {
        **_header(config, dt=dt, model=model, geometry=geometry, variability=variability),
        "format": FAILED_FORMAT,
        "status": "failed",
        "error": error,
        "nominal": _part(first, "nominal", config=config, dt=dt, loop=loop_of(first_name)),
        **_history(partials),
        "timing": {
            "nominal_solve_s": first.nominal.wall_time,
            "robust_loop_s": {name: p.wall_time for name, p in partials.items()},
        },
        "versions": _versions(),
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    write_json(path, payload)
