"""Replay campaigns: exact equality with plain mj_step loops, closed loop, the campaign log
(dataset loader, SIGKILL + recover), the Rerun recording, statistics and one-line errors."""

from __future__ import annotations

import copy
import json
import os
import signal
import subprocess
import sys
import textwrap
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import mujoco
import numpy as np
import pytest

from common.streams import stream
from control.config import OCPConfig, predicted_loop
from control.figures import predicted_band
from control.ocp_file import FORMAT, INDEX_CONVENTION, VERSION, OCPFile, read_ocp
from ppann.model import PPANN, constant_ppann
from ppann.montecarlo import Feedback, monte_carlo
from replay.campaign import draw_machines, play, run_campaign
from replay.campaign_log import partial_path
from replay.config import ReplayConfig, ReplayConfigError
from replay.files import output_paths, replay_file
from replay.heldout import heldout_check
from replay.recording import BAND_LINES, band_lines, check_recording
from replay.statistics import campaign_statistics, replay_statistics
from tests.conftest import crank
from twin.geometry import PAPER
from twin.mcap_dataset import ContractError, read_dataset, read_run, read_truth
from twin.physics import STATE_SPEC, SliderCrank
from twin.stepping import chunk_time
from twin.variability import Variability, apply

N = 150


def _nominal_twin_trajectory(physics: SliderCrank, tau: np.ndarray) -> np.ndarray:
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
        state = _state(model, data)
        states[k] = physics.qpos(state, "motor"), physics.qvel(state, "motor")
        data.ctrl[motor] = u
        for _ in range(physics.substeps):
            mujoco.mj_step(model, data)
    return states


def _state(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
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


@pytest.fixture(scope="module")
def ocp_path(tmp_path_factory: pytest.TempPathFactory, physics: SliderCrank) -> Path:
    """An ocp.json whose predicted states are the nominal twin's own: a torque that swings the
    crank from rest at θ = π over top dead centre; 'robust' pushes 10 % harder."""
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
        payload[name] = _profile(tau, _nominal_twin_trajectory(physics, tau), sigma)
    path = tmp_path_factory.mktemp("replay") / "ocp.json"
    path.write_text(json.dumps(payload))
    return path


@pytest.fixture(scope="module")
def ocp(ocp_path: Path) -> OCPFile:
    return read_ocp(ocp_path)


def test_each_mode_is_predicted_by_its_loops_monte_carlo(ocp: OCPFile) -> None:
    """open plays the open-loop spread; closed and mpc (the MPC's unsaturated law is the LQR's)
    the closed loop's, which the fixture makes a tenth of it."""
    robust = ocp.profiles["robust"]
    np.testing.assert_array_equal(robust.sigma_in("open"), np.full(N, 0.004))
    for mode in ("closed", "mpc"):
        assert predicted_loop(mode) == "closed"
        np.testing.assert_array_equal(robust.sigma_in(mode), np.full(N, 0.0004))
    assert predicted_loop("open") == "open"


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
            state = _state(model, data)
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
    direct = _nominal_twin_trajectory(physics, ocp.nominal.tau)
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
    for replay, sigma in (
        (open_loop, ocp.nominal.slider_sigma_open),
        (closed, ocp.nominal.slider_sigma_closed),
    ):
        row = replay_statistics(replay, ocp)
        for sample, entry in row["constraint"].items():
            assert entry["predicted_k_sigma"] == 3 * sigma[int(sample) - 1]
    assert not np.array_equal(ocp.nominal.slider_sigma_open, ocp.nominal.slider_sigma_closed)


@pytest.mark.parametrize(
    ("modes", "feedback"),
    [(("open",), "lqr"), (("closed",), "lqr"), (("closed", "open"), "lqr"), (("closed",), "pd")],
)
def test_heldout_check_plays_and_predicts_every_profile_in_its_mode(
    physics: SliderCrank, ocp_path: Path, ocp: OCPFile, modes: tuple[str, ...], feedback: str
) -> None:
    """Every profile of the held-out check is played in each loop asked for, on the same
    machines, and predicted by a Monte-Carlo of that loop: the observed spread equals a direct
    replay's in that mode, and the prediction equals a Monte-Carlo under the profile's gains
    (closed; the fixed PD's with feedback "pd") or none (open). (A loop variable once shadowed the
    mode, and the second profile was played open loop.) The robust profile's verdict is of its
    own loop, open, when played."""
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
        modes=modes,
        feedback=feedback,
    )
    assert result["modes"] == list(modes) and result["feedback"] == feedback
    assert list(result["holds"]) == (["robust"] if "open" in modes else [])
    for mode, name in ((m, n) for m in modes for n in ocp.names):
        entry = result["profiles"][name][mode]
        _check_heldout_entry(physics, ocp, model, entry, name, mode, feedback=feedback)


def _check_heldout_entry(
    physics: SliderCrank,
    ocp: OCPFile,
    model: PPANN,
    result: dict,
    name: str,
    mode: str,
    *,
    feedback: str,
) -> None:
    """One profile's held-out entry in `mode` against a direct replay and Monte-Carlo."""
    variability = Variability.scenario("paper")
    config = ReplayConfig(
        runs=8, seed=11, modes=(mode,), variability=variability, feedback=feedback
    )
    machines = draw_machines(config, N, held_out=True)
    profile = ocp.profiles[name]
    replay = play(physics, ocp, profile=name, mode=mode, machines=machines, config=config)
    law = None
    if mode == "closed":
        gains = np.stack([profile.gain_theta, profile.gain_omega], axis=-1)
        if feedback == "pd":
            gains = np.tile([20.0, 0.5], (N - 1, 1))
        law = Feedback(
            np.stack([profile.theta, profile.omega], axis=-1), gains, ocp.config.torque_limit
        )
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
        predicted = PAPER.slider_position(bands.samples[:, int(k) - 1, 0]).std(ddof=1)
        assert entry["predicted"]["mixed"]["sigma"] == pytest.approx(predicted, rel=1e-12)
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


@pytest.fixture(scope="module")
def campaign_files(tmp_path_factory: pytest.TempPathFactory, ocp_path: Path) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("campaign") / "replay.mcap"
    replay_file(ocp_path, out, config=ReplayConfig(runs=6, seed=5))
    return output_paths(out)


def test_campaign_log_reads_back_through_the_dataset_loader(
    physics: SliderCrank, ocp: OCPFile, campaign_files: dict[str, Path]
) -> None:
    path = campaign_files["mcap"]
    dataset, truth, run = read_dataset(path), read_truth(path), read_run(path)
    assert run["kind"] == "replay-campaign" and run["config"]["runs"] == 6
    assert len(dataset) == 4 * 6 * N
    assert np.array_equal(np.unique(dataset.episode), np.arange(24))
    campaign = run_campaign(physics, ocp, config=ReplayConfig(runs=6, seed=5))
    order = [("nominal", "open"), ("nominal", "closed"), ("robust", "open"), ("robust", "closed")]
    for block, key in enumerate(order):
        replay = campaign.replays[key]
        rows = slice(block * 6 * N, (block + 1) * 6 * N)
        np.testing.assert_array_equal(dataset.theta[rows], replay.theta.ravel())
        np.testing.assert_array_equal(dataset.tau[rows], replay.tau.ravel())
        np.testing.assert_array_equal(truth.disturbance_force[rows], replay.disturbance.ravel())
    # every message is tagged; one metadata record per run; OCP and config attached
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f)
        first = next(reader.iter_messages())[2]
        tags = json.loads(first.data)
        runs = [m for m in reader.iter_metadata() if m.name == "replay_run"]
        attachments = {a.name for a in reader.iter_attachments()}
    assert {tags["run"], tags["profile"], tags["mode"], tags["sample"]} == {0, "nominal", "open", 1}
    assert len(runs) == 24
    assert json.loads(runs[7].metadata["machine"]) == campaign.machines.draws[1].as_dict()
    assert attachments == {"model.xml", "ocp.json", "config.json"}


def test_rrd_reads_back_with_reruns_reader(campaign_files: dict[str, Path]) -> None:
    from rerun.chunk import RrdReader

    path = campaign_files["rrd"]
    assert check_recording(path) == ["crank_replay"]
    reader = RrdReader(path)
    assert len(reader.blueprints()) == 1
    summary = reader.store().summary()
    lines = {line.split()[0]: line for line in summary.splitlines()}
    for entity in (
        "/mechanism/nominal/open/linkage",
        "/mechanism/robust/closed/slider",
        "/slider/nominal/open/runs",
        "/slider/robust/closed/band",
        "/slider/robust/open/planned",
        "/torque/robust/closed/runs",
        "/torque/nominal/planned",
    ):
        assert f"rows={N}" in lines[entity], lines.get(entity)
        assert "timelines=['sample', 'time']" in lines[entity] or "'sample'" in lines[entity]
    assert (
        "/slider/nominal/open/constraint" in lines
        and "rows=2" in lines["/slider/nominal/open/constraint"]
    )


def test_rerun_band_is_shaded_between_the_bounds_and_inside_the_stroke() -> None:
    """The drawn band stays within the stroke (a predicted 3σ above top dead centre is drawn at
    the stroke's end) and its Rerun series run evenly from the lower to the upper bound."""
    profile = SimpleNamespace(
        slider=np.array([0.02, 0.0, 0.1]), sigma_in=lambda mode: np.array([0.003, 0.002, 0.004])
    )
    lower, upper = predicted_band(profile, "open", 3.0, geometry=PAPER)
    assert np.allclose(lower, [0.011, 0.0, 0.088], rtol=0, atol=1e-15)
    assert np.allclose(upper, [0.029, 0.006, PAPER.stroke_top], rtol=0, atol=1e-15)
    lines = band_lines(lower, upper)
    assert lines.shape == (BAND_LINES, 3)
    assert np.array_equal(lines[0], lower) and np.allclose(lines[-1], upper, rtol=0, atol=1e-15)
    assert np.allclose(np.diff(lines, axis=0), (upper - lower) / (BAND_LINES - 1))


KILLER = textwrap.dedent(
    """
    import os, signal, sys
    from mcap.writer import Writer
    from replay.config import ReplayConfig
    from replay.files import replay_file

    # SIGKILL in the middle of writing run 7: a run is 150 messages on each of the two dataset
    # channels, then 150 transforms, 1 scene and 150 plan rows for Foxglove
    limit, written, add_message = 6 * 601 + 300, 0, Writer.add_message

    def counting(self, *args, **kwargs):
        global written
        written += 1
        if written == limit:
            os.kill(os.getpid(), signal.SIGKILL)
        return add_message(self, *args, **kwargs)

    Writer.add_message = counting
    replay_file(sys.argv[1], sys.argv[2], config=ReplayConfig(runs=4, seed=6))
    """
)


def test_killed_campaign_is_recovered_with_every_completed_run(
    physics: SliderCrank, ocp: OCPFile, ocp_path: Path, tmp_path: Path
) -> None:
    out = tmp_path / "replay.mcap"
    root = Path(__file__).resolve().parent.parent
    killed = subprocess.run(
        [sys.executable, "-c", KILLER, str(ocp_path), str(out)],
        cwd=root,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    broken = partial_path(out)
    assert broken.exists() and not out.exists()
    with pytest.raises(ContractError, match="truncated"):
        read_dataset(broken)
    fixed = tmp_path / "fixed.mcap"
    result = crank("recover", str(broken), str(fixed))
    assert result.returncode == 0, result.stderr
    assert "6 complete runs" in result.stdout
    dataset = read_dataset(fixed)
    assert np.array_equal(np.unique(dataset.episode), np.arange(6))
    campaign = run_campaign(physics, ocp, config=ReplayConfig(runs=4, seed=6))
    first = np.concatenate(
        [
            campaign.replays["nominal", "open"].theta.ravel(),
            campaign.replays["nominal", "closed"].theta[:2].ravel(),
        ]
    )
    np.testing.assert_array_equal(dataset.theta, first)
    # a new campaign refuses to overwrite the crashed one's partial file
    again = crank("replay", "--ocp", str(ocp_path), "--out", str(out), "--runs", "2")
    assert again.returncode == 2 and "crank recover" in again.stderr


@pytest.mark.parametrize("fraction", [0.3, 0.55, 0.8])
def test_recover_keeps_the_complete_runs_before_any_cut(
    campaign_files: dict[str, Path], tmp_path: Path, fraction: float
) -> None:
    from replay.campaign_log import recover

    full = campaign_files["mcap"].read_bytes()
    broken = tmp_path / "cut.mcap"
    broken.write_bytes(full[: int(fraction * len(full))])  # mid-record, mid-chunk
    result = recover(broken, tmp_path / "fixed.mcap")
    assert not result.complete and 0 < result.runs < 24
    recovered, reference = (
        read_dataset(tmp_path / "fixed.mcap"),
        read_dataset(campaign_files["mcap"]),
    )
    assert np.array_equal(np.unique(recovered.episode), np.arange(result.runs))
    np.testing.assert_array_equal(
        recovered.slider_position, reference.slider_position[: result.runs * N]
    )
    from mcap.reader import make_reader

    from replay.foxglove import TF_TOPIC

    with open(tmp_path / "fixed.mcap", "rb") as f:  # Foxglove's channels keep the same runs
        summary = make_reader(f).get_summary()
    counts = {c.topic: summary.statistics.channel_message_counts.get(i, 0)
              for i, c in summary.channels.items()}  # fmt: skip
    assert counts[TF_TOPIC] == result.runs * N


def _broken_ocp(ocp_path: Path, tmp_path: Path, edit) -> Path:
    raw = json.loads(ocp_path.read_text())
    edit(raw)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(raw).replace("Infinity", "NaN"))
    return path


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda r: r["robust"].pop("tau"), "missing key 'robust.tau'"),
        (lambda r: r["robust"].pop("gain_omega"), "missing key 'robust.gain_omega'"),
        (lambda r: r["nominal"]["theta"].pop(), "nominal.theta has 149 values, expected 150"),
        (lambda r: r["nominal"]["tau"].__setitem__(3, float("inf")), "non-finite value at index 3"),
        (
            lambda r: r["config"].__setitem__("torque_limit", 12.0),
            "solved with |τ| <= 12 N·m but the twin's actuator saturates at 10 N·m",
        ),
    ],
)
def test_replay_rejects_a_bad_ocp_json_in_one_line(
    ocp_path: Path, tmp_path: Path, edit, match: str
) -> None:
    bad = _broken_ocp(ocp_path, tmp_path, edit)
    out = tmp_path / "out" / "replay.mcap"
    out.parent.mkdir()
    result = crank("replay", "--ocp", str(bad), "--out", str(out), "--runs", "2")
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and match in result.stderr, result.stderr
    assert list(out.parent.iterdir()) == []  # nothing half-written, not even a .partial


def test_replay_config_validation() -> None:
    with pytest.raises(ReplayConfigError, match="runs must be an integer"):
        ReplayConfig(runs=2.5)  # type: ignore[arg-type]
    with pytest.raises(ReplayConfigError, match="modes repeat"):
        ReplayConfig(modes=("open", "open"))
    assert replace(ReplayConfig(), runs=3).runs == 3


def test_cli_replay_writes_every_file_and_view_explains(ocp_path: Path, tmp_path: Path) -> None:
    out = tmp_path / "campaign" / "replay.mcap"
    result = crank("replay", "--ocp", str(ocp_path), "--out", str(out), "--runs", "3")
    assert result.returncode == 0, result.stderr
    assert "robust" in result.stdout and "below@50" in result.stdout
    paths = output_paths(out)
    assert all(p.is_file() for p in paths.values())
    stats = json.loads(paths["stats"].read_text())
    assert stats["format"] == "crank-replay-stats" and stats["version"] == 2
    assert stats["config"]["runs"] == 3
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    view = subprocess.run(
        [sys.executable, "-m", "crank", "view", str(paths["rrd"])],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
        check=False,
    )
    assert view.returncode == 0 and "no display" in view.stdout and "rerun" in view.stdout
    garbage = tmp_path / "garbage.rrd"
    garbage.write_text("not a recording")
    bad = crank("view", str(garbage))
    assert bad.returncode == 2 and "not a readable Rerun recording" in bad.stderr
