"""The twin as a rig for `crank verify`'s tests: a profile played on twin machines, written as a
rig logs it (1 kHz, ms, degrees, rpm, mN·m, mm, angle, speed and torque counted the other way,
one run per episode) and imported as `crank import` does; and a rig whose controller evaluates
the closed-loop law faster than the plan's rate (`fast_controller_runs`)."""

from __future__ import annotations

import copy
import csv
from pathlib import Path

import mujoco
import numpy as np

from control.ocp_file import read_ocp
from replay.campaign import Replay, draw_machines, play
from replay.config import ReplayConfig
from twin.physics import STATE_SPEC, SliderCrank
from twin.rig_import import ImportSpec, import_table
from twin.variability import apply

MAP = "t=time_ms,theta=enc_deg,omega=speed_rpm,tau=cmd_mNm,slider_position=x_mm,episode=run"
UNITS = "t=ms,theta=deg,omega=rpm,tau=mN*m,slider_position=mm"
FLIP = "theta,omega,tau"
SPEC = ImportSpec.parse(columns=MAP, units=UNITS, flip=FLIP)


def play_runs(
    physics: SliderCrank, ocp_path: Path, *, profile: str, mode: str, runs: int, seed: int
) -> Replay:
    """`profile` of `ocp_path` played on `runs` twin machines of the replay streams at `seed`."""
    config = ReplayConfig(runs=runs, seed=seed)
    ocp = read_ocp(ocp_path)
    machines = draw_machines(config, ocp.horizon)
    return play(physics, ocp, profile=profile, mode=mode, machines=machines, config=config)


def write_rig_csv(
    replay: Replay,
    path: Path,
    *,
    lead: int = 0,
    keep: int | None = None,
    machines: list[int] | None = None,
) -> Path:
    """Each run as a 1 kHz rig logs it: a row at every sample and one midway (states
    interpolated, the torque held), after `lead` samples at rest at its start angle with no
    torque, its first `keep` samples only if given; runs 1 s apart; with `machines`, each run's
    machine id in a column `unit`."""
    rows = []
    for run in range(replay.runs):
        series = [replay.theta[run], replay.omega[run], replay.slider_position[run]]
        tau = replay.tau[run]
        if keep is not None:
            series, tau = [s[:keep] for s in series], tau[:keep]
        theta, omega, slider = (
            np.r_[np.full(lead, s[0] if i != 1 else 0.0), s] for i, s in enumerate(series)
        )
        tau = np.r_[np.zeros(lead), tau]
        fine = np.arange(2 * len(theta) - 1) / 2.0
        index = np.arange(len(theta))
        columns = (
            1e3 * (2e-3 * fine + run),
            -np.degrees(np.interp(fine, index, theta)),
            -np.interp(fine, index, omega) * 60 / (2 * np.pi),
            -1e3 * tau[np.floor(fine).astype(int)],
            1e3 * np.interp(fine, index, slider),
            np.full(len(fine), run),
            *(() if machines is None else (np.full(len(fine), machines[run]),)),
        )
        rows += zip(*(c.tolist() for c in columns), strict=True)
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        header = ["time_ms", "enc_deg", "speed_rpm", "cmd_mNm", "x_mm", "run"]
        writer.writerow(header + ([] if machines is None else ["unit"]))
        writer.writerows(rows)
    return path


def import_runs(
    replay: Replay, out: Path, *, machines: list[int] | None = None, **options: int | None
) -> Path:
    """The runs of `replay` as a rig's table (write_rig_csv `options`), imported to `out`; with
    `machines`, each run's machine id in its machine column."""
    table = write_rig_csv(replay, out.with_suffix(".csv"), machines=machines, **options)
    spec = (
        SPEC
        if machines is None
        else ImportSpec.parse(columns=MAP + ",machine=unit", units=UNITS, flip=FLIP)
    )
    import_table(table, out, spec=spec)
    return out


def fast_controller_runs(
    physics: SliderCrank, ocp_path: Path, out: Path, *, profile: str, per_sample: int, runs: int
) -> Path:
    """`profile`'s closed-loop law run `per_sample` times a sample on `runs` drawn twin machines
    (no disturbance), each row's reference and gains held over its sample, logged at the
    controller's rate in the contract's units and imported to `out`."""
    ocp = read_ocp(ocp_path)
    plan, limit = ocp.profiles[profile], ocp.config.torque_limit
    gains = [np.append(g, g[-1]) for g in (plan.gain_theta, plan.gain_omega)]
    config = ReplayConfig(runs=runs, seed=4)
    machines = draw_machines(config, ocp.horizon)
    motor = physics.layout.actuator["motor_torque"]
    state = np.empty(mujoco.mj_stateSize(physics.model, STATE_SPEC))
    rows = []
    for run, draw in enumerate(machines.draws):
        model = copy.copy(physics.model)
        friction = config.variability.friction_at(draw, float(machines.start_times[run]))
        apply(model, draw=draw, friction=friction, layout=physics.layout)
        data = mujoco.MjData(model)
        start = physics.initial_state(plan.theta[0], plan.omega[0])
        mujoco.mj_setState(model, data, start, STATE_SPEC)
        for k in range(ocp.horizon):
            for j in range(per_sample):
                mujoco.mj_getState(model, data, state, STATE_SPEC)
                theta = float(physics.qpos(state, "motor"))  # a view of `state` otherwise
                omega = float(physics.qvel(state, "motor"))
                feedback = gains[0][k] * (plan.theta[k] - theta) + gains[1][k] * (
                    plan.omega[k] - omega
                )
                u = float(np.clip(plan.tau[k] + feedback, -limit, limit))
                rows.append((ocp.dt * (k + j / per_sample) + run, theta, omega, u, run))
                data.ctrl[motor] = u
                for _ in range(physics.substeps // per_sample):
                    mujoco.mj_step(model, data)
    table = out.with_suffix(".csv")
    with table.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["t", "theta", "omega", "tau", "run"])
        writer.writerows(rows)
    spec = ImportSpec.parse(columns="t=t,theta=theta,omega=omega,tau=tau,episode=run")
    import_table(table, out, spec=spec)
    return out
