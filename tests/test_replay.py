"""Replay campaigns: exact equality with plain mj_step loops, the closed loop, the held-out check
and the statistics (the synthetic ocp.json: tests/replay_ocp.py)."""

from __future__ import annotations

import copy
import json
from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest

from common.streams import stream
from control.config import PD_GAINS
from control.dynamics import CasadiPPANN
from control.lqr import LQRWeights, tracking_gains
from control.ocp_file import OCPFile
from control.tightening import sigma_relative_se
from ppann.heads import FusedHeads
from ppann.model import PPANN, constant_ppann
from ppann.montecarlo import Feedback, monte_carlo
from replay.campaign import _counting_steps, draw_machines, play, run_campaign
from replay.config import ReplayConfig
from replay.heldout import heldout_check, heldout_file
from replay.model_rate import model_rate
from replay.placement import placement
from replay.spread_interval import ratio_interval
from replay.statistics import campaign_statistics, replay_statistics
from tests.checkpoints import constant_checkpoint
from tests.conftest import LATE_MPC
from tests.replay_ocp import N, nominal_twin_trajectory, twin_state
from twin.geometry import PAPER
from twin.physics import STATE_SPEC, SliderCrank
from twin.stepping import chunk_time
from twin.variability import Variability, apply


def test_each_loop_of_the_file_has_its_own_monte_carlo(ocp: OCPFile) -> None:
    """open is the open-loop spread; closed the closed loop's under the profile's own gains,
    which the fixture makes a tenth of it. The MPC is another law (replay/laws.py), which the
    file has no spread for (replay/laws.py predicts it)."""
    robust = ocp.profiles["robust"]
    np.testing.assert_array_equal(robust.sigma_in("open"), np.full(N, 0.004))
    np.testing.assert_array_equal(robust.sigma_in("closed"), np.full(N, 0.0004))
    with pytest.raises(ValueError, match="'mpc': open or closed"):
        robust.sigma_in("mpc")


def _reference_run(physics, config, machines, i, profile, *, feedback: bool) -> dict:
    """One run as a plain Python mj_step loop: its own model, friction at the replay's middle,
    and (closed loop) the tracking law (the profile's gains, or config's PD) computed from the
    state at t_k."""
    layout = physics.layout
    model = copy.copy(physics.model)
    draw = machines.draws[i]
    start = float(machines.start_times[i])
    friction = config.variability.friction_at(draw, start + chunk_time(0, N))
    apply(model, draw=draw, friction=friction, layout=layout)
    data = mujoco.MjData(model)
    mujoco.mj_setState(model, data, physics.initial_state(np.pi, 0.0), STATE_SPEC)
    theta, slider, tau = np.empty(N), np.empty(N), np.empty(N)
    limit = physics.torque_limit
    for k in range(N):
        u = profile.tau[k]
        if feedback:
            state = twin_state(model, data)
            kp, kd = profile.gain_theta[min(k, N - 2)], profile.gain_omega[min(k, N - 2)]
            if config.feedback == "pd":
                kp, kd = config.kp, config.kd
            u += kp * (profile.theta[k] - physics.qpos(state, "motor")) + kd * (
                profile.omega[k] - physics.qvel(state, "motor")
            )
        tau[k] = np.clip(u, -limit, limit)
        data.ctrl[layout.actuator["motor_torque"]] = tau[k]
        data.ctrl[layout.actuator["slider_disturbance"]] = machines.disturbance[i, k]
        for s in range(physics.substeps):
            mujoco.mj_step(model, data)
            if s == 0:
                theta[k] = physics.sensor(data.sensordata, "theta")
                slider[k] = physics.sensor(data.sensordata, "slider_position")
    return {"theta": theta, "slider": slider, "tau": tau}


def test_zero_variability_replays_one_trajectory_equal_to_direct_simulation(
    physics: SliderCrank, ocp: OCPFile
) -> None:
    config = ReplayConfig(runs=3, variability=Variability.none())
    machines = draw_machines(config, N)
    replay = play(physics, ocp, profile="nominal", mode="open", machines=machines, config=config)
    direct = nominal_twin_trajectory(physics, ocp.nominal.tau)
    for run in range(3):
        np.testing.assert_array_equal(replay.theta[run], direct[:, 0])
        np.testing.assert_array_equal(replay.omega[run], direct[:, 1])
    # and the ocp.json was built from the same simulation, so the replay is its prediction
    np.testing.assert_array_equal(replay.theta[0], ocp.nominal.theta)


@pytest.mark.parametrize(
    ("mode", "feedback"), [("open", "lqr"), ("closed", "lqr"), ("closed", "pd")]
)
def test_batched_replay_equals_a_per_run_mj_step_loop(
    physics: SliderCrank, ocp: OCPFile, mode: str, feedback: str
) -> None:
    config = ReplayConfig(runs=4, seed=3, feedback=feedback, kp=40.0, kd=0.8)
    machines = draw_machines(config, N)
    replay = play(physics, ocp, profile="robust", mode=mode, machines=machines, config=config)
    for i in range(config.runs):
        ref = _reference_run(
            physics, config, machines, i, ocp.profiles["robust"], feedback=mode == "closed"
        )
        np.testing.assert_array_equal(replay.theta[i], ref["theta"])
        np.testing.assert_array_equal(replay.slider_position[i], ref["slider"])
        np.testing.assert_array_equal(replay.tau[i], ref["tau"])


def test_closed_loop_with_zero_gains_equals_open_loop(physics: SliderCrank, ocp: OCPFile) -> None:
    config = ReplayConfig(runs=5, seed=1, feedback="pd", kp=0.0, kd=0.0)
    machines = draw_machines(config, N)
    kwargs = {"profile": "nominal", "machines": machines, "config": config}
    open_loop = play(physics, ocp, mode="open", **kwargs)
    closed = play(physics, ocp, mode="closed", **kwargs)
    for name in ("theta", "omega", "slider_position", "tau", "crank_angle"):
        np.testing.assert_array_equal(getattr(closed, name), getattr(open_loop, name))


def test_closed_loop_feedback_uses_the_measurements_and_tracks(
    physics: SliderCrank, ocp: OCPFile
) -> None:
    config = ReplayConfig(runs=20, seed=2)
    machines = draw_machines(config, N)
    kwargs = {"profile": "nominal", "machines": machines, "config": config}
    open_loop = play(physics, ocp, mode="open", **kwargs)
    closed = play(physics, ocp, mode="closed", **kwargs)
    # u_k - tau_k is the profile's LQR law on the encoder readings of sample k (where not
    # saturated; the last gain is held for sample N)
    gain_theta = np.append(ocp.nominal.gain_theta, ocp.nominal.gain_theta[-1])
    gain_omega = np.append(ocp.nominal.gain_omega, ocp.nominal.gain_omega[-1])
    law = gain_theta * (ocp.nominal.theta - closed.theta) + gain_omega * (
        ocp.nominal.omega - closed.omega
    )
    unsaturated = np.abs(closed.tau) < physics.torque_limit
    np.testing.assert_allclose(
        (closed.tau - ocp.nominal.tau)[unsaturated], law[unsaturated], rtol=0, atol=1e-12
    )
    # feedback shrinks the machine-to-machine spread of the angle at the end by > 5x
    assert closed.theta[:, -1].std() < open_loop.theta[:, -1].std() / 5
    # each row is compared with the PPANN's prediction of its own loop, never the other's
    campaign = run_campaign(
        physics, ocp, config=replace(config, modes=("open", "closed")), machines=machines
    )
    for mode, sigma in (
        ("open", ocp.nominal.slider_sigma_open),
        ("closed", ocp.nominal.slider_sigma_closed),
    ):
        row = replay_statistics(campaign.replays["nominal", mode], ocp)
        for sample, entry in row["constraint"].items():
            assert entry["predicted_k_sigma"] == 3 * sigma[int(sample) - 1]
    assert not np.array_equal(ocp.nominal.slider_sigma_open, ocp.nominal.slider_sigma_closed)


@pytest.mark.parametrize(
    ("modes", "feedback", "pd"),
    [
        (("open",), "lqr", PD_GAINS),
        (("closed",), "lqr", PD_GAINS),
        (("closed", "open"), "lqr", PD_GAINS),
        (("closed",), "pd", PD_GAINS),
        (("closed",), "pd", (10.0, 0.25)),
        (("mpc",), "lqr", PD_GAINS),
    ],
)
def test_heldout_check_plays_and_predicts_every_profile_in_its_mode(
    physics: SliderCrank,
    ocp_path: Path,
    ocp: OCPFile,
    modes: tuple[str, ...],
    feedback: str,
    pd: tuple[float, float],
) -> None:
    """Every profile of the held-out check is played in each loop asked for, on the same
    machines, and predicted by a Monte-Carlo of that loop: the observed spread equals a direct
    replay's in that mode, and the prediction equals a Monte-Carlo under the profile's gains
    (closed; with feedback "pd" the fixed PD asked for, the default one or another), under the
    LQR the MPC is without active bounds (mpc: its weights' gains along the plan, not the
    file's), or none (open). (A loop variable once shadowed the mode, and the second profile was
    played open loop; the MPC was once predicted with the file's gains, a PD for robust-pd; the
    check once played the default PD whatever the run's was.) The robust profile's verdict is of
    its own loop, open, when played."""
    model = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))
    variability = Variability.scenario("paper")
    result = heldout_check(
        physics,
        ocp_path,
        model,
        runs=8,
        seed=11,
        variability=variability,
        mc_samples=50,
        tail_draws=300,
        modes=modes,
        feedback=feedback,
        kp=pd[0],
        kd=pd[1],
        mpc=LATE_MPC,
    )
    assert result["modes"] == list(modes) and result["feedback"] == feedback
    assert result["pd"] == {"kp": pd[0], "kd": pd[1]}
    assert list(result["holds"]) == (["robust"] if "open" in modes else [])
    for name in result["holds"]:  # 8 machines confirm no rate of 0.5 %
        below = result["profiles"][name]["open"]["violating_runs"]
        assert result["verdicts"][name] == ("unconfirmed" if below == 0 else "fails")
    for mode, name in ((m, n) for m in modes for n in ocp.names):
        entry = result["profiles"][name][mode]
        _check_heldout_entry(physics, ocp, model, entry, name, mode, feedback=feedback, pd=pd)


def test_heldout_check_in_batches_of_machines_equals_one_batch(
    physics: SliderCrank, ocp_path: Path, ocp: OCPFile
) -> None:
    """A long check plays its machines a batch at a time, open and closed loop, reporting each
    batch (`crank heldout`'s progress) after saying once what it will play: heldout.json the
    same to the last bit but its timing; the MPC, a solver per machine, plays all its machines
    at once, step by step, and reports the machines' worth of steps done: with 8 machines and
    more samples than that, one machine's worth at a time, 8 in all."""
    model = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))
    kwargs = dict(
        runs=8,
        seed=11,
        variability=Variability.scenario("paper"),
        mc_samples=50,
        tail_draws=300,
        modes=("open", "closed", "mpc"),
        mpc=LATE_MPC,
    )
    whole = heldout_check(physics, ocp_path, model, **kwargs)
    played: list[tuple] = []
    batched = heldout_check(
        physics,
        ocp_path,
        model,
        batch=3,
        on_start=lambda solved, modes: played.append((solved.names, modes)),
        on_machines=lambda name, mode, n: played.append((name, mode, n)),
        **kwargs,
    )
    loops = [(n, m) for n in ocp.names for m in ("open", "closed", "mpc")]
    expected = [(n, m, k) for n, m in loops for k in ((1,) * 8 if m == "mpc" else (3, 3, 2))]
    assert played == [(ocp.names, ("open", "closed", "mpc")), *expected]
    for result in (whole, batched):  # the compute times differ from run to run
        for name in ocp.names:
            assert result["profiles"][name]["mpc"].pop("mpc")["deadline_misses"] == 0
        del result["timing"]
    assert json.dumps(batched, sort_keys=True) == json.dumps(whole, sort_keys=True)


def test_mpc_progress_counts_machines_worth_of_steps_as_they_are_played() -> None:
    """8 machines over 150 samples: one machine's worth after samples 19, 38, 57, 75, 94, 113,
    132 and 150 (8·k/150 crossing each whole number), each reported as its step is played, and
    the law's torques passed through unchanged."""
    reports: list[tuple[int, int]] = []
    step = [-1]

    def law(k: int, states: np.ndarray) -> np.ndarray:
        step[0] = k
        return states[:, 0] * k

    counted = _counting_steps(law, 8, 150, lambda n: reports.append((step[0], n)))
    states = np.arange(16.0).reshape(8, 2)
    for k in range(150):
        np.testing.assert_array_equal(counted(k, states), states[:, 0] * k)
    assert reports == [(k, 1) for k in (18, 37, 56, 74, 93, 112, 131, 149)]
    bigger: list[int] = []
    many = _counting_steps(law, 1000, 150, bigger.append)
    for k in range(150):
        many(k, states)
    assert sum(bigger) == 1000 and len(bigger) == 150  # 6 or 7 machines' worth a sample


def _check_heldout_entry(
    physics: SliderCrank,
    ocp: OCPFile,
    model: PPANN,
    result: dict,
    name: str,
    mode: str,
    *,
    feedback: str,
    pd: tuple[float, float],
) -> None:
    """One profile's held-out entry in `mode` against a direct replay and Monte-Carlo."""
    variability = Variability.scenario("paper")
    config = ReplayConfig(
        runs=8,
        seed=11,
        modes=(mode,),
        variability=variability,
        feedback=feedback,
        kp=pd[0],
        kd=pd[1],
        mpc=LATE_MPC,
    )
    machines = draw_machines(config, N, held_out=True)
    profile = ocp.profiles[name]
    replay = play(
        physics, ocp, profile=name, mode=mode, machines=machines, config=config, model=model
    )
    states = np.stack([profile.theta, profile.omega], axis=-1)
    own = np.stack([profile.gain_theta, profile.gain_omega], axis=-1)
    law = None
    if mode != "open":
        gains = own
        if feedback == "pd":
            gains = np.tile(pd, (N - 1, 1))
        if mode == "mpc":
            weights = LQRWeights(q_theta=LATE_MPC.q_theta, q_omega=LATE_MPC.q_omega, r=LATE_MPC.r)
            gains = tracking_gains(CasadiPPANN(model).step_on_turn, states, profile.tau, weights)
            assert np.abs(gains - own).max() > 1.0  # the file's gains would be another law
        law = Feedback(states, gains, ocp.config.torque_limit)
    bands = monte_carlo(
        model,
        [profile.theta[0], profile.omega[0]],
        profile.tau[:-1],
        n_samples=50,
        mode="mixed",
        seed=stream(ocp.config.mc_seed, "monte_carlo"),
        feedback=law,
    )
    for k, entry in result["samples"].items():
        x = replay.slider_position[:, int(k) - 1]
        assert entry["observed_sigma"] == float(x.std(ddof=1))
        low, high = entry["observed_sigma_ci95"]
        assert low < entry["observed_sigma"] < high
        predicted = PAPER.slider_position(bands.samples[:, int(k) - 1, 0]).std(ddof=1)
        assert entry["predicted"]["mixed"]["sigma"] == pytest.approx(predicted, rel=1e-9)
        ratio = entry["predicted"]["mixed"]
        slider = PAPER.slider_position(bands.samples[:, int(k) - 1, 0])
        assert ratio["sigma_se"] == pytest.approx(predicted * sigma_relative_se(slider), rel=1e-9)
        assert ratio["ratio_ci95"] == pytest.approx(
            ratio_interval(
                predicted,
                entry["observed_sigma"],
                (low, high),
                predicted_relative_se=sigma_relative_se(slider),
            ),
            rel=1e-9,
        )
        outer = (ratio["sigma"] / high, ratio["sigma"] / low)  # the machines' interval alone
        assert ratio["ratio_ci95"][0] < outer[0] and ratio["ratio_ci95"][1] > outer[1]
        theta = replay.theta[:, int(k) - 1].std(ddof=1)
        assert entry["theta"]["observed_sigma"] == float(theta)
        theta_predicted = bands.samples[:, int(k) - 1, 0].std(ddof=1)
        assert entry["theta"]["predicted"]["mixed"]["sigma"] == pytest.approx(
            theta_predicted, rel=1e-12
        )
        assert entry["theta"]["predicted"]["mixed"]["ratio"] == pytest.approx(
            theta_predicted / theta, rel=1e-12
        )
        assert entry["theta"]["observed_mean"] == float(replay.theta[:, int(k) - 1].mean())
        assert entry["theta"]["predicted"]["mixed"]["mean"] == pytest.approx(
            bands.samples[:, int(k) - 1, 0].mean(), rel=1e-12
        )
    assert result["theta_final"]["observed_sigma"] == float(replay.theta[:, -1].std(ddof=1))
    # the machines below, by index: those of the direct replay of the same machines
    index = np.array(ocp.config.constraint_samples) - 1
    below = (replay.slider_position[:, index] < ocp.config.height).any(axis=1)
    assert result["violating_machines"] == np.flatnonzero(below).tolist()
    assert len(result["violating_machines"]) == result["violating_runs"]
    # and where each sits in the line: its draws, its start, its force to the last sample
    last = max(ocp.config.constraint_samples)
    for machine, where in zip(
        result["violating_machines"], result["violating_placements"], strict=True
    ):
        expected = placement(
            machines.draws[machine],
            variability,
            force=machines.disturbance[machine][:last],
            start_s=float(machines.start_times[machine]),
            max_start_s=config.max_start_time,
        )
        assert where == expected
    # the model's own rate below the height: its Monte-Carlo of the same loop, 300 draws
    tail = monte_carlo(
        model,
        [profile.theta[0], profile.omega[0]],
        profile.tau[:-1],
        n_samples=300,
        mode=ocp.config.mc_mode,
        seed=stream(ocp.config.mc_seed, "monte_carlo"),
        feedback=law,
    )
    index = np.array(ocp.config.constraint_samples) - 1
    below = PAPER.slider_position(tail.samples[:, index, 0]) < ocp.config.height
    rate = result["model_rate"]
    assert (rate["draws"], rate["mode"]) == (300, ocp.config.mc_mode)
    assert rate["rate"] == below.any(axis=1).mean()
    assert rate["samples"] == {str(k): below[:, j].mean() for j, k in enumerate(index + 1)}


def testmodel_rate_is_the_share_of_its_own_draws_below_the_height(ocp: OCPFile) -> None:
    """heldout.json's model_rate at a height set to the median of the same Monte-Carlo's slider
    at sample 50 is one half there (its own draws, exactly), and the rate at any sample is at
    least the largest per-sample rate and at most their sum."""
    model = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))
    profile = ocp.profiles["robust"]
    config = replace(ocp.config, constraint_samples=(50, 100))
    bands = monte_carlo(
        model,
        [profile.theta[0], profile.omega[0]],
        profile.tau[:-1],
        n_samples=400,
        mode=config.mc_mode,
        seed=stream(config.mc_seed, "monte_carlo"),
    )
    slider = PAPER.slider_position(bands.samples[:, [49, 99], 0])
    config = replace(config, height=float(np.median(slider[:, 0])))
    rate = model_rate(FusedHeads(model), profile, config, n_samples=400, law=None)
    assert rate["samples"]["50"] == 0.5
    assert rate["samples"]["100"] == np.mean(slider[:, 1] < config.height)
    assert max(rate["samples"].values()) <= rate["rate"] <= sum(rate["samples"].values())


def test_statistics_count_what_the_runs_did(physics: SliderCrank, ocp: OCPFile) -> None:
    config = ReplayConfig(runs=30, seed=4, modes=("open",))
    campaign = run_campaign(physics, ocp, config=config)
    stats = campaign_statistics(campaign, ocp, ocp_path="x", timing={})
    assert set(stats["claims"]) == {"robust"} and stats["claims"]["robust"]["loop"] == "open"
    assert stats["ocp"]["premiums"] == {"robust": ocp.premium("robust")}
    for profile in ("nominal", "robust"):
        replay = campaign.replays[profile, "open"]
        s = stats["profiles"][profile]["open"]
        for k in (50, 100):
            at = replay.slider_position[:, k - 1]
            assert s["violations"][str(k)] == np.count_nonzero(at < 0.08)
            assert s["constraint"][str(k)]["lowest"] == at.min()
            assert s["constraint"][str(k)]["observed_k_sigma"] == pytest.approx(3 * at.std(ddof=1))
        assert s["effort"]["applied_mean"] == pytest.approx(np.sum(replay.tau**2, axis=1).mean())
        assert s["final_error"]["theta"]["mean"] == pytest.approx(
            replay.theta[:, -1].mean() - 3 * np.pi
        )
    claim = stats["claim"]
    assert claim["holds"] == (
        claim["robust_open_violating_runs"] == 0 and claim["nominal_open_violating_runs"] >= 3
    )
    # same seed, same numbers
    again = replay_statistics(
        run_campaign(physics, ocp, config=config).replays["robust", "open"], ocp
    )
    assert again == stats["profiles"]["robust"]["open"]


def test_heldout_file_plays_the_loops_its_robust_profiles_were_tightened_for(
    tmp_path: Path, ocp_path: Path
) -> None:
    """Without modes the held-out file plays each robust profile in its own loop: open for
    robust, closed for a tube (a fallback's file has only the tube, which open loop would go
    unchecked)."""
    model = tmp_path / "m.pt"
    constant_checkpoint(model)
    tube = json.loads(ocp_path.read_text())
    tube["robust-fb"] = tube.pop("robust") | {"loop": "closed"}
    tube["profiles"] = ["nominal", "robust-fb"]
    (tmp_path / "tube.json").write_text(json.dumps(tube))
    cases = ((ocp_path, "robust", ["open"]), (tmp_path / "tube.json", "robust-fb", ["closed"]))
    for path, robust, loops in cases:
        kwargs = {"model": model, "runs": 2, "seed": 3, "mc_samples": 100}
        line = Variability.scenario("paper")
        result = heldout_file(path, tmp_path / "h.json", variability=line, **kwargs)
        assert result["modes"] == loops
        assert list(result["profiles"][robust]) == list(result["profiles"]["nominal"]) == loops
