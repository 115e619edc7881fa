"""The synthetic ocp.json the replay tests play (tests/conftest.py `ocp_path`): a torque that
swings the nominal twin's crank from rest at θ = π over top dead centre, with the twin's own
states as the predicted ones; 'robust' pushes 10 % harder."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import mujoco
import numpy as np

from control.config import OCPConfig
from control.ocp_file import FORMAT, INDEX_CONVENTION, VERSION
from twin.geometry import PAPER
from twin.physics import STATE_SPEC, SliderCrank
from twin.variability import Variability, apply

N = 150


def nominal_twin_trajectory(physics: SliderCrank, tau: np.ndarray) -> np.ndarray:
    """(θ, ω) of the nominal machine without disturbance under `tau`, sample by sample."""
    model = copy.copy(physics.model)
    nominal = Variability.none()
    draw = nominal.nominal()
    apply(model, draw=draw, friction=nominal.friction_at(draw, 0.0), layout=physics.layout)
    data = mujoco.MjData(model)
    mujoco.mj_setState(model, data, physics.initial_state(np.pi, 0.0), STATE_SPEC)
    motor = physics.layout.actuator["motor_torque"]
    states = np.empty((len(tau), 2))
    for k, u in enumerate(tau):
        state = twin_state(model, data)
        states[k] = physics.qpos(state, "motor"), physics.qvel(state, "motor")
        data.ctrl[motor] = u
        for _ in range(physics.substeps):
            mujoco.mj_step(model, data)
    return states


def twin_state(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    state = np.empty(mujoco.mj_stateSize(model, STATE_SPEC))
    mujoco.mj_getState(model, data, state, STATE_SPEC)
    return state


def _profile(tau: np.ndarray, states: np.ndarray, sigma: float) -> dict:
    slider = PAPER.slider_position(states[:, 0])
    return {
        "time": (np.arange(N) / 500).tolist(),
        "tau": tau.tolist(),
        "theta": states[:, 0].tolist(),
        "omega": states[:, 1].tolist(),
        "slider": slider.tolist(),
        "slider_mc_mean": slider.tolist(),
        "slider_sigma": [sigma] * N,
        "slider_lower": (slider - 3 * sigma).tolist(),
        "slider_upper": (slider + 3 * sigma).tolist(),
        "slider_sigma_open": [sigma] * N,
        "slider_sigma_closed": [sigma / 10] * N,
        "heights": [0.08, 0.08],
        "gain_theta": (30 + 10 * np.sin(np.arange(N - 1) / 20)).tolist(),
        "gain_omega": (0.6 + 0.2 * np.cos(np.arange(N - 1) / 30)).tolist(),
        "cost": float(np.sum(tau**2)),
        "status": "Solve_Succeeded",
        "ipopt_iterations": 10,
        "wall_time_s": 0.1,
        "loop": "open",
    }


def write_ocp(path: Path, physics: SliderCrank) -> Path:
    """Write the synthetic ocp.json to `path` and return it."""
    t = np.arange(N) / 500
    base = 2.5 * np.cos(2 * np.pi * t / 0.3) + 0.6
    payload = {
        "format": FORMAT,
        "version": VERSION,
        "index_convention": INDEX_CONVENTION,
        "dt": 1 / 500,
        "horizon": N,
        "constraint_samples": [50, 100],
        "config": OCPConfig().as_dict(),
        "model": {"path": "synthetic", "sha256": "", "kind": "ppann"},
        "geometry": physics.geometry.as_dict(),
        "profiles": ["nominal", "robust"],
    }
    for name, tau, sigma in (("nominal", base, 0.006), ("robust", 1.1 * base, 0.004)):
        payload[name] = _profile(tau, nominal_twin_trajectory(physics, tau), sigma)
    path.write_text(json.dumps(payload))
    return path
