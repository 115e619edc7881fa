"""ocp.json: the nominal and robust torque profiles of one `crank solve`, and its loader (the
writer: control/ocp_write.py).

Top-level keys (stable; `version` changes if any meaning does):

  format, version            "crank-ocp", 7
  index_convention           how sample k maps to arrays (text; see control/ocp.py)
  dt                         sample time Ts, s
  horizon                    N, samples per profile
  constraint_samples         1-based samples of the slider constraint
  config                     the resolved OCPConfig
  model                      {path, sha256, kind} of the checkpoint solved on
  geometry                   {crank_length, rod_length}, m: the checkpoint's (twin/geometry.py)
  profiles                   the profiles in the file, in order: "nominal", then each robust
                             profile of config.profiles that was solved (control/config.py
                             ROBUST_PROFILES: "robust", open-loop tightening, the paper's eq. 16;
                             "robust-fb", tightened for the LQR closed loop; "robust-pd",
                             for the fixed-PD closed loop)
  nominal, robust, robust-fb,
  robust-pd                  each profile listed (below)
  refused                    {profile: the one-line reason} for each asked-for robust profile
                             that has no robust torque (e.g. open loop on a wide line)
  refused_spread             {profile: {sample, tightening, se, available, line}} for each
                             refusal beyond the stroke: the tightening it would need at that
                             constraint sample, its standard error, the stroke above the height
                             a margin may take, the share of it for the line's mean (m; absent
                             before session 54)
  fallback                   the robust profiles solved only because every one asked for was
                             refused (config.fallback; absent before session 54: none)
  variability                the training dataset's variability scenario (replays draw from it)
  robust_iterations          one entry per robust solve: profile, margin, tightening,
                             tightening_se (m, per constraint sample: k sigma or plan - quantile,
                             and its standard error from the finite Monte-Carlo), cost,
                             ipopt_iterations, solve_time_s, monte_carlo_time_s, damping, draft
                             (true: a draft solve, control/ocp.py; each profile's last entry is
                             always a full solve, the one in its profile), scheme ("aware":
                             control/aware.py, margin = the one the solution keeps; "bracket"),
                             k_sigma (the k its tightening is at; since session 47)
  failed_margins             {profile: margins IPOPT could not meet during its loop, m}
  timing                     build_s, engine (compiled or vm), nominal_solve_s, robust_loop_s
                             ({profile: s})
  versions                   project, casadi, torch, numpy, python
  created                    ISO time of writing

A profile holds arrays of length N, index k - 1 for sample k: `time` (s), `tau` (N·m, u_k acts
from t_k to t_{k+1}; the last is the torque after the horizon), `theta`, `omega` (mean-model
states), `slider` (mean-model slider position, m), `slider_mc_mean`, `slider_sigma` (Monte-Carlo
mean and standard deviation of the slider position, in the loop the tightening was sized for),
`slider_lower`, `slider_upper` (slider ∓ k sigma), `slider_sigma_open`, `slider_sigma_closed`
(the Monte-Carlo std of the plan open loop and closed under its gains, which the replay's rows
compare against); and scalars `cost`, `status`, `ipopt_iterations`, `wall_time_s`, `loop`
(open or closed: the loop its bands and tightening are of; a robust profile's is the loop it
was tightened for), plus
`heights`, the slider lower bounds used at the constraint samples, and `tightening`,
`tightening_se` there (m), and `population` and `sampling`, the parts of `tightening` that
allow for the line's uncertain mean and for the Monte-Carlo's standard error (m,
control/robust.py; 0 at confidence 0); a robust profile also `tightening_method` (the
tightening its torque was solved with: config.tightening, or "quantile" where its own tail sent
it there), `k_sigma` (the k it was solved with: config.k_sigma, or raised by its own tail's
check) and `tail_checks` (control/tail.py: each check of a torque's own Monte-Carlo, {draws,
stages, rate, samples, target, tightening, k_sigma, passed, wall_time_s}: `draws` the stage
that decided, `stages` every one drawn; empty without config.tail_check; absent in files
written before session 30, `k_sigma` before session 31, `stages` before session 43; since
session 46 also `sampling` ("plain" or "lines": control/tail_lines.py, `draws` then counting
lines), `standard_error`, and with lines `lines_unsettled` (crossings whose secant steps had
not settled) and `lines_diverged`); since session 47 `draft` (true for the check of the robust
loop's draft near its fixed point, first where it was made, which chose the k of the full
solve);
and `gain_theta`, `gain_omega`
(N - 1 each), the gains of the profile's law (control/config.py law_of: the LQR along the plan,
control/lqr.py, or robust-pd's fixed PD at every sample; N·m/rad and N·m·s/rad) that the twin's
closed loop applies before samples 1..N-1. The nominal profile carries the gains of the first
robust profile's law.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from common.errors import CrankError
from control.config import ROBUST_PROFILES, OCPConfig
from twin.geometry import Geometry, GeometryError

FORMAT = "crank-ocp"
FAILED_FORMAT = "crank-ocp-failed"
"""The format of what a failed robust solve leaves beside the ocp.json it could not write."""
VERSION = 7
"""2: variability, tightening (was k_sigma) and tightening_se; 3: config.confidence, and
population in each profile; 4: LQR gains and both loops' spreads; 5: sampling in each profile
(the tightening includes the Monte-Carlo's standard-error allowance); 6: geometry; 7: several
robust profiles (config.profiles in place of config.feedback; profiles, refused, each profile's
loop; iterations, failed margins and loop times per profile)."""
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
TOP_KEYS = ("dt", "horizon", "constraint_samples", "config", "geometry", "profiles", "nominal")


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
    """... and closed loop under the profile's own gains (its LQR; robust-pd's PD), m."""
    heights: np.ndarray
    gain_theta: np.ndarray
    """(N - 1,) LQR gain on the angle error before samples 1..N-1, N·m/rad."""
    gain_omega: np.ndarray
    """(N - 1,) on the speed error, N·m·s/rad."""
    cost: float
    status: str
    ipopt_iterations: int
    wall_time_s: float
    loop: str
    """open or closed: the loop its bands and tightening are of (a robust profile's claim)."""

    def sigma_in(self, loop: str) -> np.ndarray:
        """Monte-Carlo slider std of the plan played in `loop`, (N,), m: "open", or "closed"
        under the profile's own gains (its LQR; robust-pd's fixed PD). Under another law (a
        replay's fixed PD, the MPC) see replay/laws.py predicted_sigma."""
        if loop not in ("open", "closed"):
            raise ValueError(f"loop {loop!r}: open or closed")
        return self.slider_sigma_closed if loop == "closed" else self.slider_sigma_open


@dataclass(frozen=True)
class OCPFile:
    config: OCPConfig
    geometry: Geometry
    dt: float
    profiles: dict[str, Profile]
    """"nominal", then each robust profile solved, in the file's order."""
    refused: dict[str, str]
    """Each asked-for robust profile that has none: why."""
    raw: dict[str, Any]
    fallback: tuple[str, ...] = ()
    """The robust profiles solved because every one asked for was refused (OCPConfig.fallback)."""

    @property
    def horizon(self) -> int:
        return self.config.horizon

    @property
    def nominal(self) -> Profile:
        return self.profiles["nominal"]

    @property
    def names(self) -> tuple[str, ...]:
        """The profiles in the file: "nominal" first."""
        return tuple(self.profiles)

    @property
    def robust_names(self) -> tuple[str, ...]:
        """The robust profiles in the file."""
        return self.names[1:]

    def premium(self, name: str) -> float:
        """The cost of profile `name` over the nominal's, minus 1."""
        return self.profiles[name].cost / self.nominal.cost - 1.0


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
    if isinstance(raw, dict) and raw.get("format") == FAILED_FORMAT:
        raise OCPFileError(
            f"{path}: the record of a solve that found no robust torque ({FAILED_FORMAT}: its "
            "error, nominal plan and margins), not an ocp.json to play"
        )
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
        settings["profiles"] = tuple(settings["profiles"])
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
    names = raw["profiles"]
    if (
        not isinstance(names, list)
        or names[:1] != ["nominal"]
        or len(set(names)) != len(names)
        or any(name not in ROBUST_PROFILES for name in names[1:])
    ):
        raise OCPFileError(
            f"{path}: profiles must be 'nominal' then distinct names among "
            f"{', '.join(ROBUST_PROFILES)}, got {names!r}"
        )
    for name in names:
        if name not in raw:
            raise OCPFileError(f"{path}: missing key {name!r}")
    refused = raw.get("refused", {})
    if not isinstance(refused, dict) or not all(isinstance(v, str) for v in refused.values()):
        raise OCPFileError(f"{path}: refused must map profiles to reasons, got {refused!r}")
    fallback = raw.get("fallback", [])
    if not isinstance(fallback, list) or not set(fallback) <= set(names[1:]):
        raise OCPFileError(
            f"{path}: fallback must list robust profiles of the file, got {fallback!r}"
        )
    profiles = {name: _profile(path, name, raw[name], config) for name in names}
    return OCPFile(
        config=config,
        geometry=geometry,
        dt=dt,
        profiles=profiles,
        refused=refused,
        raw=raw,
        fallback=tuple(fallback),
    )


def _finite(path: Path, name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise OCPFileError(f"{path}: {name} must be a finite number, got {value!r}")
    return float(value)


def _profile(path: Path, name: str, raw: Any, config: OCPConfig) -> Profile:
    if not isinstance(raw, dict):
        raise OCPFileError(f"{path}: {name} must be an object")
    for key in (*SERIES, "heights", *GAINS, *SCALARS, "status", "loop"):
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
    if raw["loop"] not in ("open", "closed"):
        raise OCPFileError(f"{path}: {name}.loop must be open or closed, got {raw['loop']!r}")
    return Profile(
        loop=raw["loop"],
        **arrays,
        cost=scalars["cost"],
        status=str(raw["status"]),
        ipopt_iterations=int(scalars["ipopt_iterations"]),
        wall_time_s=scalars["wall_time_s"],
    )
