"""Replay campaigns: the OCP's torque profiles played on many freshly drawn twins (paper 3.5).

Every run is one machine of the product line: its friction, damping, backlash and warm-up drop
drawn from the twin's `Variability`, how long it has been running before the replay (so where its
warm-up drift stands), and its own white slider force. All runs start at rest at the OCP's θ₁.

The same machines (same draws, start times and disturbances) serve every profile and mode, so
nominal against robust and open against closed loop are paired comparisons.

Modes:
  open    the torque as computed (the paper's experiment).
  closed  the torque plus a tracking law on the measured (θ, ω) of the PPANN's predicted
          trajectory, u_k = τ_k + K_θ,k (θ̂_k − θ_k) + K_ω,k (ω̂_k − ω_k), saturated at the
          torque limit, computed at every 2 ms sample from the state at t_k only. K_k are the
          profile's own gains from ocp.json (`feedback="lqr"`, the default: its LQR,
          control/lqr.py, or robust-pd's fixed PD), or a fixed PD (`feedback="pd"`: K_p, K_d).
  mpc     an online MPC on the PPANN mean tracking the profile (control/mpc.py): one
          real-time iteration per machine per 2 ms sample, inside the twin's stepping loop,
          from the measured (θ, ω); each step's compute time is recorded (`MPCRecord`), and a
          step over the deadline applies the shifted previous solution.

Random streams (common/streams.py): replay_machines spawns one child per run (machine, start
time), replay_noise one per run (disturbance); changing the number of runs leaves the first runs
as they were. Held-out machines come from heldout_machines and heldout_noise instead.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from common.streams import stream
from control.config import lower_tail
from control.mpc_config import MPCConfigError
from control.ocp_file import OCPFile, Profile
from ppann.transmission import LEVELS as TRANSMISSION_LEVELS
from replay.config import ReplayConfig
from replay.laws import closed_loop_gains, played_gains, predicted_sigma
from twin.physics import SliderCrank
from twin.stepping import simulate_batches
from twin.variability import MachineDraw

if TYPE_CHECKING:
    from control.mpc import SliderLimit
    from ppann.model import PPANN


@dataclass(frozen=True)
class Machines:
    """The machines of a campaign, one per run."""

    draws: list[MachineDraw]
    start_times: np.ndarray
    """Seconds each machine has run before its replay, (runs,)."""
    disturbance: np.ndarray
    """Slider force per sample, (runs, n_samples)."""


@dataclass(frozen=True)
class MPCRecord:
    """Every MPC step of a replay, (runs, n_samples): one per machine per sample, but none at
    the last sample (no state of the plan is left to predict; the plan's torque is applied)."""

    seconds: np.ndarray
    """Compute time of the step, s (NaN where there was no step)."""
    missed: np.ndarray
    """The step overran the deadline and the shifted previous solution was applied."""
    qp_iterations: np.ndarray
    horizon: int
    deadline: float
    engine: str
    """What evaluated the predictions: "compiled" (C) or "vm" (CasADi's virtual machine)."""
    gains: np.ndarray
    """The LQR the MPC is while no bound is active (N-1, 2): its weights' Riccati gains along
    the plan (control/mpc.py), the law its closed-loop prediction uses."""


@dataclass(frozen=True)
class Replay:
    """One profile played in one mode on every machine. Arrays are (runs, n_samples); index k − 1
    is the OCP's sample k (t = (k − 1) Ts)."""

    profile: str
    mode: str
    theta: np.ndarray
    omega: np.ndarray
    slider_position: np.ndarray
    tau: np.ndarray
    """Torque actually applied from t_k to t_{k+1}, N·m (after feedback and saturation)."""
    crank_angle: np.ndarray
    backlash_angle: np.ndarray
    loop_closure_error: np.ndarray
    disturbance: np.ndarray
    friction: dict[str, np.ndarray]
    mpc: MPCRecord | None = None
    """What the MPC's steps took (mpc mode only)."""
    predicted_sigma: np.ndarray | None = None
    """The PPANN's slider σ (N,), m, under the law played (replay/laws.py predicted_sigma): set
    by `run_campaign`; None where that law is not the profile's own and no PPANN was given."""

    @property
    def runs(self) -> int:
        return self.theta.shape[0]


@dataclass(frozen=True)
class Campaign:
    config: ReplayConfig
    machines: Machines
    replays: dict[tuple[str, str], Replay]
    """(profile, mode) → what happened."""
    wall_time: float = 0.0
    """Seconds spent simulating (all profiles and modes)."""


def draw_machines(config: ReplayConfig, n_samples: int, *, held_out: bool = False) -> Machines:
    """The campaign's machines, start times and disturbances, from its seed.

    Campaign machines come from the streams replay_machines and replay_noise, held-out machines
    (`held_out=True`) from heldout_machines and heldout_noise: neither ever equals a dataset's
    machine, nor each other, whatever the seeds (common/streams.py).
    """
    kind = "heldout" if held_out else "replay"
    machine_children = stream(config.seed, f"{kind}_machines").spawn(config.runs)
    noise_children = stream(config.seed, f"{kind}_noise").spawn(config.runs)
    draws, starts, forces = [], [], []
    for machine_child, noise_child in zip(machine_children, noise_children, strict=True):
        machine_rng, start_rng = (np.random.default_rng(s) for s in machine_child.spawn(2))
        draws.append(config.variability.sample(machine_rng))
        starts.append(start_rng.uniform(0.0, config.max_start_time))
        forces.append(config.variability.disturbance(np.random.default_rng(noise_child), n_samples))
    return Machines(draws=draws, start_times=np.array(starts), disturbance=np.array(forces))


def tracking_law(
    physics: SliderCrank, profile: Profile, config: ReplayConfig
) -> Callable[[int, np.ndarray], np.ndarray]:
    """Feedback on the encoder angle and speed, tracking the profile's predicted states with
    `closed_loop_gains` (after the last gain, the last one is held)."""
    gains = closed_loop_gains(profile, config)
    last = len(gains) - 1

    def law(k: int, states: np.ndarray) -> np.ndarray:
        theta = physics.qpos(states, "motor")
        omega = physics.qvel(states, "motor")
        kp, kd = gains[min(k, last)]
        return kp * (profile.theta[k] - theta) + kd * (profile.omega[k] - omega)

    return law


def slider_limit(ocp: OCPFile, model: PPANN) -> SliderLimit:
    """The OCP's slider height at its constraint samples for the MPC's QP, with the crank's
    angle to the motor at its quantiles Φ(∓k_sigma) (the OCP's confidence; the model's
    transmission quantiles, ppann/transmission.py)."""
    from control.mpc import SliderLimit

    level = lower_tail(ocp.config.k_sigma)
    quantiles = model.transmission.detach().numpy()
    return SliderLimit(
        geometry=ocp.geometry,
        height=ocp.config.height,
        samples=tuple(k - 1 for k in ocp.config.constraint_samples),
        delta_low=float(np.interp(level, TRANSMISSION_LEVELS, quantiles)),
        delta_high=float(np.interp(1.0 - level, TRANSMISSION_LEVELS, quantiles)),
    )


def mpc_law(
    physics: SliderCrank, ocp: OCPFile, profile: Profile, model: PPANN, config: ReplayConfig
) -> tuple[Callable[[int, np.ndarray], np.ndarray], MPCRecord]:
    """One online MPC per machine, tracking `profile` on the PPANN mean, and the record its
    steps fill in as the twin calls the law (control/mpc.py)."""
    from control.dynamics import CasadiPPANN  # CasADi: only when an MPC is played
    from control.mpc import TrackingMPC

    controller = TrackingMPC(
        CasadiPPANN(model).step,
        states=np.stack([profile.theta, profile.omega], axis=-1),
        tau=profile.tau,
        torque_limit=ocp.config.torque_limit,
        config=config.mpc,
        slider=slider_limit(ocp, model) if config.mpc.slider_limit else None,
    )
    shape = (config.runs, ocp.horizon)
    record = MPCRecord(
        seconds=np.full(shape, np.nan),
        missed=np.zeros(shape, dtype=bool),
        qp_iterations=np.zeros(shape, dtype=int),
        horizon=config.mpc.horizon,
        deadline=config.mpc.deadline,
        engine=controller.engine,
        gains=controller.gains,
    )
    guesses = np.tile(controller.start(), (config.runs, 1))

    def law(k: int, states: np.ndarray) -> np.ndarray:
        theta = physics.qpos(states, "motor")
        omega = physics.qvel(states, "motor")
        out = np.zeros(config.runs)
        if k >= ocp.horizon - 1:
            return out  # after the last state of the plan: its last torque
        for i in range(config.runs):
            step, guesses[i] = controller.step(k, np.array([theta[i], omega[i]]), guesses[i])
            out[i] = step.torque - profile.tau[k]
            record.seconds[i, k] = step.seconds
            record.missed[i, k] = step.missed
            record.qp_iterations[i, k] = step.qp_iterations
        return out

    return law, record


def _counting_steps(
    law: Callable[[int, np.ndarray], np.ndarray],
    n_runs: int,
    n_samples: int,
    on_machines: Callable[[int], None],
) -> Callable[[int, np.ndarray], np.ndarray]:
    """`law`, reporting after sample k the machines' worth of steps it completes: of
    n_runs·(k + 1)/n_samples, rounded down, what was not reported before (n_runs in all)."""
    reported = 0

    def counted(k: int, states: np.ndarray) -> np.ndarray:
        nonlocal reported
        torque = law(k, states)
        worth = n_runs * (k + 1) // n_samples
        if worth > reported:
            on_machines(worth - reported)
            reported = worth
        return torque

    return counted


def play(
    physics: SliderCrank,
    ocp: OCPFile,
    *,
    profile: str,
    mode: str,
    machines: Machines,
    config: ReplayConfig,
    nthread: int | None = None,
    model: PPANN | None = None,
    batch: int | None = None,
    on_machines: Callable[[int], None] | None = None,
) -> Replay:
    """Play one profile of `ocp` on every machine, open or closed loop or under the MPC, in one
    native batch (`model`: the PPANN the MPC predicts with, needed in mpc mode only), or open
    and closed loop `batch` machines at a time, `on_machines(machines just played)` after
    each: the same result bit for bit (twin/stepping.py `simulate_batches`). The MPC, a solver
    per machine, plays every machine in one batch, step by step; `on_machines` then counts the
    machines' worth of steps done (all machines at sample k of n: k/n of them), so that a
    progress bar moves through the minutes a thousand MPCs take.

    Each machine's friction is evaluated once, at the middle of its replay (the warm-up time
    constant, 20 s, is 70× the 0.3 s replay).
    """
    chosen: Profile = ocp.profiles[profile]
    n_runs, n_samples = config.runs, ocp.horizon
    state0 = physics.initial_state(ocp.config.theta_start, ocp.config.omega_start)
    feedback, record = None, None
    if mode == "closed":
        feedback = tracking_law(physics, chosen, config)
    elif mode == "mpc":
        if model is None:
            raise MPCConfigError("the mpc mode needs the PPANN the plan was solved on")
        feedback, record = mpc_law(physics, ocp, chosen, model, config)
        if on_machines is not None:
            feedback, on_machines = _counting_steps(feedback, n_runs, n_samples, on_machines), None
    runs = simulate_batches(
        physics,
        config.variability,
        batch=n_runs if batch is None or mode == "mpc" else batch,
        draws=machines.draws,
        initial_states=np.tile(state0, (n_runs, 1)),
        tau=np.tile(chosen.tau, (n_runs, 1)),
        disturbance=machines.disturbance,
        start_times=machines.start_times,
        chunk_samples=n_samples,
        nthread=nthread,
        feedback=feedback,
        on_batch=on_machines,
    )
    sd = runs.sensordata
    theta = physics.sensor(sd, "theta")
    backlash = physics.sensor(sd, "backlash_angle")
    return Replay(
        profile=profile,
        mode=mode,
        theta=theta,
        omega=physics.sensor(sd, "omega"),
        slider_position=physics.sensor(sd, "slider_position"),
        tau=runs.tau,
        crank_angle=theta + backlash,
        backlash_angle=backlash,
        loop_closure_error=physics.loop_closure_error(sd),
        disturbance=runs.disturbance,
        friction=runs.friction,
        mpc=record,
    )


def run_campaign(
    physics: SliderCrank,
    ocp: OCPFile,
    *,
    config: ReplayConfig,
    machines: Machines | None = None,
    nthread: int | None = None,
    on_replay: Callable[[Replay], None] | None = None,
    model: PPANN | None = None,
    on_machines: Callable[[int], None] | None = None,
) -> Campaign:
    """Play every profile of `ocp` in every configured mode on the same machines (default:
    drawn from the config's seed), each with the PPANN's slider σ under the law it played
    (`model`: the plan's PPANN; the mpc mode needs it, and so does the prediction of a law
    other than the profile's own); `on_replay` sees each (profile, mode) as soon as it is
    simulated (the campaign log writes it then), `on_machines` its machines as they are played
    (`play`'s: the MPC's step by step)."""
    machines = machines if machines is not None else draw_machines(config, ocp.horizon)
    heads = None
    if model is not None:
        from ppann.heads import FusedHeads

        heads = FusedHeads(model)
    replays = {}
    simulating = 0.0
    for profile in ocp.names:
        for mode in config.modes:
            started = time.perf_counter()
            replay = play(
                physics,
                ocp,
                profile=profile,
                mode=mode,
                machines=machines,
                config=config,
                nthread=nthread,
                model=model,
                on_machines=on_machines,
            )
            simulating += time.perf_counter() - started
            mpc_gains = None if replay.mpc is None else replay.mpc.gains
            gains = played_gains(ocp.profiles[profile], mode, config, mpc_gains=mpc_gains)
            sigma = predicted_sigma(ocp, profile, gains, heads=heads)
            replay = replace(replay, predicted_sigma=sigma)
            replays[profile, mode] = replay
            if on_replay is not None:
                on_replay(replay)
    return Campaign(
        config=config,
        machines=machines,
        replays=replays,
        wall_time=simulating,
    )
