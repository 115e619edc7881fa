"""ocp.json: the nominal and robust torque profiles of one `crank solve`, and its loader.

Top-level keys (stable; `version` changes if any meaning does):

  format, version            "crank-ocp", 6
  index_convention           how sample k maps to arrays (text; see control/ocp.py)
  dt                         sample time Ts, s
  horizon                    N, samples per profile
  constraint_samples         1-based samples of the slider constraint
  config                     the resolved OCPConfig
  model                      {path, sha256, kind} of the checkpoint solved on
  geometry                   {crank_length, rod_length}, m: the checkpoint's (twin/geometry.py)
  nominal, robust            profiles (below)
  variability                the training dataset's variability scenario (replays draw from it)
  robust_iterations          one entry per robust solve: margin, tightening, tightening_se (m,
                             per constraint sample: k sigma or plan - quantile, and its standard
                             error from the finite Monte-Carlo), cost, ipopt_iterations,
                             solve_time_s, monte_carlo_time_s, damping, draft (true: a draft
                             solve, control/ocp.py; the last entry is always a full solve, the
                             one in `robust`)
  failed_margins             margins IPOPT could not meet during the loop, m
  timing                     build_s, engine (compiled or vm), nominal_solve_s, robust_loop_s
  versions                   project, casadi, torch, numpy, python
  created                    ISO time of writing

A profile holds arrays of length N, index k - 1 for sample k: `time` (s), `tau` (N·m, u_k acts
from t_k to t_{k+1}; the last is the torque after the horizon), `theta`, `omega` (mean-model
states), `slider` (mean-model slider position, m), `slider_mc_mean`, `slider_sigma` (Monte-Carlo
mean and standard deviation of the slider position, in the loop the tightening was sized for),
`slider_lower`, `slider_upper` (slider ∓ k sigma), `slider_sigma_open`, `slider_sigma_closed`
(the Monte-Carlo std of the plan open loop and closed under its gains, which the replay's rows
compare against); and scalars `cost`, `status`, `ipopt_iterations`, `wall_time_s`, plus
`heights`, the slider lower bounds used at the constraint samples, and `tightening`,
`tightening_se` there (m), and `population` and `sampling`, the parts of `tightening` that
allow for the line's uncertain mean and for the Monte-Carlo's standard error (m,
control/robust.py; 0 at confidence 0); and `gain_theta`, `gain_omega`
(N - 1 each), the LQR gains along the profile (control/lqr.py, N·m/rad and N·m·s/rad) that the
twin's closed loop applies before samples 1..N-1. With config.feedback "lqr" the Monte-Carlo
bands and the tightening are those of that closed loop.
"""

from __future__ import annotations

import json
import math
import platform
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np
import torch

from common.atomic import writes
from common.errors import CrankError
from common.jsonio import write_json
from control.config import OCPConfig
from control.ocp import Solution
from control.robust import Partial, RobustResult
from control.tightening import Uncertainty
from twin import __version__
from twin.geometry import Geometry, GeometryError

FORMAT = "crank-ocp"
FAILED_FORMAT = "crank-ocp-failed"
"""The format of what a failed robust solve leaves beside the ocp.json it could not write."""
VERSION = 6
"""2: variability, tightening (was k_sigma) and tightening_se; 3: config.confidence, and
population in each profile; 4: LQR gains and both loops' spreads; 5: sampling in each profile
(the tightening includes the Monte-Carlo's standard-error allowance); 6: geometry."""
INDEX_CONVENTION = (
    "sample k = 1..N is array index k - 1 at t = (k - 1) dt; tau[k - 1] acts from t_k to "
    "t_{k+1}; constraint_samples are 1-based"
)
SERIES = (
    "time",
    "tau",
    "theta",
    "omega",
    "slider",
    "slider_mc_mean",
    "slider_sigma",
    "slider_lower",
    "slider_upper",
    "slider_sigma_open",
    "slider_sigma_closed",
)
GAINS = ("gain_theta", "gain_omega")
SCALARS = ("cost", "ipopt_iterations", "wall_time_s")
TOP_KEYS = ("dt", "horizon", "constraint_samples", "config", "geometry", "nominal", "robust")


class OCPFileError(CrankError, ValueError):
    """A file is not a valid ocp.json."""


@dataclass(frozen=True)
class Profile:
    """One torque profile and what the PPANN predicts for it; arrays (N,)."""

    time: np.ndarray
    tau: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    slider: np.ndarray
    slider_mc_mean: np.ndarray
    slider_sigma: np.ndarray
    slider_lower: np.ndarray
    slider_upper: np.ndarray
    slider_sigma_open: np.ndarray
    """Monte-Carlo slider std of the plan played open loop, m."""
    slider_sigma_closed: np.ndarray
    """... and closed loop under the profile's LQR gains, m."""
    heights: np.ndarray
    gain_theta: np.ndarray
    """(N - 1,) LQR gain on the angle error before samples 1..N-1, N·m/rad."""
    gain_omega: np.ndarray
    """(N - 1,) on the speed error, N·m·s/rad."""
    cost: float
    status: str
    ipopt_iterations: int
    wall_time_s: float

    def sigma_in(self, mode: str) -> np.ndarray:
        """Monte-Carlo slider std of the plan played in `mode`, (N,), m: open loop, or closed
        loop under the LQR gains ("closed"; also the prediction shown for "mpc", whose
        unsaturated law is that LQR's: control/mpc.py)."""
        return self.slider_sigma_closed if mode in ("closed", "mpc") else self.slider_sigma_open


@dataclass(frozen=True)
class OCPFile:
    config: OCPConfig
    geometry: Geometry
    dt: float
    nominal: Profile
    robust: Profile
    raw: dict[str, Any]

    @property
    def horizon(self) -> int:
        return self.config.horizon


def profile_dict(
    solution: Solution,
    uncertainty: Uncertainty,
    *,
    gains: np.ndarray,
    loops: dict[str, np.ndarray],
    k_sigma: float,
    dt: float,
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
        "gain_theta": [float(v) for v in gains[:, 0]],
        "gain_omega": [float(v) for v in gains[:, 1]],
        "cost": solution.cost,
        "status": solution.status,
        "ipopt_iterations": solution.iterations,
        "wall_time_s": solution.wall_time,
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


def _profile_of(
    result: RobustResult | Partial, name: str, *, config: OCPConfig, dt: float
) -> dict[str, Any]:
    """The profile `name` of a result (or of a failed solve's partial one) as JSON-ready data."""
    return profile_dict(
        getattr(result, name),
        getattr(result, f"{name}_uncertainty"),
        gains=getattr(result, f"{name}_gains"),
        loops=getattr(result, f"{name}_loops"),
        k_sigma=config.k_sigma,
        dt=dt,
    )


def _history(result: RobustResult | Partial) -> dict[str, Any]:
    """Every robust iteration and every margin IPOPT could not meet."""
    return {
        "robust_iterations": [
            {
                "margin": it.margin.tolist(),
                "tightening": it.tightening.tolist(),
                "tightening_se": it.tightening_se.tolist(),
                "cost": it.cost,
                "ipopt_iterations": it.ipopt_iterations,
                "solve_time_s": it.solve_time,
                "monte_carlo_time_s": it.monte_carlo_time,
                "damping": it.damping,
                "draft": it.draft,
            }
            for it in result.iterations
        ],
        "failed_margins": [m.tolist() for m in result.failed_proposals],
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
    result: RobustResult,
    *,
    config: OCPConfig,
    dt: float,
    model: dict[str, Any],
    geometry: Geometry,
    build_s: float,
    variability: dict[str, Any] | None = None,
    engine: str = "vm",
) -> dict[str, Any]:
    """Write ocp.json atomically and return what was written. `variability` is the training
    dataset's scenario (from the checkpoint), which replays draw their machines from; `engine`
    what evaluated the NLP (compiled or vm, control/ocp.py)."""
    payload = {
        **_header(config, dt=dt, model=model, geometry=geometry, variability=variability),
        **{name: _profile_of(result, name, config=config, dt=dt) for name in ("nominal", "robust")},
        **_history(result),
        "timing": {
            "build_s": build_s,
            "engine": engine,
            "nominal_solve_s": result.nominal.wall_time,
            "robust_loop_s": result.wall_time,
        },
        "versions": _versions(),
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    write_json(path, payload)
    return payload


@writes("path", suffix=".json")
def write_failed(
    path: str | Path,
    partial: Partial,
    *,
    error: str,
    config: OCPConfig,
    dt: float,
    model: dict[str, Any],
    geometry: Geometry,
    variability: dict[str, Any] | None = None,
) -> None:
    """Write what a failed robust solve leaves (`<stem>.failed.json`): the nominal profile in
    ocp.json's form, the margin history and the error, marked `"status": "failed"`. It is not an
    ocp.json (no robust profile), and read_ocp refuses it by its format name."""
    payload = {
        **_header(config, dt=dt, model=model, geometry=geometry, variability=variability),
        "format": FAILED_FORMAT,
        "status": "failed",
        "error": error,
        "nominal": _profile_of(partial, "nominal", config=config, dt=dt),
        **_history(partial),
        "timing": {
            "nominal_solve_s": partial.nominal.wall_time,
            "robust_loop_s": partial.wall_time,
        },
        "versions": _versions(),
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    write_json(path, payload)


def read_ocp(path: str | Path) -> OCPFile:
    """Load and validate an ocp.json.

    Raises:
      OCPFileError: missing or unreadable file, not JSON, another format or version, a missing
        key, an array of the wrong length, a non-finite number.
    """
    path = Path(path)
    if not path.is_file():
        raise OCPFileError(f"OCP file not found: {path}")
    try:
        raw = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise OCPFileError(f"{path}: not a JSON file ({exc})") from None
    if not isinstance(raw, dict) or raw.get("format") != FORMAT:
        raise OCPFileError(f"{path}: not a {FORMAT} file")
    if raw.get("version") != VERSION:
        raise OCPFileError(f"{path}: version {raw.get('version')!r}, this code reads {VERSION}")
    for key in TOP_KEYS:
        if key not in raw:
            raise OCPFileError(f"{path}: missing key {key!r}")
    try:
        settings = dict(raw["config"])
        settings["constraint_samples"] = tuple(settings["constraint_samples"])
        config = OCPConfig(**settings)
    except (TypeError, KeyError, ValueError) as exc:
        raise OCPFileError(f"{path}: bad config ({exc})") from None
    if raw["horizon"] != config.horizon:
        raise OCPFileError(
            f"{path}: horizon {raw['horizon']!r} differs from the config's {config.horizon}"
        )
    dt = _finite(path, "dt", raw["dt"])
    if dt <= 0:
        raise OCPFileError(f"{path}: dt must be > 0, got {dt}")
    if not isinstance(raw["geometry"], dict):
        raise OCPFileError(f"{path}: geometry must be a table, got {raw['geometry']!r}")
    try:
        geometry = Geometry.from_dict(raw["geometry"], source=str(path))
    except GeometryError as exc:
        raise OCPFileError(str(exc)) from None
    profiles = {name: _profile(path, name, raw[name], config) for name in ("nominal", "robust")}
    return OCPFile(config=config, geometry=geometry, dt=dt, raw=raw, **profiles)


def _finite(path: Path, name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise OCPFileError(f"{path}: {name} must be a finite number, got {value!r}")
    return float(value)


def _profile(path: Path, name: str, raw: Any, config: OCPConfig) -> Profile:
    if not isinstance(raw, dict):
        raise OCPFileError(f"{path}: {name} must be an object")
    for key in (*SERIES, "heights", *GAINS, *SCALARS, "status"):
        if key not in raw:
            raise OCPFileError(f"{path}: missing key '{name}.{key}'")
    arrays = {}
    for key, length, what in [
        *((k, config.horizon, "horizon") for k in SERIES),
        ("heights", len(config.constraint_samples), "constraint samples"),
        *((k, config.horizon - 1, "horizon - 1") for k in GAINS),
    ]:
        values = raw[key]
        if not isinstance(values, list) or len(values) != length:
            got = len(values) if isinstance(values, list) else type(values).__name__
            raise OCPFileError(f"{path}: {name}.{key} has {got} values, expected {length} ({what})")
        try:
            array = np.array(values, dtype=float)
        except (TypeError, ValueError):
            raise OCPFileError(f"{path}: {name}.{key} holds a non-number") from None
        bad = np.flatnonzero(~np.isfinite(array))
        if bad.size:
            raise OCPFileError(
                f"{path}: {name}.{key} holds a non-finite value at index {int(bad[0])}"
            )
        arrays[key] = array
    limit = config.torque_limit
    if np.any(np.abs(arrays["tau"]) > limit * (1 + 1e-9)):
        raise OCPFileError(f"{path}: {name}.tau exceeds the torque limit {limit:g} N·m")
    scalars = {key: _finite(path, f"{name}.{key}", raw[key]) for key in SCALARS}
    return Profile(
        **arrays,
        cost=scalars["cost"],
        status=str(raw["status"]),
        ipopt_iterations=int(scalars["ipopt_iterations"]),
        wall_time_s=scalars["wall_time_s"],
    )
