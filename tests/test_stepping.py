"""The native batched path equals a plain mj_step loop bit for bit, and samples are aligned."""

from __future__ import annotations

import copy
import os

import mujoco
import numpy as np
import pytest

from common.errors import ConfigError
from common.threads import ENVIRONMENT
from twin.physics import STATE_SPEC, SliderCrank
from twin.stepping import (
    Stepper,
    chunk_bounds,
    chunk_time,
    rollout_threads,
    set_rollout_threads,
    simulate,
    simulate_batches,
)
from twin.variability import Variability, apply


def _inputs(physics: SliderCrank, n_runs: int, n: int, seed: int):
    rng = np.random.default_rng(seed)
    variability = Variability()
    draws = [variability.sample(rng) for _ in range(n_runs)]
    states = np.array([physics.initial_state(rng.uniform(0, 2 * np.pi)) for _ in range(n_runs)])
    tau = rng.uniform(-6, 6, (n_runs, n))
    tau[:, ::7] = 12.0  # beyond the torque limit: both paths must clip alike
    disturbance = variability.disturbance(rng, n_runs * n).reshape(n_runs, n)
    return variability, draws, states, tau, disturbance


def _reference(physics, variability, draws, states, tau, disturbance, chunk):
    """A plain Python mj_step loop: same models, drift schedule and sample-held controls."""
    layout = physics.layout
    n_runs, n = tau.shape
    sensordata = np.empty((n_runs, n, physics.model.nsensordata))
    qpos_at_sample = np.empty((n_runs, n, physics.model.nq))
    for i in range(n_runs):
        model = copy.copy(physics.model)
        data = mujoco.MjData(model)
        mujoco.mj_setState(model, data, states[i], STATE_SPEC)
        for start, stop in chunk_bounds(n, chunk):
            friction = variability.friction_at(draws[i], chunk_time(start, stop))
            apply(model, draw=draws[i], friction=friction, layout=layout)
            for k in range(start, stop):
                qpos_at_sample[i, k] = data.qpos
                data.ctrl[layout.actuator["motor_torque"]] = tau[i, k]
                data.ctrl[layout.actuator["slider_disturbance"]] = disturbance[i, k]
                for s in range(physics.substeps):
                    mujoco.mj_step(model, data)
                    if s == 0:  # sensors of the first substep are evaluated at t_k
                        sensordata[i, k] = data.sensordata
    return sensordata, qpos_at_sample


def test_native_rollout_equals_mj_step_loop(physics: SliderCrank) -> None:
    variability, draws, states, tau, disturbance = _inputs(physics, n_runs=3, n=300, seed=7)
    chunk = 40
    runs = simulate(
        physics,
        variability,
        draws=draws,
        initial_states=states,
        tau=tau,
        disturbance=disturbance,
        chunk_samples=chunk,
        nthread=2,
    )
    expected, _ = _reference(physics, variability, draws, states, tau, disturbance, chunk)
    assert np.array_equal(runs.sensordata, expected)
    assert np.all(np.abs(runs.tau) <= physics.torque_limit)


def test_sample_k_holds_the_state_at_t_k(physics: SliderCrank) -> None:
    """MuJoCo's one-step sensor lag is handled: theta[k] is the motor qpos at t = k dt."""
    variability, draws, states, tau, disturbance = _inputs(physics, n_runs=1, n=100, seed=3)
    runs = simulate(
        physics,
        variability,
        draws=draws,
        initial_states=states,
        tau=tau,
        disturbance=disturbance,
        chunk_samples=100,
    )
    _, qpos = _reference(physics, variability, draws, states, tau, disturbance, 100)
    theta = physics.sensor(runs.sensordata[0], "theta")
    assert np.array_equal(theta, qpos[0, :, physics.layout.qpos["motor"]])
    assert theta[0] == physics.qpos(states[0], "motor")


def test_chunking_does_not_change_a_trajectory_without_drift(physics: SliderCrank) -> None:
    _, draws, states, tau, disturbance = _inputs(physics, n_runs=2, n=200, seed=5)
    still = Variability(drift=False)
    a = simulate(
        physics,
        still,
        draws=draws,
        initial_states=states,
        tau=tau,
        disturbance=disturbance,
        chunk_samples=200,
    )
    b = simulate(
        physics,
        still,
        draws=draws,
        initial_states=states,
        tau=tau,
        disturbance=disturbance,
        chunk_samples=13,
        nthread=1,
    )
    assert np.array_equal(a.sensordata, b.sensordata)
    assert np.array_equal(a.final_state, b.final_state)


@pytest.mark.parametrize("closed", [False, True])
def test_batches_of_runs_equal_one_call_bit_for_bit(physics: SliderCrank, closed: bool) -> None:
    """A long check plays its machines a batch at a time (progress): the same runs, in order,
    to the last bit, open loop and under a law acting on each run's state alone."""
    variability, draws, states, tau, disturbance = _inputs(physics, n_runs=7, n=60, seed=11)
    starts = np.linspace(0.0, 50.0, 7)
    motor = physics.layout.qpos["motor"]

    def law(k: int, x: np.ndarray) -> np.ndarray:
        return -2.0 * (x[:, motor] - 0.01 * k)

    common = dict(
        initial_states=states,
        tau=tau,
        disturbance=disturbance,
        start_times=starts,
        chunk_samples=60,
        feedback=law if closed else None,
    )
    whole = simulate(physics, variability, draws=draws, **common)
    played: list[int] = []
    parts = simulate_batches(
        physics, variability, batch=3, draws=draws, on_batch=played.append, **common
    )
    assert played == [3, 3, 1]
    for field in ("sensordata", "tau", "disturbance", "final_state"):
        assert np.array_equal(getattr(parts, field), getattr(whole, field)), field
    assert parts.friction.keys() == whole.friction.keys()
    for name, values in whole.friction.items():
        assert np.array_equal(parts.friction[name], values), name
    assert not np.array_equal(whole.sensordata[0], whole.sensordata[3])  # machines differ
    with pytest.raises(ValueError, match="batch must be >= 1"):
        simulate_batches(physics, variability, batch=0, draws=draws, **common)


def test_drift_lowers_friction_over_time(physics: SliderCrank) -> None:
    variability, draws, states, tau, disturbance = _inputs(physics, n_runs=1, n=2500, seed=1)
    runs = simulate(
        physics, variability, draws=draws, initial_states=states, tau=tau, disturbance=disturbance
    )
    motor = runs.friction["motor_frictionloss"][0]
    assert motor[0] < draws[0].motor_frictionloss
    assert np.all(np.diff(motor) <= 0) and motor[-1] < motor[0]
    expected = 1 - draws[0].warmup_drop * (1 - np.exp(-chunk_time(2250, 2500) / 20.0))
    assert motor[-1] == draws[0].motor_frictionloss * expected


def test_the_process_default_sets_a_rollout_s_threads_and_not_its_result(
    physics: SliderCrank, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`set_rollout_threads` is what a rollout steps on when its caller does not say (a sweep's
    Ray worker sets 1); an explicit count still wins, None gives every core back, and the
    trajectories are the same bit for bit on one thread as on two."""
    monkeypatch.delenv(ENVIRONMENT, raising=False)  # the test suite's workers set it
    variability, draws, states, tau, disturbance = _inputs(physics, n_runs=3, n=120, seed=11)

    def run(**threads):
        return simulate(
            physics,
            variability,
            draws=draws,
            initial_states=states,
            tau=tau,
            disturbance=disturbance,
            **threads,
        )

    try:
        set_rollout_threads(1)
        assert rollout_threads() == 1 and Stepper(physics).nthread == 1
        assert Stepper(physics, nthread=2).nthread == 2
        one = run()
        set_rollout_threads(None)
        assert rollout_threads() == (os.cpu_count() or 1)
        two = run(nthread=2)
    finally:
        set_rollout_threads(None)
    assert np.array_equal(one.sensordata, two.sensordata)
    assert np.array_equal(one.final_state, two.final_state)


@pytest.mark.parametrize("count", [0, -1, 1.5, True, "2"])
def test_a_rollout_thread_count_must_be_a_positive_integer(
    count: object, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv(ENVIRONMENT, raising=False)
    with pytest.raises(ValueError, match="rollout threads must be an integer >= 1, got"):
        set_rollout_threads(count)  # type: ignore[arg-type]
    assert rollout_threads() == (os.cpu_count() or 1)


def test_the_environment_gives_the_default_that_a_set_count_overrides(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """$CRANK_ROLLOUT_THREADS is a process's default (a command started beside others; the
    suite's workers set 1); `set_rollout_threads` wins over it; a bad value is refused naming
    the variable."""
    monkeypatch.setenv(ENVIRONMENT, "3")
    assert rollout_threads() == 3
    try:
        set_rollout_threads(2)
        assert rollout_threads() == 2
    finally:
        set_rollout_threads(None)
    assert rollout_threads() == 3
    for bad in ("0", "two", "1.5", "", "-2", "²"):
        monkeypatch.setenv(ENVIRONMENT, bad)
        with pytest.raises(ConfigError, match=r"\$CRANK_ROLLOUT_THREADS must be an integer >= 1"):
            rollout_threads()
