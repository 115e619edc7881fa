"""Native batched stepping of the twin: many machines at once in MuJoCo's compiled rollout.

Each run has its own copy of the model (its machine draw) and its own torque and disturbance
profiles, one value per 2 ms sample held over the physics substeps. Time is cut into chunks; before
each chunk every run's model receives the friction its machine has at that moment (warm-up drift),
then `mujoco.rollout` advances all runs through the chunk in C++ threads.

Sample alignment (MuJoCo's one-step sensor lag): `mj_step` evaluates sensors on the state it starts
from, before integrating. The sensordata of physics step k·S (S substeps per sample) is therefore
the state at t = k·Δt exactly, and it is what sample k holds; `tau[k]` is the torque applied over
the S steps from t_k to t_{k+1}.

Because the MJCF disables solver warm-starting, a trajectory does not depend on where it is cut
into chunks, and it equals a plain `mj_step` loop bit for bit (tests/test_stepping.py).

`simulate_batches` plays the runs a batch at a time (progress on long checks), equal to one call
bit for bit for the same reason.

Closed loop: with a `feedback` law the rollout advances one sample at a time; before sample k the
law sees every run's state at t_k and returns a torque added to `tau[:, k]` (then clipped). With
a law that returns zeros the result equals the open-loop one bit for bit.

The threads a rollout runs on by default are the process's (`common.threads`, re-exported here
as `set_rollout_threads` and `rollout_threads`).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from typing import Any

import mujoco
import numpy as np
from mujoco import rollout

from common.threads import rollout_threads, set_rollout_threads
from twin.physics import SAMPLE_RATE, STATE_SPEC, SliderCrank
from twin.variability import FrictionState, MachineDraw, Variability, apply


@dataclass(frozen=True)
class Runs:
    """What a batch of runs produced. Arrays have shape (n_runs, n_samples) unless noted."""

    sensordata: np.ndarray
    """Sensor readings at t_k, shape (n_runs, n_samples, nsensordata)."""
    tau: np.ndarray
    """Motor torque applied from t_k to t_{k+1} (after clipping to the actuator range)."""
    disturbance: np.ndarray
    """Slider disturbance force applied from t_k to t_{k+1}."""
    friction: dict[str, np.ndarray]
    """FrictionState field name → value in effect from t_k to t_{k+1}."""
    final_state: np.ndarray
    """Full-physics state at t_{n_samples}, shape (n_runs, nstate)."""


class Stepper:
    """Advances a batch of runs through sample-held controls in MuJoCo's native rollout."""

    def __init__(self, physics: SliderCrank, *, nthread: int | None = None) -> None:
        self.physics = physics
        self.nthread = max(1, nthread if nthread is not None else rollout_threads())
        self._data = [mujoco.MjData(physics.model) for _ in range(self.nthread)]

    def step(
        self, models: Sequence[mujoco.MjModel], states: np.ndarray, controls: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Step every run through its controls.

        Args:
          models: one model per run.
          states: initial full-physics states, (n_runs, nstate).
          controls: per-sample controls, (n_runs, n_samples, nu), each held for S substeps.

        Returns:
          sensordata at the start of every sample, (n_runs, n_samples, nsensordata), and the
          final states, (n_runs, nstate).
        """
        s = self.physics.substeps
        held = np.repeat(controls, s, axis=1)
        state, sensordata = rollout.rollout(
            list(models),
            self._data[: min(self.nthread, len(models))],
            states,
            held,
            control_spec=mujoco.mjtState.mjSTATE_CTRL,
        )
        return sensordata[:, ::s], state[:, -1]


def chunk_bounds(n_samples: int, chunk_samples: int) -> list[tuple[int, int]]:
    """[start, stop) sample ranges of the native rollout calls."""
    return [(a, min(a + chunk_samples, n_samples)) for a in range(0, n_samples, chunk_samples)]


def chunk_time(start: int, stop: int) -> float:
    """Time (s) at which a chunk's drift is evaluated: its midpoint."""
    return 0.5 * (start + stop) / SAMPLE_RATE


def simulate(
    physics: SliderCrank,
    variability: Variability,
    *,
    draws: Sequence[MachineDraw],
    initial_states: np.ndarray,
    tau: np.ndarray,
    disturbance: np.ndarray,
    start_times: np.ndarray | None = None,
    chunk_samples: int = 250,
    nthread: int | None = None,
    on_chunk: Callable[[int], None] | None = None,
    feedback: Callable[[int, np.ndarray], np.ndarray] | None = None,
) -> Runs:
    """Run one machine per draw through its torque and disturbance, natively and in chunks.

    Args:
      physics: the twin's model; it is copied once per run and never modified.
      variability: gives the friction of each machine over time (drift).
      draws: the machine of each run, length n_runs.
      initial_states: full-physics states, (n_runs, nstate).
      tau: motor torque per sample, (n_runs, n_samples).
      disturbance: slider force per sample, (n_runs, n_samples).
      start_times: how long each machine has been running at sample 0, (n_runs,); default 0.
      chunk_samples: samples per native rollout call; the drift is held constant over one.
      nthread: rollout threads (default: `twin.stepping.rollout_threads()`, all cores unless set).
      on_chunk: called with the number of samples just completed, for progress reporting.
      feedback: closed-loop law `(k, states at t_k (n_runs, nstate)) -> torque (n_runs,)`, added
        to `tau[:, k]` before clipping; `Runs.tau` then holds the torque actually applied.
    """
    n_runs, n_samples = tau.shape
    if len(draws) != n_runs or disturbance.shape != tau.shape:
        raise ValueError(
            f"need one draw and one disturbance row per run: {len(draws)} draws, "
            f"tau {tau.shape}, disturbance {disturbance.shape}"
        )
    if initial_states.shape != (n_runs, physics.layout.nstate):
        raise ValueError(
            f"initial_states must have shape {(n_runs, physics.layout.nstate)}, "
            f"got {initial_states.shape}"
        )
    if chunk_samples < 1:
        raise ValueError(f"chunk_samples must be >= 1, got {chunk_samples}")
    start_times = np.zeros(n_runs) if start_times is None else np.asarray(start_times, float)

    layout = physics.layout
    limit = physics.torque_limit
    motor = layout.actuator["motor_torque"]
    tau = np.clip(tau, -limit, limit) if feedback is None else np.array(tau, dtype=float)
    controls = np.zeros((n_runs, n_samples, physics.model.nu))
    controls[..., motor] = tau
    controls[..., layout.actuator["slider_disturbance"]] = disturbance

    models = [copy.copy(physics.model) for _ in range(n_runs)]
    stepper = Stepper(physics, nthread=nthread)
    sensordata = np.empty((n_runs, n_samples, physics.model.nsensordata))
    friction = {f.name: np.empty((n_runs, n_samples)) for f in fields(FrictionState)}
    state = np.array(initial_states, dtype=float)

    for start, stop in chunk_bounds(n_samples, chunk_samples):
        t_mid = chunk_time(start, stop)
        for i, (model, draw) in enumerate(zip(models, draws, strict=True)):
            now = variability.friction_at(draw, float(start_times[i]) + t_mid)
            apply(model, draw=draw, friction=now, layout=layout)
            for name, values in friction.items():
                values[i, start:stop] = getattr(now, name)
        if feedback is None:
            sensordata[:, start:stop], state = stepper.step(models, state, controls[:, start:stop])
        else:
            for k in range(start, stop):
                tau[:, k] = np.clip(tau[:, k] + feedback(k, state), -limit, limit)
                controls[:, k, motor] = tau[:, k]
                sensordata[:, k : k + 1], state = stepper.step(
                    models, state, controls[:, k : k + 1]
                )
        if on_chunk is not None:
            on_chunk(stop - start)

    return Runs(
        sensordata=sensordata,
        tau=tau,
        disturbance=np.asarray(disturbance, dtype=float),
        friction=friction,
        final_state=state,
    )


def simulate_batches(
    physics: SliderCrank,
    variability: Variability,
    *,
    batch: int,
    draws: Sequence[MachineDraw],
    initial_states: np.ndarray,
    tau: np.ndarray,
    disturbance: np.ndarray,
    start_times: np.ndarray | None = None,
    feedback: Callable[[int, np.ndarray], np.ndarray] | None = None,
    on_batch: Callable[[int], None] | None = None,
    **options: Any,
) -> Runs:
    """`simulate` on at most `batch` runs at a time, in order, the batches' results joined:
    equal to one call bit for bit (each run has its own model, and the MJCF's solver does not
    warm-start), with `on_batch(runs just played)` after each batch, for progress on long
    checks. A `feedback` law must act on each run's state alone, as the tracking laws do (the
    MPC's, which keeps a solver per machine, needs the one call). `options`: `simulate`'s."""
    if batch < 1:
        raise ValueError(f"batch must be >= 1, got {batch}")
    n_runs = tau.shape[0]
    starts = np.zeros(n_runs) if start_times is None else np.asarray(start_times, float)
    parts = []
    for a in range(0, n_runs, batch):
        b = min(a + batch, n_runs)
        parts.append(
            simulate(
                physics,
                variability,
                draws=draws[a:b],
                initial_states=initial_states[a:b],
                tau=tau[a:b],
                disturbance=disturbance[a:b],
                start_times=starts[a:b],
                feedback=feedback,
                **options,
            )
        )
        if on_batch is not None:
            on_batch(b - a)
    if len(parts) == 1:
        return parts[0]
    return Runs(
        sensordata=np.concatenate([r.sensordata for r in parts]),
        tau=np.concatenate([r.tau for r in parts]),
        disturbance=np.concatenate([r.disturbance for r in parts]),
        friction={k: np.concatenate([r.friction[k] for r in parts]) for k in parts[0].friction},
        final_state=np.concatenate([r.final_state for r in parts]),
    )


__all__ = [
    "STATE_SPEC",
    "Runs",
    "Stepper",
    "chunk_bounds",
    "chunk_time",
    "rollout_threads",
    "set_rollout_threads",
    "simulate",
    "simulate_batches",
]
