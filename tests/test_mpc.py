"""The online MPC (control/mpc.py) against exact answers: the TV-LQR law on a linear system, the
closed-form one-step law, exact tracking of a plan of the model itself, the torque limit, the
deadline rule and the slider limit (its box QP: tests/test_boxqp.py)."""

from __future__ import annotations

import hashlib
import json
import shutil
from collections import OrderedDict
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

import control.mpc as mpc_module
from control.compiled import Workshop
from control.dynamics import CasadiPPANN
from control.lqr import LQRWeights, riccati
from control.mpc import SliderLimit, TrackingMPC, prediction_function
from control.mpc_config import MPCConfig, MPCConfigError
from control.ocp_file import OCPFile, read_ocp
from ppann.checkpoint import CheckpointError
from ppann.model import constant_ppann
from replay.campaign import draw_machines, play
from replay.config import ReplayConfig
from replay.files import replay_file
from tests.checkpoints import constant_checkpoint
from tests.conftest import LATE
from twin.physics import SliderCrank

DT = 2e-3


def _linear_step(a: np.ndarray, b: np.ndarray) -> ca.Function:
    x, u = ca.SX.sym("x", 2), ca.SX.sym("u")
    return ca.Function("linear_step", [x, u], [ca.mtimes(ca.DM(a), x) + ca.DM(b) * u])


def _linear_plan(a, b, n, rng):
    tau = rng.uniform(-1.0, 1.0, n)
    states = np.zeros((n, 2))
    for k in range(n - 1):
        states[k + 1] = a @ states[k] + b * tau[k]
    return states, tau


@pytest.mark.parametrize("horizon", [1, 5, 30])
def test_mpc_on_a_linear_system_is_the_tv_lqr_law(horizon: int) -> None:
    """No bound active, terminal cost the Riccati cost-to-go: the first torque is
    u_k = û_k - K_k (x_k - x̂_k) of the finite-horizon LQR, to 1e-9, at every sample including
    those where the horizon shrinks at the end of the plan; the warm start does not matter."""
    a = np.array([[1.0, DT], [-DT * 4.0, 1.0 - DT * 0.3]])
    b = np.array([0.0, DT / 3e-3])
    n = 60
    rng = np.random.default_rng(1)
    states, tau = _linear_plan(a, b, n, rng)
    config = MPCConfig(horizon=horizon, compiled=False, deadline=LATE)
    mpc = TrackingMPC(_linear_step(a, b), states=states, tau=tau, torque_limit=1e6, config=config)
    weights = LQRWeights(q_theta=config.q_theta, q_omega=config.q_omega, r=config.r)
    gains, _ = riccati(np.repeat(a[None], n - 1, 0), np.repeat(b[None], n - 1, 0), weights)
    np.testing.assert_allclose(mpc.gains, gains, rtol=1e-12)  # the held-out check predicts with it
    for k in range(n - 1):
        x = states[k] + rng.normal(scale=[0.05, 1.0])
        guess = rng.uniform(-5.0, 5.0, horizon)
        step, _ = mpc.step(k, x, guess)
        expected = tau[k] - gains[k] @ (x - states[k])
        assert step.torque == pytest.approx(expected, rel=1e-9, abs=1e-9)


def _ppann_plan(dynamics: CasadiPPANN, n: int) -> tuple[np.ndarray, np.ndarray]:
    """A plan that is a trajectory of the model itself: its rollout of a smooth torque."""
    t = np.arange(n) * DT
    tau = 3.0 * np.sin(2 * np.pi * 4.0 * t) + 1.0
    states = dynamics.rollout(np.array([np.pi, 0.0]), tau[:-1])
    return states, tau


def _model():
    return CasadiPPANN(constant_ppann(z_mean=(0.1, -0.2, -0.9), z_sigma=(0.03, 0.05, 0.05)))


def test_horizon_one_is_the_closed_form_one_step_law() -> None:
    """H = 1: the map is affine in u, f(x, u) = f(x, 0) + b u, so the MPC's torque is
    û + b^T P (x̂_{k+1} - f(x, û)) / (r + b^T P b) with P the cost-to-go at k + 1, exactly; at
    the last step (P = Q) with q_theta = r = 0 it is the torque that puts ω on the plan."""
    dynamics = _model()
    n = 80
    states, tau = _ppann_plan(dynamics, n)
    config = MPCConfig(horizon=1, compiled=False, deadline=LATE)
    mpc = TrackingMPC(dynamics.step, states=states, tau=tau, torque_limit=100.0, config=config)
    rng = np.random.default_rng(2)

    def f(x, u):
        return dynamics.step(x, u).full().ravel()

    for k in (0, 17, 40, n - 2):
        x = states[k] + rng.normal(scale=[0.03, 0.5])
        b = f(x, 1.0) - f(x, 0.0)
        p = mpc.costs[k + 1]
        expected = tau[k] + b @ p @ (states[k + 1] - f(x, tau[k])) / (config.r + b @ p @ b)
        step, _ = mpc.step(k, x, np.array([tau[k]]))
        assert step.torque == pytest.approx(expected, rel=1e-9)
    deadbeat = TrackingMPC(
        dynamics.step,
        states=states,
        tau=tau,
        torque_limit=100.0,
        config=MPCConfig(horizon=1, q_theta=0.0, q_omega=1.0, r=0.0, compiled=False, deadline=LATE),
    )
    x = states[n - 2] + np.array([0.02, -0.7])
    step, _ = deadbeat.step(n - 2, x, np.array([0.0]))
    assert f(x, step.torque)[1] == pytest.approx(states[n - 1, 1], abs=1e-9)


def test_mpc_tracks_a_plan_of_its_own_model() -> None:
    """The plant is the model (no disturbance): from the plan's start the MPC applies the
    plan's torques (to 1e-9); from a start 50 mrad off it brings the state back onto the plan
    (within 1e-5 rad and 1e-3 rad/s at the end; 50 mrad, 0 rad/s at the start)."""
    dynamics = _model()
    n = 150
    states, tau = _ppann_plan(dynamics, n)
    mpc = TrackingMPC(
        dynamics.step,
        states=states,
        tau=tau,
        torque_limit=100.0,
        config=MPCConfig(compiled=False, deadline=LATE),
    )
    for offset, check in ((0.0, "exact"), (0.05, "converges")):
        x, guess, applied = states[0] + [offset, 0.0], mpc.start(), []
        for k in range(n - 1):
            step, guess = mpc.step(k, x, guess)
            applied.append(step.torque)
            x = dynamics.step(x, step.torque).full().ravel()
        if check == "exact":
            np.testing.assert_allclose(applied, tau[:-1], atol=1e-9)
        else:
            assert abs(x[0] - states[-1, 0]) < 1e-5 and abs(x[1] - states[-1, 1]) < 1e-3
            assert abs(applied[0] - tau[0]) > 1.0  # it did have to correct


@pytest.mark.skipif(shutil.which("gcc") is None, reason="no C compiler here")
def test_compiled_prediction_equals_the_virtual_machine_and_falls_back_without_a_compiler(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    dynamics = _model()
    monkeypatch.chdir(tmp_path)
    workshop = Workshop()
    compiled, engine = prediction_function(dynamics.step, 12, workshop=workshop)
    assert list(tmp_path.iterdir()) == []  # sources and library in the workshop's folder
    vm, vm_engine = prediction_function(dynamics.step, 12)
    assert (engine, vm_engine) == ("compiled", "vm")
    rng = np.random.default_rng(5)
    for _ in range(5):
        x, u = np.array([rng.uniform(0, 12), rng.uniform(-30, 30)]), rng.uniform(-5, 5, 12)
        for a, b in zip(compiled(x, u), vm(x, u), strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-12)
    monkeypatch.setenv("PATH", "/nonexistent")  # no C compiler to be found
    assert prediction_function(dynamics.step, 12, workshop=Workshop())[1] == "vm"


def test_the_mpcs_of_one_model_share_one_prediction_and_play_the_same(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Two plans of one model (two CasadiPPANN of it: the same content), one horizon: one
    prediction function built; another model or horizon builds its own. An MPC on the shared
    function steps bit for bit as one on a function of its own."""
    monkeypatch.setattr(mpc_module, "_kept", OrderedDict())
    built: list[int] = []

    def counted(step, horizon, *, workshop=None):
        built.append(horizon)
        return prediction_function(step, horizon, workshop=workshop)

    monkeypatch.setattr(mpc_module, "prediction_function", counted)
    model = constant_ppann(z_mean=(0.1, -0.2, -0.9), z_sigma=(0.03, 0.05, 0.05))
    first, second = CasadiPPANN(model), CasadiPPANN(model)
    config = MPCConfig(horizon=8, compiled=False, deadline=LATE)
    states, tau = _ppann_plan(first, 60)
    mpcs = [
        TrackingMPC(d.step, states=s, tau=t, torque_limit=100.0, config=config)
        for d, (s, t) in ((first, (states, tau)), (second, (states[::-1], tau[::-1])))
    ]
    assert built == [8] and mpcs[0].predict is mpcs[1].predict
    other = CasadiPPANN(constant_ppann(z_mean=(0.2, -0.2, -0.9), z_sigma=(0.03, 0.05, 0.05)))
    TrackingMPC(other.step, states=states, tau=tau, torque_limit=100.0, config=config)
    shorter = MPCConfig(horizon=5, compiled=False, deadline=LATE)
    TrackingMPC(first.step, states=states, tau=tau, torque_limit=100.0, config=shorter)
    assert built == [8, 8, 5]
    own = TrackingMPC(first.step, states=states, tau=tau, torque_limit=100.0, config=config)
    own.predict, _ = prediction_function(first.step, 8)
    assert own.predict is not mpcs[0].predict
    x, guesses = states[0] + [0.2, -1.0], [mpcs[0].start(), own.start()]
    for k in range(59):
        (a, guesses[0]), (b, guesses[1]) = (
            m.step(k, x, g) for m, g in zip((mpcs[0], own), guesses, strict=True)
        )
        assert (a.torque, a.qp_iterations) == (b.torque, b.qp_iterations), k
        assert np.array_equal(guesses[0], guesses[1]), k
        x = first.step(x, a.torque).full().ravel()


def test_mpc_respects_the_torque_limit_and_the_deadline_rule() -> None:
    dynamics = _model()
    n = 100
    states, tau = _ppann_plan(dynamics, n)
    limit = 4.5  # the plan peaks at 4 N·m: a 0.3 rad offset asks for more
    mpc = TrackingMPC(
        dynamics.step,
        states=states,
        tau=tau,
        torque_limit=limit,
        config=MPCConfig(compiled=False, deadline=LATE),
    )
    x, guess, applied = states[0] + [0.3, 0.0], mpc.start(), []
    for k in range(n - 1):
        step, guess = mpc.step(k, x, guess)
        applied.append(step.torque)
        x = dynamics.step(x, step.torque).full().ravel()
    applied = np.array(applied)
    assert np.all(np.abs(applied) <= limit + 1e-12)
    assert np.abs(applied[0]) == pytest.approx(limit, abs=1e-12)  # the bound was active,
    free = TrackingMPC(  # where the same MPC without the bound asks for more
        dynamics.step,
        states=states,
        tau=tau,
        torque_limit=100.0,
        config=MPCConfig(compiled=False, deadline=LATE),
    )
    assert abs(free.step(0, states[0] + [0.3, 0.0], free.start())[0].torque) > limit + 1.0
    # every step over a deadline of 1 ns: each applies the shifted previous solution, which
    # from the first warm start on is the plan itself
    late = TrackingMPC(
        dynamics.step,
        states=states,
        tau=tau,
        torque_limit=limit,
        config=MPCConfig(deadline=1e-9, compiled=False),
    )
    x, guess = states[0] + [0.3, 0.0], late.start()
    for k in range(n - 1):
        step, guess = late.step(k, x, guess)
        assert step.missed and step.torque == tau[k]
        x = dynamics.step(x, step.torque).full().ravel()


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"q_theta": -1.0}, "q_theta must be >= 0"),
        ({"r": float("nan")}, "r must be a finite number"),
        ({"r": 0.0, "q_omega": 0.0}, "not determined"),
        ({"horizon": 0}, "horizon"),
        ({"deadline": 0.0}, "deadline must be > 0"),
    ],
)
def test_bad_mpc_settings_are_refused(options: dict, message: str) -> None:
    with pytest.raises(MPCConfigError, match=message):
        MPCConfig(**options)


def test_a_horizon_longer_than_the_plan_is_refused() -> None:
    dynamics = _model()
    states, tau = _ppann_plan(dynamics, 20)
    with pytest.raises(MPCConfigError, match="longer than the plan's 19 steps"):
        TrackingMPC(
            dynamics.step,
            states=states,
            tau=tau,
            torque_limit=10.0,
            config=MPCConfig(horizon=20, compiled=False),
        )


def test_mpc_mode_replays_on_the_twin_and_logs_every_step(
    ocp_path: Path,
    tmp_path: Path,
    physics: SliderCrank,
) -> None:
    """The mpc mode inside the twin's stepping loop: the torque stays within the limit, the
    MPC holds the runs nearer the plan than open loop, each step's time is in the stats and in
    the log's /slider_crank/mpc channel (one message per machine and step); a plan whose
    checkpoint is another file is refused before anything is written."""
    from mcap.reader import make_reader

    checkpoint = tmp_path / "m.pt"
    constant_checkpoint(checkpoint)
    raw = json.loads(ocp_path.read_text())
    raw["model"] = {
        "path": "m.pt",
        "sha256": hashlib.sha256(checkpoint.read_bytes()).hexdigest(),
        "kind": "ppann",
    }
    plan = tmp_path / "ocp.json"
    plan.write_text(json.dumps(raw))
    runs = 3
    config = ReplayConfig(runs=runs, seed=7, modes=("open", "mpc"), mpc=MPCConfig(horizon=10))
    stats = replay_file(plan, tmp_path / "r.mcap", config=config)
    horizon = read_ocp(plan).horizon
    for profile in ("nominal", "robust"):
        mpc, open_loop = stats["profiles"][profile]["mpc"], stats["profiles"][profile]["open"]
        timing = mpc["mpc"]
        assert timing["steps"] == runs * (horizon - 1) and timing["horizon"] == 10
        assert 0 < timing["median_ms"] <= timing["p99_ms"] <= timing["max_ms"]
        assert mpc["tracking"]["theta_rms"] < 0.5 * open_loop["tracking"]["theta_rms"]
    with (tmp_path / "r.mcap").open("rb") as f:
        steps = [
            json.loads(message.data)
            for _, channel, message in make_reader(f).iter_messages(topics=["/slider_crank/mpc"])
        ]
    assert len(steps) == 2 * runs * (horizon - 1)
    assert {s["mode"] for s in steps} == {"mpc"} and all(s["step_ms"] > 0 for s in steps)
    assert sum(s["missed"] for s in steps) == sum(
        stats["profiles"][p]["mpc"]["mpc"]["deadline_misses"] for p in ("nominal", "robust")
    )
    # the plan solved on another checkpoint
    raw["model"]["sha256"] = "0" * 64
    plan.write_text(json.dumps(raw))
    before = sorted(tmp_path.iterdir())
    with pytest.raises(CheckpointError, match="is not the checkpoint"):
        replay_file(plan, tmp_path / "other.mcap", config=config)
    assert sorted(tmp_path.iterdir()) == before


def test_mpc_applied_torque_is_within_the_twin_limit_on_every_sample(
    ocp: OCPFile,
    physics: SliderCrank,
) -> None:
    model = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))
    config = ReplayConfig(runs=4, seed=3, modes=("mpc",), mpc=MPCConfig(horizon=5))
    machines = draw_machines(config, ocp.horizon)
    replay = play(
        physics, ocp, profile="robust", mode="mpc", machines=machines, config=config, model=model
    )
    assert np.all(np.abs(replay.tau) <= ocp.config.torque_limit + 1e-12)
    assert replay.mpc is not None and np.isnan(replay.mpc.seconds[:, -1]).all()
    assert np.isfinite(replay.mpc.seconds[:, :-1]).all()


@pytest.mark.parametrize(("bias", "delta"), [(-0.3, 0.0), (0.3, 0.0), (-0.3, -0.01)])
def test_slider_limit_holds_the_height_against_an_unmodelled_torque(
    bias: float, delta: float
) -> None:
    """A plan that sits exactly on the slider's height at one sample, and a plant that is the
    model plus a constant torque the MPC does not know. Tracking only, the bias that lowers the
    slider leaves it 0.2 mm below the height; with the limit in the QP the slider misses by no
    more than what the bias does in the one step no torque can answer any more (the angle of
    the next sample is set by the speed now: dt² |bias| / J times the slope), and where the bias
    raises the slider the limit is slack and changes nothing. With the crank allowed to lag
    the motor by 10 mrad (`delta_low`, the slider rising there), the MPC holds the lagging
    crank's slider at the height, so the motor's own runs that much higher."""
    model = constant_ppann(z_mean=(0.1, -0.2, -0.9), z_sigma=(0.03, 0.05, 0.05))
    dynamics = CasadiPPANN(model)
    n, c = 100, 60
    states, tau = _ppann_plan(dynamics, n)
    position = model.geometry.slider_position
    height = float(position(states[c, 0]))
    limit = SliderLimit(geometry=model.geometry, height=height, samples=(c,), delta_low=delta)
    ends = {}
    for name, slider in (("tracking", None), ("limited", limit)):
        mpc = TrackingMPC(
            dynamics.step,
            states=states,
            tau=tau,
            torque_limit=100.0,
            config=MPCConfig(deadline=LATE, compiled=False),
            slider=slider,
        )
        x, guess = states[0].copy(), mpc.start()
        for k in range(c):
            step, guess = mpc.step(k, x, guess)
            x = dynamics.step(x, step.torque + bias).full().ravel()
        ends[name] = float(position(x[0] + (delta if slider else 0.0))) - height
    inertia = float(model.physical[0]) * 1.1  # J (1 + z_J)
    slope = abs(float(position(states[c, 0] + 1e-6) - position(states[c, 0] - 1e-6)) / 2e-6)
    one_step = slope * DT**2 * abs(bias) / inertia
    if bias < 0:
        assert ends["tracking"] < -1e-4
        assert -1.5 * one_step <= ends["limited"] < 0.0
    else:
        assert ends["tracking"] > 1e-4
        assert ends["limited"] == pytest.approx(ends["tracking"], abs=1e-12)
