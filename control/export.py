"""A profile of ocp.json as a table a machine's own controller plays (`crank export`): the rig's
side of `crank import`, in the rig's units and signs.

One row per sample k = 1..N at t = (k - 1) dt (ocp.json's index convention): the planned torque,
the mean model's angle and speed there, the gains of the profile's law (its LQR; robust-pd's
fixed PD) and the slider the PPANN predicts with its spread in the profile's loop. The law the
twin's closed loop applies, row by row, from t_k to t_{k+1} (replay/campaign.py tracking_law):

    u_k = clip(tau_k + gain_theta_k (theta_k - θ measured at t_k)
                     + gain_omega_k (omega_k - ω measured at t_k), ±torque_limit)

and open loop u_k = tau_k, θ and ω being the motor's encoder (the dataset's theta and omega).
Row N holds the last gain (as the twin does). Lines starting with
"#" before the header say which profile, file and law, and the task it was solved for; numbers
are written to the last bit (Python's repr), so reading them back gives the plan's floats.
"""

from __future__ import annotations

import csv
import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from common.atomic import atomic_path, writes
from common.errors import ConfigError
from control.ocp_file import OCPFile, read_ocp
from twin.rig_units import UNITS, check_units, option_pairs

FIELDS = ("t", "theta", "omega", "tau", "slider_position")
"""The quantities a table carries in a unit of its own (twin/rig_import.py UNITS)."""
SIGNED = ("theta", "omega", "tau", "slider_position")
"""Those with a sign a rig may count the other way."""


@dataclass(frozen=True)
class ExportSpec:
    """The rig's units and signs, as `crank import` takes them (`--units`, `--flip`)."""

    units: dict[str, str]
    """Field -> its unit in the table; the contract's own (s, rad, rad/s, N*m, m) if not given."""
    flip: tuple[str, ...] = ()
    """Fields whose sign is the opposite of the contract's."""

    def __post_init__(self) -> None:
        check_units(self.units, FIELDS)
        for name in self.flip:
            if name not in SIGNED:
                raise ConfigError(
                    f"--flip: {name!r} has no sign here (fields: {', '.join(SIGNED)})"
                )

    @classmethod
    def parse(cls, *, units: str = "", flip: str = "") -> ExportSpec:
        """From the command line's `field=unit,...` and `field,...`."""
        pairs = option_pairs(units, "--units")
        return cls(units=pairs, flip=tuple(n.strip() for n in flip.split(",") if n.strip()))

    def unit(self, name: str) -> str:
        return self.units.get(name, next(iter(UNITS[name])))

    def scale(self, name: str) -> float:
        """The table's value per contract value of `name` (sign included)."""
        sign = -1.0 if name in self.flip else 1.0
        return sign / UNITS[name][self.unit(name)]


def profile_table(ocp: OCPFile, name: str, spec: ExportSpec) -> dict[str, np.ndarray]:
    """The rows of profile `name` in the rig's units, by column header (N rows each). A gain
    maps an error in the table's angle (speed) unit to the table's torque unit:
    K_rig = K · scale(tau) / scale(theta)."""
    profile = ocp.profiles[name]
    held = (
        np.append(profile.gain_theta, profile.gain_theta[-1]),
        np.append(profile.gain_omega, profile.gain_omega[-1]),
    )
    tau, theta, omega = (spec.unit(n) for n in ("tau", "theta", "omega"))
    slider = spec.unit("slider_position")
    per_speed = f"({omega})" if "/" in omega else omega  # N*m/(rad/s), mN*m/rpm
    scale = {n: spec.scale(n) for n in FIELDS}
    return {
        "sample": np.arange(1, ocp.horizon + 1),
        f"t[{spec.unit('t')}]": profile.time * scale["t"],
        f"tau[{tau}]": profile.tau * scale["tau"],
        f"theta[{theta}]": profile.theta * scale["theta"],
        f"omega[{omega}]": profile.omega * scale["omega"],
        f"gain_theta[{tau}/{theta}]": held[0] * scale["tau"] / scale["theta"],
        f"gain_omega[{tau}/{per_speed}]": held[1] * scale["tau"] / scale["omega"],
        f"slider[{slider}]": profile.slider * scale["slider_position"],
        f"slider_sigma[{slider}]": profile.sigma_in(profile.loop) * abs(scale["slider_position"]),
    }


def chosen_profile(ocp: OCPFile, path: Path, profile: str | None) -> str:
    """`profile`, or the file's first robust one; a refused or absent one is a ConfigError."""
    name = ocp.robust_names[0] if profile is None else profile
    if name in ocp.refused:
        raise ConfigError(f"{path}: {name} was refused in this file ({ocp.refused[name]})")
    if name not in ocp.profiles:
        raise ConfigError(f"{path} has no profile {name!r} (it has {', '.join(ocp.names)})")
    return name


def _preamble(ocp: OCPFile, path: Path, name: str, spec: ExportSpec) -> list[str]:
    profile, c = ocp.profiles[name], ocp.config
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    limit = c.torque_limit * abs(spec.scale("tau"))
    height = c.height * spec.scale("slider_position")
    side = "below" if spec.scale("slider_position") < 0 else "above"
    if profile.loop == "open":
        play = (
            "tightened for the open loop: play u_k = tau_k (the gains are its plan's LQR, for a "
            "closed loop it was not sized for)"
        )
    else:
        play = (
            f"tightened for the closed loop: play u_k = clip(tau_k + gain_theta_k (theta_k - "
            f"theta measured at t_k) + gain_omega_k (omega_k - omega measured at t_k), "
            f"+-{limit!r})"
        )
    return [
        f"crank export: profile {name} of {path} (sha256 {digest})",
        f"{play}, held from t_k to t_(k+1)"
        + (
            f" (evaluated once a sample, {1 / ocp.dt:g} Hz; runs of a faster controller: crank "
            "verify --control-rate)"
            if profile.loop == "closed"
            else ""
        ),
        f"dt {ocp.dt * spec.scale('t')!r} {spec.unit('t')}, {ocp.horizon} samples, torque limit "
        f"{limit!r} {spec.unit('tau')}; the constraint: the slider at or {side} {height!r} "
        f"{spec.unit('slider_position')} at samples "
        f"{', '.join(map(str, c.constraint_samples))}; cost premium "
        f"{100 * ocp.premium(name):+.1f} % over the nominal",
        f"units and signs: {', '.join(f'{n} {spec.unit(n)}' for n in FIELDS)}"
        + (f"; flipped: {', '.join(spec.flip)}" if spec.flip else "; the contract's signs"),
    ]


@writes("out", inputs=("ocp_path",), suffix=".csv")
def export_file(
    ocp_path: str | Path, out: str | Path, *, profile: str | None = None, spec: ExportSpec
) -> dict[str, Any]:
    """Write profile `profile` of `ocp_path` (default: its first robust one) to the CSV `out`;
    return what was written (profile, loop, rows, columns).

    Raises:
      OCPFileError: not a valid ocp.json. ConfigError: no such profile, or one the file refused.
    """
    ocp_path = Path(ocp_path)
    ocp = read_ocp(ocp_path)
    name = chosen_profile(ocp, ocp_path, profile)
    table = profile_table(ocp, name, spec)
    with atomic_path(out) as tmp, open(tmp, "w", newline="", encoding="utf-8") as handle:
        for line in _preamble(ocp, ocp_path, name, spec):
            handle.write(f"# {line}\n")
        writer = csv.writer(handle)
        writer.writerow(table)
        for row in zip(*table.values(), strict=True):
            writer.writerow([repr(v.item()) for v in row])
    return {
        "profile": name,
        "loop": ocp.profiles[name].loop,
        "rows": ocp.horizon,
        "columns": list(table),
    }
