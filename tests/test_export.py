"""`crank export`: a profile of ocp.json as the table a machine's controller plays — the plan to
the last bit, and the law its rows state is the one the twin's closed loop applied."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from control.export import ExportSpec, export_file
from control.ocp_file import OCPFile
from replay.campaign import draw_machines, play
from replay.config import ReplayConfig
from tests.conftest import crank
from tests.replay_ocp import N
from twin.physics import SliderCrank

RIG = ExportSpec.parse(
    units="t=ms,theta=deg,omega=rpm,tau=mN*m,slider_position=mm", flip="theta,omega,tau"
)
"""A rig that counts in ms, degrees, rpm and mN·m, its angle, speed and torque the other way."""


def _read(path: Path) -> tuple[list[str], dict[str, np.ndarray]]:
    """The "#" lines and the columns of an exported table, numbers parsed as Python floats."""
    lines = path.read_text(encoding="utf-8").splitlines()
    notes = [line[2:] for line in lines if line.startswith("# ")]
    rows = list(csv.reader(line for line in lines if not line.startswith("#")))
    header, body = rows[0], rows[1:]
    return notes, {name: np.array([float(r[i]) for r in body]) for i, name in enumerate(header)}


def test_the_table_is_the_plan_to_the_last_bit(
    ocp_path: Path, ocp: OCPFile, tmp_path: Path
) -> None:
    out = tmp_path / "robust.csv"
    written = export_file(ocp_path, out, spec=ExportSpec.parse())
    assert written["profile"] == "robust" and written["rows"] == N  # the first robust profile
    notes, table = _read(out)
    robust = ocp.profiles["robust"]
    np.testing.assert_array_equal(table["sample"], np.arange(1, N + 1))
    for column, series in (
        ("t[s]", robust.time),
        ("tau[N*m]", robust.tau),
        ("theta[rad]", robust.theta),
        ("omega[rad/s]", robust.omega),
        ("slider[m]", robust.slider),
        ("slider_sigma[m]", robust.slider_sigma_open),  # its loop's: open
    ):
        np.testing.assert_array_equal(table[column], series, err_msg=column)
    # gains before samples 1..N-1, the last one held for sample N (as the twin holds it)
    np.testing.assert_array_equal(table["gain_theta[N*m/rad]"][:-1], robust.gain_theta)
    np.testing.assert_array_equal(table["gain_omega[N*m/(rad/s)]"][:-1], robust.gain_omega)
    assert table["gain_theta[N*m/rad]"][-1] == robust.gain_theta[-1]
    assert notes[1].startswith("tightened for the open loop: play u_k = tau_k")
    assert (
        "torque limit 10.0 N*m" in notes[2] and "at or above 0.08 m at samples 50, 100" in notes[2]
    )


@pytest.mark.parametrize("spec", [ExportSpec.parse(), RIG], ids=["contract", "rig"])
def test_the_tables_law_is_what_the_twin_played_closed_loop(
    physics: SliderCrank, ocp_path: Path, tmp_path: Path, spec: ExportSpec
) -> None:
    """Each row's law on the machine's readings of its sample, in the table's own units and
    signs, gives the torque the twin's closed loop applied: to the last bit in the contract's
    units, to 1e-9 N·m through the rig's (degrees, rpm, mN·m, all three flipped)."""
    from control.ocp_file import read_ocp

    pushed = json.loads(ocp_path.read_text())  # stiff gains: the clip acts too
    for key in ("gain_theta", "gain_omega"):
        pushed["robust"][key] = [3.0 * g for g in pushed["robust"][key]]
    pushed["robust"]["loop"] = "closed"  # the law to play is the closed loop's
    ocp_path = tmp_path / "ocp.json"
    ocp_path.write_text(json.dumps(pushed))
    out = tmp_path / "robust.csv"
    export_file(ocp_path, out, spec=spec)
    notes, table = _read(out)
    assert notes[1].startswith("tightened for the closed loop: play u_k = clip(tau_k + ")
    assert notes[1].endswith(
        "(evaluated once a sample, 500 Hz; runs of a faster controller: crank verify "
        "--control-rate)"
    )
    config = ReplayConfig(runs=8, seed=3)
    closed = play(
        physics,
        read_ocp(ocp_path),
        profile="robust",
        mode="closed",
        machines=draw_machines(config, N),
        config=config,
    )
    cols = {name.split("[")[0]: values for name, values in table.items()}
    theta = closed.theta * spec.scale("theta")  # what the rig's encoder reads, in its units
    omega = closed.omega * spec.scale("omega")
    limit = 10.0 * abs(spec.scale("tau"))
    law = cols["gain_theta"] * (cols["theta"] - theta) + cols["gain_omega"] * (
        cols["omega"] - omega
    )
    applied = np.clip(cols["tau"] + law, -limit, limit) / spec.scale("tau")
    assert 0 < np.mean(np.abs(closed.tau) == 10.0) < 0.5  # the clip acts, on some samples
    if spec == RIG:
        np.testing.assert_allclose(applied, closed.tau, rtol=0, atol=1e-9)
    else:
        np.testing.assert_array_equal(applied, closed.tau)


def test_the_command_writes_the_table_and_says_what(ocp_path: Path, tmp_path: Path) -> None:
    out = tmp_path / "p.csv"
    units = "t=ms,theta=deg,omega=rpm,tau=mN*m"
    done = crank(
        "export", str(ocp_path), "--profile", "nominal", "--out", str(out), "--units", units
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"wrote {out}: profile nominal (open loop), {N} rows of sample, ")
    notes, table = _read(out)
    assert notes[0].startswith(f"crank export: profile nominal of {ocp_path} (sha256 ")
    assert list(table)[1:6] == [
        "t[ms]",
        "tau[mN*m]",
        "theta[deg]",
        "omega[rpm]",
        "gain_theta[mN*m/deg]",
    ]
    assert table["t[ms]"][1] == 2.0 and table["theta[deg]"][0] == 180.0
    assert [p.name for p in tmp_path.iterdir()] == ["p.csv"]  # no temporary or lock left
